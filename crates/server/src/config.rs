//! The visualiser server's command-line flags ([`HttpArgs`], flattened into `voxhap serve`) and the settings
//! they resolve to: where to listen, the control token, the client cap.
//!
//! Safe by default: the server listens on loopback; a non-loopback address needs `--allow-remote`, because
//! anyone who can reach it sees the session, and with the token moves a real arm. The control token is random
//! (128 bits from the OS) unless given.

use clap::Args;
use std::net::{Ipv4Addr, SocketAddr};
use std::time::Duration;

/// The address the server listens on when `--http` is not given.
pub const DEFAULT_HTTP_ADDR: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 8080);
/// Default cap on concurrent WebSocket clients.
pub const DEFAULT_MAX_CLIENTS: usize = 64;
/// A connection on which nothing moved this long is closed (see `server::guard`).
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// A request's head (request line and headers) must arrive this soon after the connection opens or the
/// previous answer was written (see `server::guard`).
pub const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(5);
/// Largest `--max-clients`.
pub const MAX_CLIENTS_LIMIT: usize = 4096;

/// Flags of the visualiser server (page, REST API, WebSocket stream).
#[derive(Debug, Clone, Args)]
pub struct HttpArgs {
    /// Address of the visualiser server (page, REST API, WebSocket) [default: 127.0.0.1:8080]. A busy default
    /// port only warns; a busy --http is an error. Port 0 picks a free port.
    #[arg(long = "http", value_name = "ADDR", value_parser = parse_addr)]
    pub http: Option<SocketAddr>,
    /// Allow --http on an address other than loopback (anyone who reaches it sees the session).
    #[arg(long)]
    pub allow_remote: bool,
    /// Bearer token that control requests must carry [default: 32 random hex digits, printed at start].
    #[arg(long, value_name = "TOKEN")]
    pub token: Option<String>,
    /// Most WebSocket clients at once; more are refused with 503.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_CLIENTS)]
    pub max_clients: usize,
    /// Another name this server may be addressed by in the Host header (besides its IP address, and
    /// localhost on loopback); repeat for more. Needed behind a DNS name or a reverse proxy.
    #[arg(long, value_name = "NAME")]
    pub allow_host: Vec<String>,
    /// Another web origin (`http://viewer.lab:3000`) whose pages may open /ws and send control requests;
    /// repeat for more. By default only the page served here may.
    #[arg(long, value_name = "ORIGIN")]
    pub allow_origin: Vec<String>,
    /// Do not start the visualiser server (--token still sets the OpenIGTLink server's token).
    #[arg(long, conflicts_with_all = ["http", "allow_remote", "max_clients", "allow_host", "allow_origin"])]
    pub no_http: bool,
}

/// What the server needs once it has a listener.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServerConfig {
    /// The bearer token of control requests.
    pub token: String,
    /// Most WebSocket clients at once.
    pub max_clients: usize,
    /// A connection to which the server has written nothing this long (since the accept or the last
    /// write) is closed; bytes from the client do not count, so a trickled request cannot hold it.
    pub idle_timeout: Duration,
    /// A request's head must be complete this soon after the accept or the previous answer.
    pub header_timeout: Duration,
    /// Names (`--allow-host`) the Host header may carry besides the listening address.
    pub allowed_hosts: Vec<String>,
    /// Origins (`--allow-origin`) whose pages may open /ws and change the session.
    pub allowed_origins: Vec<String>,
}

impl ServerConfig {
    /// A random token and the default cap.
    pub fn new() -> Result<ServerConfig, ConfigError> {
        Ok(ServerConfig {
            token: random_token()?,
            max_clients: DEFAULT_MAX_CLIENTS,
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            header_timeout: DEFAULT_HEADER_TIMEOUT,
            allowed_hosts: Vec::new(),
            allowed_origins: Vec::new(),
        })
    }
}

/// The resolved flags: where to listen, whether that address was asked for, and the server settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HttpSettings {
    pub addr: SocketAddr,
    /// True when `--http` was given (a busy port is then an error, not a warning).
    pub explicit: bool,
    pub config: ServerConfig,
}

/// Why the flags do not make a server.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("--http {0} is not a loopback address: anyone who can reach it sees the session, and with the token controls the device; add --allow-remote to serve it anyway")]
    Remote(SocketAddr),
    #[error("--token must be 8 to 256 visible ASCII characters (no spaces), got {0} characters")]
    Token(usize),
    #[error("--max-clients must be 1 ..= {MAX_CLIENTS_LIMIT}, got {0}")]
    MaxClients(usize),
    #[error("could not get random bytes for the control token: {0}")]
    Random(getrandom::Error),
}

/// Parses `--http`: `IP:PORT`, `[IPv6]:PORT`, or `localhost:PORT`.
fn parse_addr(text: &str) -> Result<SocketAddr, crate::addr::ListenAddrError> {
    crate::addr::parse_listen_addr(text, DEFAULT_HTTP_ADDR.port())
}

/// 32 hex digits from the OS's random source.
pub fn random_token() -> Result<String, ConfigError> {
    let mut bytes = [0u8; 16];
    getrandom::fill(&mut bytes).map_err(ConfigError::Random)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

impl HttpArgs {
    /// The settings, or `None` with `--no-http`.
    pub fn resolve(&self) -> Result<Option<HttpSettings>, ConfigError> {
        if self.no_http {
            return Ok(None);
        }
        let addr = self.http.unwrap_or(DEFAULT_HTTP_ADDR);
        if !addr.ip().is_loopback() && !self.allow_remote {
            return Err(ConfigError::Remote(addr));
        }
        if !(1..=MAX_CLIENTS_LIMIT).contains(&self.max_clients) {
            return Err(ConfigError::MaxClients(self.max_clients));
        }
        let token = match &self.token {
            Some(token) => {
                let visible = token.bytes().all(|b| b.is_ascii_graphic());
                if !visible || !(8..=256).contains(&token.len()) {
                    return Err(ConfigError::Token(token.chars().count()));
                }
                token.clone()
            }
            None => random_token()?,
        };
        Ok(Some(HttpSettings {
            addr,
            explicit: self.http.is_some(),
            config: ServerConfig {
                token,
                max_clients: self.max_clients,
                idle_timeout: DEFAULT_IDLE_TIMEOUT,
                header_timeout: DEFAULT_HEADER_TIMEOUT,
                allowed_hosts: self.allow_host.clone(),
                allowed_origins: self.allow_origin.clone(),
            },
        }))
    }
}

/// Parses `args` (without the program name) as a command line holding only the flags `A`: the flag
/// groups' tests.
#[cfg(test)]
pub(crate) fn parse_flags<A: clap::Args>(args: &[&str]) -> Result<A, clap::Error> {
    let command = A::augment_args(clap::Command::new("voxhap"));
    let matches =
        command.try_get_matches_from(std::iter::once("voxhap").chain(args.iter().copied()))?;
    A::from_arg_matches(&matches)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn resolve(args: &[&str]) -> Result<Option<HttpSettings>, String> {
        let http: HttpArgs = parse_flags(args).map_err(|e| e.to_string())?;
        http.resolve().map_err(|e| e.to_string())
    }

    #[test]
    fn defaults_are_loopback_8080_a_random_token_and_64_clients() {
        let settings = resolve(&[]).unwrap().unwrap();
        assert_eq!(settings.addr, DEFAULT_HTTP_ADDR);
        assert!(!settings.explicit);
        assert_eq!(settings.config.max_clients, 64);
        assert_eq!(settings.config.token.len(), 32);
        assert!(settings.config.token.bytes().all(|b| b.is_ascii_hexdigit()));
        let other = resolve(&[]).unwrap().unwrap();
        assert_ne!(settings.config.token, other.config.token);
    }

    #[test]
    fn remote_addresses_need_allow_remote() {
        let err = resolve(&["--http", "0.0.0.0:8080"]).unwrap_err();
        assert!(err.contains("--allow-remote"), "{err}");
        let ok = resolve(&["--http", "0.0.0.0:9000", "--allow-remote"])
            .unwrap()
            .unwrap();
        assert!(ok.explicit);
        let local = resolve(&["--http", "localhost:0"]).unwrap().unwrap();
        assert_eq!(local.addr.port(), 0);
        assert!(resolve(&["--http", "[::1]:8080"]).is_ok());
        assert!(resolve(&["--http", "nonsense"])
            .unwrap_err()
            .contains("expected IP:PORT"));
    }

    #[test]
    fn tokens_caps_and_no_http() {
        let given = resolve(&["--token", "s3cret-token"]).unwrap().unwrap();
        assert_eq!(given.config.token, "s3cret-token");
        assert!(resolve(&["--token", "short"])
            .unwrap_err()
            .contains("--token must be"));
        assert!(resolve(&["--token", "has a space"]).is_err());
        assert!(resolve(&["--max-clients", "0"])
            .unwrap_err()
            .contains("--max-clients must be"));
        assert_eq!(resolve(&["--no-http"]).unwrap(), None);
        assert!(resolve(&["--no-http", "--http", "127.0.0.1:1"]).is_err());
        assert_eq!(
            resolve(&["--no-http", "--token", "s3cret-token"]).unwrap(),
            None
        );
    }
}

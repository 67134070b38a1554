//! Host and Origin checks: the visualiser server answers only requests addressed to it by a name it knows,
//! and takes WebSocket upgrades and state-changing requests only from its own page (or origins the operator
//! allowed).
//!
//! Where it sits: an axum middleware in front of every route (`http::router`), before the token check.
//! Why: the server listens on loopback and reading needs no token, so a web page the user happens to visit
//! could otherwise read the live session through DNS rebinding (its own name re-pointed at 127.0.0.1: the
//! browser then sends `Host: evil.example:8080`), and could open `/ws` from any page (WebSocket is not
//! covered by the browser's same-origin rule; the browser sends `Origin: https://evil.example`).
//!
//! - **Host** must name the listening address: its IP literal (any IP literal when listening on 0.0.0.0 or
//!   `::`, since rebinding needs a DNS name), `localhost` when listening on loopback, or a name given with
//!   `--allow-host`; and the port must be the listening port. A request without a Host header is refused
//!   with 400 (RFC 9112 section 3.2: a server "MUST respond with a 400 (Bad Request) status code to any
//!   HTTP/1.1 request message that lacks a Host header field"; HTTP/1.0 requests are held to the same, since
//!   the Host check is what stops a DNS-rebinding page, and curl, browsers and scripts always send one).
//! - **Origin**, on `/ws` and on every request that is not GET or HEAD, must be `http://` + the request's
//!   own Host (same origin), or one given with `--allow-origin`. Requests without an Origin header
//!   (curl, scripts) pass: they are not a browser acting for a web page.
//! - **One of each:** a request with more than one Host header, or more than one Origin header, is refused
//!   with 400 before either check. HTTP allows one Host field line (RFC 9112 section 3.2: a server "MUST
//!   respond with a 400 (Bad Request) status code to any request message that contains more than one Host
//!   header field line"), and a browser sends at most one Origin (RFC 6454 section 7.3); with two, the
//!   check could read a good one while another part of the stack reads the other.

use std::net::{IpAddr, SocketAddr};

/// Who may address the server, resolved once from the listening address and the flags.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OriginPolicy {
    listen: SocketAddr,
    allowed_hosts: Vec<String>,
    allowed_origins: Vec<String>,
}

/// Why a request was refused (HTTP 403, or 400 for a repeated or missing Host header:
/// [`OriginError::http_status`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OriginError {
    #[error("bad request: {count} {header} headers; a request carries at most one (with two, a check could read one and another part of the server the other)")]
    Repeated { header: &'static str, count: usize },
    #[error("bad request: no Host header; every request must name the server it is for (RFC 9112 section 3.2)")]
    MissingHost,
    #[error("forbidden: Host {host:?} is not this server's address {listen} (a DNS-rebinding page would send its own name); start voxhap with --allow-host NAME to serve that name")]
    Host { host: String, listen: SocketAddr },
    #[error("forbidden: Origin {origin:?} is not this server's page (http://{host}); only the page served here may open /ws or change the session; start voxhap with --allow-origin ORIGIN to allow another")]
    Origin { origin: String, host: String },
}

impl OriginError {
    /// The HTTP status that answers it: 400 for a repeated header, 403 otherwise.
    pub fn http_status(&self) -> u16 {
        match self {
            OriginError::Repeated { .. } | OriginError::MissingHost => 400,
            OriginError::Host { .. } | OriginError::Origin { .. } => 403,
        }
    }
}

/// Refuses more than one line of the header `header` (`count` lines were received).
pub fn check_single(header: &'static str, count: usize) -> Result<(), OriginError> {
    if count > 1 {
        Err(OriginError::Repeated { header, count })
    } else {
        Ok(())
    }
}

impl OriginPolicy {
    /// The policy of a server listening on `listen` (the bound address, port resolved).
    pub fn new(listen: SocketAddr, allowed_hosts: &[String], allowed_origins: &[String]) -> Self {
        OriginPolicy {
            listen,
            allowed_hosts: allowed_hosts
                .iter()
                .map(|h| h.to_ascii_lowercase())
                .collect(),
            allowed_origins: allowed_origins
                .iter()
                .map(|o| o.trim_end_matches('/').to_ascii_lowercase())
                .collect(),
        }
    }

    /// Checks a request's Host header (`None`: no header, refused).
    pub fn check_host(&self, host: Option<&str>) -> Result<(), OriginError> {
        let Some(host) = host else {
            return Err(OriginError::MissingHost);
        };
        if self.host_allowed(host) {
            Ok(())
        } else {
            Err(OriginError::Host {
                host: host.to_owned(),
                listen: self.listen,
            })
        }
    }

    fn host_allowed(&self, host: &str) -> bool {
        let host = host.trim().to_ascii_lowercase();
        let Some((name, port)) = split_host_port(&host) else {
            return false;
        };
        if port.unwrap_or(80) != self.listen.port() {
            return false;
        }
        if self.allowed_hosts.iter().any(|allowed| allowed == name) {
            return true;
        }
        match name.parse::<IpAddr>() {
            Ok(ip) => self.listen.ip().is_unspecified() || ip == self.listen.ip(),
            Err(_) => name == "localhost" && self.listen.ip().is_loopback(),
        }
    }

    /// Checks a request's Origin header against its (already checked) Host header.
    pub fn check_origin(
        &self,
        origin: Option<&str>,
        host: Option<&str>,
    ) -> Result<(), OriginError> {
        let Some(origin) = origin else {
            return Ok(());
        };
        let normalised = origin.trim().trim_end_matches('/').to_ascii_lowercase();
        let host = host.unwrap_or_default().trim().to_ascii_lowercase();
        let same_origin = !host.is_empty() && normalised == format!("http://{host}");
        if same_origin || self.allowed_origins.contains(&normalised) {
            Ok(())
        } else {
            Err(OriginError::Origin {
                origin: origin.to_owned(),
                host,
            })
        }
    }
}

/// Splits `name[:port]` or `[v6][:port]`; `None` when the port is not a number.
fn split_host_port(host: &str) -> Option<(&str, Option<u16>)> {
    if let Some(rest) = host.strip_prefix('[') {
        let (name, after) = rest.split_once(']')?;
        return match after {
            "" => Some((name, None)),
            port => Some((name, Some(port.strip_prefix(':')?.parse().ok()?))),
        };
    }
    match host.rsplit_once(':') {
        Some((name, port)) => Some((name, Some(port.parse().ok()?))),
        None => Some((host, None)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(listen: &str) -> OriginPolicy {
        OriginPolicy::new(
            listen.parse().unwrap(),
            &["voxhap.lab".to_owned()],
            &["http://viewer.lab:3000/".to_owned()],
        )
    }

    #[test]
    fn hosts_must_name_the_listening_address() {
        let loopback = policy("127.0.0.1:8080");
        for ok in [
            "127.0.0.1:8080",
            "localhost:8080",
            "LOCALHOST:8080",
            "voxhap.lab:8080",
        ] {
            assert!(loopback.check_host(Some(ok)).is_ok(), "{ok}");
        }
        // RFC 9112 section 3.2: a request without Host is answered 400.
        assert_eq!(loopback.check_host(None), Err(OriginError::MissingHost));
        assert_eq!(OriginError::MissingHost.http_status(), 400);
        for bad in [
            "evil.example:8080",
            "127.0.0.1:9090",
            "127.0.0.2:8080",
            "localhost",
            "127.0.0.1:x",
            "",
        ] {
            let message = loopback.check_host(Some(bad)).unwrap_err().to_string();
            assert!(message.contains("--allow-host"), "{bad}: {message}");
        }
        let v6 = policy("[::1]:80");
        assert!(v6.check_host(Some("[::1]")).is_ok());
        assert!(v6.check_host(Some("[::1]:80")).is_ok());
        assert!(v6.check_host(Some("[::2]:80")).is_err());
        let any = policy("0.0.0.0:8080");
        assert!(any.check_host(Some("192.168.1.20:8080")).is_ok());
        assert!(any.check_host(Some("rebind.example:8080")).is_err());
    }

    #[test]
    fn a_repeated_host_or_origin_is_a_bad_request() {
        assert!(check_single("Host", 0).is_ok());
        assert!(check_single("Host", 1).is_ok());
        let error = check_single("Origin", 2).unwrap_err();
        assert_eq!(error.http_status(), 400);
        assert!(error.to_string().contains("2 Origin headers"), "{error}");
    }

    #[test]
    fn origins_must_be_the_page_itself_or_allowed() {
        let p = policy("127.0.0.1:8080");
        let host = Some("127.0.0.1:8080");
        assert!(p.check_origin(None, host).is_ok());
        assert!(p.check_origin(Some("http://127.0.0.1:8080"), host).is_ok());
        assert!(p.check_origin(Some("http://viewer.lab:3000"), host).is_ok());
        for bad in [
            "https://evil.example",
            "http://localhost:8080",
            "null",
            "http://127.0.0.1:8081",
        ] {
            let message = p.check_origin(Some(bad), host).unwrap_err().to_string();
            assert!(message.contains("--allow-origin"), "{bad}: {message}");
        }
        assert!(p
            .check_origin(Some("http://localhost:8080"), Some("localhost:8080"))
            .is_ok());
    }
}

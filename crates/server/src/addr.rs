//! Listening addresses on the command line (`--http`, `--igtl`, `--foxglove`): `IP:PORT`, `[IPv6]:PORT` or
//! `localhost:PORT`, parsed by one function so the three flags accept the same forms.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};

/// Why a listening address was not understood: the text given and what was wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ListenAddrError {
    /// `localhost:` followed by something that is not a port.
    #[error("{0:?} is not a port number")]
    Port(String),
    /// Neither a socket address nor `localhost:PORT`.
    #[error("expected IP:PORT such as 127.0.0.1:{example_port} or [::1]:{example_port}, or localhost:PORT, got {given:?}")]
    Address {
        /// The text given.
        given: String,
        /// The flag's usual port, for the example.
        example_port: u16,
    },
}

/// Parses `IP:PORT`, `[IPv6]:PORT` or `localhost:PORT`; `example_port` goes into the message.
pub fn parse_listen_addr(text: &str, example_port: u16) -> Result<SocketAddr, ListenAddrError> {
    if let Some(port) = text.strip_prefix("localhost:") {
        let port = port
            .parse::<u16>()
            .map_err(|_| ListenAddrError::Port(port.to_owned()))?;
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    text.parse().map_err(|_| ListenAddrError::Address {
        given: text.to_owned(),
        example_port,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_three_forms_parse_and_others_say_why() {
        assert_eq!(
            parse_listen_addr("127.0.0.1:8080", 8080),
            Ok(SocketAddr::from(([127, 0, 0, 1], 8080)))
        );
        assert_eq!(
            parse_listen_addr("[::1]:9", 8080),
            Ok("[::1]:9".parse().unwrap())
        );
        assert_eq!(
            parse_listen_addr("localhost:0", 8080),
            Ok(SocketAddr::from(([127, 0, 0, 1], 0)))
        );
        assert_eq!(
            parse_listen_addr("localhost:http", 8080),
            Err(ListenAddrError::Port("http".to_owned()))
        );
        let message = parse_listen_addr("example.org:80", 18944)
            .unwrap_err()
            .to_string();
        assert!(message.contains("127.0.0.1:18944"), "{message}");
        assert!(message.contains("\"example.org:80\""), "{message}");
    }
}

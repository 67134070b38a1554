//! `voxhap clear-fault`: the operator's explicit acknowledgement of a device fault that needs a person
//! (e-stop, over-current, ...). It asks a running `voxhap serve` (through its control API on loopback) to send
//! ClearFault to the device; the session then enables the device again once the link is healthy, and forces
//! ramp in. voxhap never clears such a fault by itself (docs/safety.md).
//!
//! The request is one HTTP/1.1 POST of `{"command":"clear_fault"}` to `/api/control` with the control token,
//! written over a plain `TcpStream`: the server is on this machine and speaks plain HTTP, so a client library
//! (and its TLS stack) would add build time for nothing.

use anyhow::{bail, Context};
use clap::Args;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;

#[derive(Debug, Args)]
pub struct ClearFaultArgs {
    /// Address of the running `voxhap serve`'s visualiser server (its `--http`).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub http: String,
    /// The control token `voxhap serve` printed at start (`http: control token T`); or set VOXHAP_TOKEN.
    #[arg(long, env = "VOXHAP_TOKEN")]
    pub token: String,
}

/// Sends the command; returns the server's reply text.
pub fn request(addr: SocketAddr, token: &str) -> anyhow::Result<(u16, String)> {
    let body = r#"{"command":"clear_fault"}"#;
    let mut stream =
        TcpStream::connect_timeout(&addr, Duration::from_secs(2)).with_context(|| {
            format!("connecting to voxhap serve at {addr} (is it running with --http?)")
        })?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    stream.set_write_timeout(Some(Duration::from_secs(5)))?;
    write!(
        stream,
        "POST /api/control HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )?;
    let mut reply = Vec::new();
    stream
        .take(64 * 1024)
        .read_to_end(&mut reply)
        .context("reading the server's answer")?;
    let text = String::from_utf8_lossy(&reply);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|code| code.parse::<u16>().ok())
        .with_context(|| format!("the server's answer is not HTTP: {head:?}"))?;
    Ok((status, body.trim().to_owned()))
}

pub fn run(args: &ClearFaultArgs) -> anyhow::Result<()> {
    let addr = args
        .http
        .to_socket_addrs()
        .with_context(|| format!("--http {}: not an address", args.http))?
        .next()
        .with_context(|| format!("--http {}: no address", args.http))?;
    let (status, body) = request(addr, &args.token)?;
    if status != 200 {
        bail!("the server refused clear_fault (HTTP {status}): {body}");
    }
    super::common::print_out(&format!("clear_fault: {body}"))
}

//! The byte stream under the WebSocket: the endpoint URL taken apart, its host
//! resolved and checked (`d3il_protocol::address`, the one classifier), one
//! TCP connection to a checked address, and a deadline on every read and write.

use crate::PolicyError;
use d3il_protocol::address::{resolve_public, AddressError};
use d3il_protocol::Limits;
use std::io::{self, Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

/// A `ws://` or `wss://` URL taken apart.
pub(super) struct Endpoint {
    pub(super) tls: bool,
    /// The host without IPv6 brackets (also the TLS server name).
    pub(super) host: String,
    pub(super) port: u16,
}

impl Endpoint {
    pub(super) fn parse(url: &str) -> Result<Endpoint, PolicyError> {
        let bad = |reason: String| PolicyError::BadEndpoint {
            url: url.into(),
            reason,
        };
        let parsed = url::Url::parse(url)
            .map_err(|e| bad(format!("not a valid URL ({e}); use ws://host:port/path")))?;
        let tls = match parsed.scheme() {
            "ws" => false,
            "wss" => true,
            s => {
                return Err(bad(format!(
                    "scheme `{s}` is not supported; use ws:// or wss://"
                )))
            }
        };
        let host = parsed
            .host_str()
            .ok_or_else(|| bad("the URL has no host".into()))?
            .trim_start_matches('[')
            .trim_end_matches(']')
            .to_string();
        // ws = 80, wss = 443 unless the URL says otherwise.
        let port = parsed.port_or_known_default().unwrap_or(80);
        Ok(Endpoint { tls, host, port })
    }
}

/// Resolve the endpoint's host, check every address (refused if any is
/// private unless `limits.allow_private_endpoints`), then connect to the first
/// checked one that answers (no second lookup that could answer differently). The returned stream's
/// deadline is `deadline` from now, for the TLS and WebSocket handshakes.
pub(super) fn connect_tcp(
    url: &str,
    ep: &Endpoint,
    limits: &Limits,
    deadline: Duration,
) -> Result<DeadlineStream, PolicyError> {
    let addrs =
        resolve_public(&ep.host, ep.port, limits.allow_private_endpoints).map_err(|e| match e {
            AddressError::Resolve { .. } => PolicyError::Connect {
                url: url.into(),
                reason: e.to_string(),
            },
            _ => PolicyError::BadEndpoint {
                url: url.into(),
                reason: e.to_string(),
            },
        })?;
    // Every checked address in turn (`localhost` gives ::1 and 127.0.0.1; a
    // server on one of them must be found), all within the one deadline.
    let start = Instant::now();
    let mut failures = vec![];
    let mut connected = None;
    for addr in &addrs {
        let left = deadline.saturating_sub(start.elapsed());
        if left.is_zero() {
            failures.push(format!("{addr}: deadline passed"));
            break;
        }
        match TcpStream::connect_timeout(addr, left) {
            Ok(tcp) => {
                connected = Some(tcp);
                break;
            }
            Err(e) => failures.push(format!("{addr}: {e}")),
        }
    }
    let tcp = connected.ok_or_else(|| PolicyError::Connect {
        url: url.into(),
        reason: failures.join("; "),
    })?;
    let _ = tcp.set_nodelay(true);
    Ok(DeadlineStream {
        inner: tcp,
        deadline: Instant::now() + deadline,
        first_byte: Arc::new(OnceLock::new()),
    })
}

/// A TCP stream whose reads and writes fail with `TimedOut` once the current
/// deadline has passed, however the server dribbles its bytes.
pub(super) struct DeadlineStream {
    pub(super) inner: TcpStream,
    pub(super) deadline: Instant,
    /// The first byte the server sent, if any (tells a TLS answer to a ws://
    /// client apart from other handshake failures); shared so that it outlives
    /// a failed handshake, which consumes the stream.
    pub(super) first_byte: Arc<OnceLock<u8>>,
}

impl DeadlineStream {
    fn remaining(&self) -> io::Result<Duration> {
        let now = Instant::now();
        if now >= self.deadline {
            return Err(io::Error::new(io::ErrorKind::TimedOut, "deadline passed"));
        }
        // A zero timeout means "block forever" to the OS; keep it positive.
        Ok((self.deadline - now).max(Duration::from_millis(1)))
    }
}

impl Read for DeadlineStream {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let t = self.remaining()?;
        self.inner.set_read_timeout(Some(t))?;
        let n = self.inner.read(buf)?;
        if n > 0 && self.first_byte.get().is_none() {
            let _ = self.first_byte.set(buf[0]);
        }
        Ok(n)
    }
}

impl Write for DeadlineStream {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let t = self.remaining()?;
        self.inner.set_write_timeout(Some(t))?;
        self.inner.write(buf)
    }
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// What the WebSocket runs over: the TCP stream itself (`ws://`) or a TLS
/// session on it (`wss://`); both obey the same deadlines.
pub(super) enum Transport {
    Plain(DeadlineStream),
    Tls(Box<rustls::StreamOwned<rustls::ClientConnection, DeadlineStream>>),
}

impl Transport {
    pub(super) fn set_deadline(&mut self, deadline: Instant) {
        match self {
            Transport::Plain(s) => s.deadline = deadline,
            Transport::Tls(t) => t.sock.deadline = deadline,
        }
    }
}

impl Read for Transport {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Transport::Plain(s) => s.read(buf),
            Transport::Tls(t) => t.read(buf),
        }
    }
}

impl Write for Transport {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Transport::Plain(s) => s.write(buf),
            Transport::Tls(t) => t.write(buf),
        }
    }
    fn flush(&mut self) -> io::Result<()> {
        match self {
            Transport::Plain(s) => s.flush(),
            Transport::Tls(t) => t.flush(),
        }
    }
}

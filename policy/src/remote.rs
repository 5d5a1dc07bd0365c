//! Client for remote policy servers (docs/remote-protocol.md): a blocking
//! WebSocket with msgpack frames, a deadline on every request and a cap on the
//! size of every reply.

use crate::wire::{self, PROTOCOL_VERSION};
use crate::{ActionChunks, Policy, PolicyError, PolicyShape, Query, IMAGE_SHAPE};
use d3il_protocol::{Limits, ObsType, TaskSpec};
use rmpv::Value;
use std::io::{self, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

/// Largest k and H a server may announce (far above any D3IL baseline).
const MAX_HISTORY: u64 = d3il_protocol::PolicyManifest::MAX_HISTORY as u64;
const MAX_HORIZON: u64 = d3il_protocol::PolicyManifest::MAX_HORIZON as u64;

/// A TCP stream whose reads and writes fail with `TimedOut` once the current
/// deadline has passed, however the server dribbles its bytes.
struct DeadlineStream {
    inner: TcpStream,
    deadline: Instant,
    /// The first byte the server sent, if any (tells a TLS answer to a ws://
    /// client apart from other handshake failures); shared so that it outlives
    /// a failed handshake, which consumes the stream.
    first_byte: Arc<OnceLock<u8>>,
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
enum Transport {
    Plain(DeadlineStream),
    Tls(Box<rustls::StreamOwned<rustls::ClientConnection, DeadlineStream>>),
}

impl Transport {
    fn set_deadline(&mut self, deadline: Instant) {
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

/// A handshake that ended because the server closed the connection.
fn closed_silently(e: &tungstenite::Error) -> bool {
    use tungstenite::Error as E;
    match e {
        E::Protocol(tungstenite::error::ProtocolError::HandshakeIncomplete)
        | E::ConnectionClosed
        | E::AlreadyClosed => true,
        E::Io(io) => matches!(
            io.kind(),
            io::ErrorKind::UnexpectedEof
                | io::ErrorKind::ConnectionReset
                | io::ErrorKind::ConnectionAborted
                | io::ErrorKind::BrokenPipe
        ),
        _ => false,
    }
}

/// First bytes of a TLS record a server sends: handshake (0x16) or alert (0x15).
fn looks_like_tls(first: Option<u8>) -> bool {
    matches!(first, Some(0x15 | 0x16))
}

/// The trust store for `wss://`: Mozilla's roots compiled into the binary (the
/// sandboxed worker reads no CA file) plus the operator's extra CA, if any.
fn tls_config(extra_ca_pem: Option<&str>) -> Result<rustls::ClientConfig, String> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::CertificateDer;
    let mut roots = rustls::RootCertStore {
        roots: webpki_roots::TLS_SERVER_ROOTS.to_vec(),
    };
    if let Some(pem) = extra_ca_pem {
        let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(pem.as_bytes())
            .collect::<Result<_, _>>()
            .map_err(|e| {
                format!("the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) is not valid PEM: {e}")
            })?;
        if certs.is_empty() {
            return Err(
                "the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) holds no `-----BEGIN CERTIFICATE-----` block"
                    .into(),
            );
        }
        for c in certs {
            roots.add(c).map_err(|e| {
                format!("the extra CA (extra_ca_pem / $D3IL_EXTRA_CA_FILE) is not a usable CA certificate: {e}")
            })?;
        }
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    Ok(rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS set-up failed: {e}"))?
        .with_root_certificates(roots)
        .with_no_client_auth())
}

/// A submitter-facing explanation of a failed TLS handshake with `host`.
fn tls_error(
    e: io::Error,
    url: &str,
    host: &str,
    deadline: Duration,
    first_byte: Option<u8>,
) -> PolicyError {
    use rustls::{CertificateError as C, Error as R};
    if matches!(
        e.kind(),
        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
    ) {
        return PolicyError::Late {
            request: "TLS handshake".into(),
            deadline_ms: deadline.as_millis() as u64,
        };
    }
    let tls = |reason: String| PolicyError::Tls {
        url: url.into(),
        reason,
    };
    let Some(r) = e.get_ref().and_then(|i| i.downcast_ref::<R>()) else {
        return match e.kind() {
            io::ErrorKind::UnexpectedEof
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe => PolicyError::Connect {
                url: url.into(),
                reason: format!(
                    "the server closed the connection during the TLS handshake ({e}); if it serves plain WebSocket, use ws:// instead of wss://"
                ),
            },
            _ => PolicyError::Connect {
                url: url.into(),
                reason: format!("TLS handshake: {e}"),
            },
        };
    };
    match r {
        R::InvalidCertificate(c) => {
            let hint = match c {
                C::UnknownIssuer | C::BadSignature => "it is not signed by a publicly trusted CA (a self-signed or private-CA certificate?); use a certificate from a public CA such as Let's Encrypt and serve its full chain (intermediates included)".to_string(),
                C::NotValidForName | C::NotValidForNameContext { .. } => format!(
                    "it does not name `{host}`; serve a certificate whose subject alternative names include `{host}`, or use the host name the certificate is for in the URL"
                ),
                C::Expired | C::ExpiredContext { .. } => "it has expired; renew it".into(),
                C::NotValidYet | C::NotValidYetContext { .. } => {
                    "it is not valid yet (check the server's clock)".into()
                }
                _ => "serve a valid certificate from a public CA for this host".into(),
            };
            tls(format!(
                "the endpoint's TLS certificate is not valid for host `{host}`: {r}; {hint}"
            ))
        }
        R::InvalidMessage(_) | R::InappropriateHandshakeMessage { .. } | R::InappropriateMessage { .. }
            if !looks_like_tls(first_byte) =>
        {
            tls(format!(
                "the policy server at `{url}` did not answer with TLS ({r}); it seems to serve plain WebSocket: use ws:// instead of wss://, or serve TLS on this port"
            ))
        }
        other => tls(format!(
            "the TLS handshake with the policy server at `{url}` failed: {other}; serve TLS 1.2 or 1.3 with a certificate for `{host}` from a public CA"
        )),
    }
}

/// Addresses a public evaluator must not be pointed at (loopback, private,
/// link-local, CGNAT, unique-local, multicast, unspecified, documentation).
pub fn is_private(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v) => {
            let o = v.octets();
            v.is_loopback()
                || v.is_private()
                || v.is_link_local()
                || v.is_unspecified()
                || v.is_multicast()
                || v.is_broadcast()
                || v.is_documentation()
                || o[0] == 0
                || (o[0] == 100 && (o[1] & 0xc0) == 64)
                || (o[0] == 198 && (o[1] & 0xfe) == 18)
                || (o[0] == 192 && o[1] == 0 && o[2] == 0)
                || o[0] >= 240
        }
        IpAddr::V6(v) => {
            if let Some(v4) = v.to_ipv4_mapped() {
                return is_private(IpAddr::V4(v4));
            }
            let s = v.segments();
            // NAT64 (64:ff9b::/96) embeds an IPv4 address in the low 32 bits.
            if s[0] == 0x64 && s[1] == 0xff9b && s[2..6] == [0, 0, 0, 0] {
                let v4 = std::net::Ipv4Addr::new(
                    (s[6] >> 8) as u8,
                    s[6] as u8,
                    (s[7] >> 8) as u8,
                    s[7] as u8,
                );
                return is_private(IpAddr::V4(v4));
            }
            v.is_loopback()
                || v.is_unspecified()
                || v.is_multicast()
                || (s[0] & 0xfe00) == 0xfc00
                || (s[0] & 0xffc0) == 0xfe80
        }
    }
}

pub struct RemotePolicy {
    ws: WebSocket<Transport>,
    url: String,
    shape: PolicyShape,
    deadline: Duration,
    frame_limit: u64,
    next_id: u64,
    broken: bool,
}

impl std::fmt::Debug for RemotePolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemotePolicy")
            .field("url", &self.url)
            .field("shape", &self.shape)
            .finish()
    }
}

/// Map a tungstenite error during `request` to a submitter-facing error.
fn ws_error(e: tungstenite::Error, request: &str, deadline: Duration, limit: u64) -> PolicyError {
    use tungstenite::Error as E;
    let late = || PolicyError::Late {
        request: request.into(),
        deadline_ms: deadline.as_millis() as u64,
    };
    let gone = |detail: String| PolicyError::Disconnected {
        request: request.into(),
        detail,
    };
    match e {
        E::Io(io)
            if matches!(
                io.kind(),
                io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
            ) =>
        {
            late()
        }
        E::Io(io) => gone(format!(" ({io})")),
        E::ConnectionClosed | E::AlreadyClosed => gone(String::new()),
        E::Capacity(_) => PolicyError::Oversized {
            request: request.into(),
            limit,
        },
        E::Protocol(tungstenite::error::ProtocolError::ResetWithoutClosingHandshake) => {
            gone(" without a closing handshake".into())
        }
        other => PolicyError::Malformed {
            request: request.into(),
            reason: format!("WebSocket error: {other}"),
        },
    }
}

impl RemotePolicy {
    /// Connect, read the server's hello, send the task spec and wait until the
    /// server is ready. Every step is bounded by `limits.remote_deadline_ms`.
    pub fn connect(
        url: &str,
        task: &TaskSpec,
        obs_type: ObsType,
        seed: u64,
        limits: &Limits,
    ) -> Result<Self, PolicyError> {
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
        let deadline = Duration::from_millis(limits.remote_deadline_ms.max(1));
        let frame_limit = limits.remote_frame_bytes.max(1024);

        let addrs: Vec<SocketAddr> = (host.as_str(), port)
            .to_socket_addrs()
            .map_err(|e| PolicyError::Connect {
                url: url.into(),
                reason: format!("cannot resolve `{host}` ({e})"),
            })?
            .collect();
        // Check every resolved address, then connect to a checked one (no second
        // lookup that could answer differently).
        let addr = addrs
            .iter()
            .copied()
            .find(|a| limits.allow_private_endpoints || !is_private(a.ip()))
            .ok_or_else(|| {
                if addrs.is_empty() {
                    bad(format!("`{host}` resolves to no address"))
                } else {
                    bad(format!(
                        "`{host}` resolves to {} which is a loopback/private/reserved address; endpoints must be public",
                        addrs[0].ip()
                    ))
                }
            })?;
        let tcp =
            TcpStream::connect_timeout(&addr, deadline).map_err(|e| PolicyError::Connect {
                url: url.into(),
                reason: e.to_string(),
            })?;
        let _ = tcp.set_nodelay(true);
        // One deadline covers the TLS handshake (wss://) and the WebSocket handshake.
        let first_byte = Arc::new(OnceLock::new());
        let stream = DeadlineStream {
            inner: tcp,
            deadline: Instant::now() + deadline,
            first_byte: Arc::clone(&first_byte),
        };
        let stream = if tls {
            // In a sandboxed worker the parent has put $D3IL_EXTRA_CA_FILE into
            // the job (and removed the variable); an unsandboxed run reads it here.
            let env_ca = match &limits.extra_ca_pem {
                Some(_) => None,
                None => Limits::extra_ca_from_env().map_err(PolicyError::Config)?,
            };
            let extra_ca = limits.extra_ca_pem.as_deref().or(env_ca.as_deref());
            let config = tls_config(extra_ca).map_err(PolicyError::Config)?;
            let name = rustls::pki_types::ServerName::try_from(host.clone())
                .map_err(|e| bad(format!("`{host}` is not a valid TLS server name ({e})")))?;
            let conn = rustls::ClientConnection::new(Arc::new(config), name).map_err(|e| {
                PolicyError::Connect {
                    url: url.into(),
                    reason: format!("TLS set-up failed: {e}"),
                }
            })?;
            let mut t = rustls::StreamOwned::new(conn, stream);
            while t.conn.is_handshaking() {
                if let Err(e) = t.conn.complete_io(&mut t.sock) {
                    return Err(tls_error(
                        e,
                        url,
                        &host,
                        deadline,
                        first_byte.get().copied(),
                    ));
                }
            }
            Transport::Tls(Box::new(t))
        } else {
            Transport::Plain(stream)
        };
        let limit = usize::try_from(frame_limit).unwrap_or(usize::MAX);
        let config = WebSocketConfig::default()
            .max_message_size(Some(limit))
            .max_frame_size(Some(limit));
        let (ws, _resp) = tungstenite::client::client_with_config(url, stream, Some(config))
            .map_err(|e| match e {
                tungstenite::HandshakeError::Failure(_) if !tls && looks_like_tls(first_byte.get().copied()) => {
                    PolicyError::Tls {
                        url: url.into(),
                        reason: format!(
                            "the policy server at `{url}` answered with TLS; use wss:// instead of ws://"
                        ),
                    }
                }
                tungstenite::HandshakeError::Failure(e)
                    if !tls && first_byte.get().is_none() && closed_silently(&e) =>
                {
                    // What a TLS-only server does with a plain HTTP request.
                    PolicyError::Connect {
                        url: url.into(),
                        reason: format!(
                            "the server closed the connection without answering the WebSocket handshake ({e}); if it serves TLS, use wss:// instead of ws://"
                        ),
                    }
                }
                tungstenite::HandshakeError::Failure(e) => {
                    match ws_error(e, "WebSocket handshake", deadline, frame_limit) {
                        PolicyError::Malformed { reason, .. } => PolicyError::Connect {
                            url: url.into(),
                            reason,
                        },
                        other => other,
                    }
                }
                tungstenite::HandshakeError::Interrupted(_) => PolicyError::Late {
                    request: "WebSocket handshake".into(),
                    deadline_ms: deadline.as_millis() as u64,
                },
            })?;
        let mut p = RemotePolicy {
            ws,
            url: url.into(),
            shape: PolicyShape {
                history: 1,
                horizon: 1,
                execute: 1,
                obs_dim: task.obs_dim,
                act_dim: task.act_dim,
                obs_type,
            },
            deadline,
            frame_limit,
            next_id: 0,
            broken: false,
        };
        p.ws.get_mut().set_deadline(Instant::now() + deadline);
        let hello = p.receive("hello")?;
        p.expect_type(&hello, "hello", "hello")?;
        let malformed = |reason: String| PolicyError::Malformed {
            request: "hello".into(),
            reason,
        };
        let version = wire::get_u64(&hello, "protocol").map_err(malformed)?;
        if version != PROTOCOL_VERSION {
            return Err(PolicyError::ProtocolVersion {
                got: version,
                expected: PROTOCOL_VERSION,
            });
        }
        let k = wire::get_u64(&hello, "history").map_err(malformed)?;
        let h = wire::get_u64(&hello, "horizon").map_err(malformed)?;
        let e = wire::get_u64(&hello, "execute").map_err(malformed)?;
        if !(1..=MAX_HISTORY).contains(&k)
            || !(1..=MAX_HORIZON).contains(&h)
            || !(1..=h).contains(&e)
        {
            return Err(malformed(format!(
                "announced history {k}, horizon {h}, execute {e}; need 1 ≤ history ≤ {MAX_HISTORY}, 1 ≤ execute ≤ horizon ≤ {MAX_HORIZON}"
            )));
        }
        p.shape.history = k as usize;
        p.shape.horizon = h as usize;
        p.shape.execute = e as usize;

        let mut spec = vec![
            ("type", Value::from("spec")),
            ("protocol", Value::from(PROTOCOL_VERSION)),
            ("task", Value::from(task.task.slug())),
            ("obs_type", Value::from(obs_type.as_str())),
            ("obs_dim", Value::from(task.obs_dim as u64)),
            ("act_dim", Value::from(task.act_dim as u64)),
            ("max_steps", Value::from(task.max_steps as u64)),
            ("n_behaviours", Value::from(task.n_behaviours as u64)),
            ("seed", Value::from(seed)),
        ];
        if obs_type == ObsType::Image {
            spec.push((
                "image_shape",
                Value::Array(IMAGE_SHAPE.iter().map(|&d| Value::from(d as u64)).collect()),
            ));
        }
        let reply = p.request("spec", wire::map(spec))?;
        p.expect_type(&reply, "ready", "spec")?;
        Ok(p)
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn expect_type(&mut self, v: &Value, want: &str, request: &str) -> Result<(), PolicyError> {
        let t = wire::get_str(v, "type").map_err(|reason| {
            self.broken = true;
            PolicyError::Malformed {
                request: request.into(),
                reason,
            }
        })?;
        if t == "error" {
            self.broken = true;
            let message = wire::get_str(v, "message")
                .unwrap_or("(no message)")
                .chars()
                .take(2000)
                .collect();
            return Err(PolicyError::ServerError {
                request: request.into(),
                message,
            });
        }
        if t != want {
            self.broken = true;
            return Err(PolicyError::Malformed {
                request: request.into(),
                reason: format!("expected a `{want}` message, got `{t}`"),
            });
        }
        Ok(())
    }

    /// Send one message and wait for the reply, all within one deadline.
    fn request(&mut self, request: &str, msg: Value) -> Result<Value, PolicyError> {
        if self.broken {
            return Err(PolicyError::Disconnected {
                request: request.into(),
                detail: " (the connection was already unusable after an earlier error)".into(),
            });
        }
        self.ws
            .get_mut()
            .set_deadline(Instant::now() + self.deadline);
        let (deadline, limit) = (self.deadline, self.frame_limit);
        if let Err(e) = self.ws.send(Message::Binary(wire::encode(&msg).into())) {
            self.broken = true;
            return Err(ws_error(e, request, deadline, limit));
        }
        self.receive(request)
    }

    /// Read the next data frame (pings are answered by tungstenite).
    fn receive(&mut self, request: &str) -> Result<Value, PolicyError> {
        let (deadline, limit) = (self.deadline, self.frame_limit);
        loop {
            let msg = match self.ws.read() {
                Ok(m) => m,
                Err(e) => {
                    self.broken = true;
                    return Err(ws_error(e, request, deadline, limit));
                }
            };
            let bytes = match msg {
                Message::Binary(b) => b,
                Message::Ping(_) | Message::Pong(_) | Message::Frame(_) => continue,
                Message::Text(_) => {
                    self.broken = true;
                    return Err(PolicyError::Malformed {
                        request: request.into(),
                        reason: "got a text frame; every message must be a binary msgpack frame"
                            .into(),
                    });
                }
                Message::Close(c) => {
                    self.broken = true;
                    return Err(PolicyError::Disconnected {
                        request: request.into(),
                        detail: c
                            .map(|c| format!(" (close code {}: {})", u16::from(c.code), c.reason))
                            .unwrap_or_default(),
                    });
                }
            };
            return wire::decode(&bytes).map_err(|reason| {
                self.broken = true;
                PolicyError::Malformed {
                    request: request.into(),
                    reason,
                }
            });
        }
    }
}

impl Policy for RemotePolicy {
    fn shape(&self) -> PolicyShape {
        self.shape
    }

    fn reset(&mut self, rollout_ids: &[u64]) -> Result<(), PolicyError> {
        let msg = wire::map(vec![
            ("type", Value::from("reset")),
            ("rollout_ids", wire::u64_array(rollout_ids)),
        ]);
        let reply = self.request("reset", msg)?;
        self.expect_type(&reply, "ok", "reset")
    }

    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        q.check(&self.shape)?;
        let s = self.shape;
        let b = q.batch();
        self.next_id += 1;
        let id = self.next_id;
        let mut fields = vec![
            ("type", Value::from("infer")),
            ("id", Value::from(id)),
            ("rollout_ids", wire::u64_array(q.rollout_ids)),
            ("steps", wire::u64_array(q.steps)),
            ("obs", wire::encode_f32(&[b, s.history, s.obs_dim], q.obs)),
        ];
        if let (ObsType::Image, Some(images)) = (s.obs_type, q.images) {
            let mut shape = vec![b, s.history];
            shape.extend_from_slice(&IMAGE_SHAPE);
            fields.push(("images", wire::encode_f32(&shape, images)));
        }
        let reply = self.request("infer", wire::map(fields))?;
        self.expect_type(&reply, "actions", "infer")?;
        let malformed = |reason: String| PolicyError::Malformed {
            request: "infer".into(),
            reason,
        };
        let got_id = wire::get_u64(&reply, "id").map_err(malformed)?;
        if got_id != id {
            self.broken = true;
            return Err(malformed(format!(
                "reply is for request {got_id} but request {id} was sent"
            )));
        }
        let arr = wire::get(&reply, "actions")
            .ok_or_else(|| malformed("missing field `actions`".into()))?;
        let (shape, data) =
            wire::decode_f32(arr).map_err(|r| malformed(format!("field `actions`: {r}")))?;
        let ok = match shape.as_slice() {
            [bb, a] => *bb == b && *a == s.act_dim && s.horizon == 1,
            [bb, h, a] => *bb == b && *h == s.horizon && *a == s.act_dim,
            _ => false,
        };
        if !ok {
            return Err(PolicyError::WrongShape {
                got: format!("actions {shape:?}"),
                expected: format!("[{b}, {}, {}]", s.horizon, s.act_dim),
                batch: b,
                rollout: q.rollout_ids.first().copied().unwrap_or(0),
                step: q.steps.first().copied().unwrap_or(0),
            });
        }
        Ok(ActionChunks {
            batch: b,
            horizon: s.horizon,
            act_dim: s.act_dim,
            data,
        })
    }
}

impl Drop for RemotePolicy {
    fn drop(&mut self) {
        if !self.broken {
            // Best effort: tell the server we are done, without waiting long.
            self.ws
                .get_mut()
                .set_deadline(Instant::now() + Duration::from_millis(200));
            let _ = self.ws.close(None);
            let _ = self.ws.flush();
            if let Transport::Tls(t) = self.ws.get_mut() {
                t.conn.send_close_notify();
                let _ = t.flush();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn private_ranges() {
        for a in [
            "127.0.0.1",
            "10.1.2.3",
            "172.16.0.1",
            "192.168.1.1",
            "169.254.1.1",
            "100.64.0.1",
            "0.0.0.0",
            "::1",
            "fd00::1",
            "fe80::1",
            "::ffff:127.0.0.1",
            "64:ff9b::a00:1",
            "192.0.0.8",
            "240.0.0.1",
            "198.18.0.1",
        ] {
            assert!(is_private(a.parse().unwrap()), "{a}");
        }
        for a in ["8.8.8.8", "1.1.1.1", "2606:4700::1111", "64:ff9b::808:808"] {
            assert!(!is_private(a.parse().unwrap()), "{a}");
        }
    }

    #[test]
    fn refuses_private_endpoints_by_default() {
        let spec = TaskSpec {
            task: d3il_protocol::TaskId::Avoiding,
            obs_dim: 4,
            act_dim: 2,
            max_steps: 250,
            n_behaviours: 24,
        };
        let e = RemotePolicy::connect(
            "ws://127.0.0.1:9/",
            &spec,
            ObsType::State,
            0,
            &Limits::default(),
        )
        .unwrap_err();
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadEndpoint);
        assert!(e.to_string().contains("loopback/private"), "{e}");
        // wss:// gets the same address checks before any TLS.
        let e = RemotePolicy::connect(
            "wss://127.0.0.1:9/",
            &spec,
            ObsType::State,
            0,
            &Limits::default(),
        )
        .unwrap_err();
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadEndpoint);
        assert!(e.to_string().contains("loopback/private"), "{e}");
        let e = RemotePolicy::connect("http://x/", &spec, ObsType::State, 0, &Limits::default())
            .unwrap_err();
        assert!(e.to_string().contains("use ws:// or wss://"), "{e}");
    }

    #[test]
    fn extra_ca_must_be_pem_certificates() {
        assert!(tls_config(None).is_ok());
        let e = tls_config(Some("not a certificate")).unwrap_err();
        assert!(
            e.contains("holds no `-----BEGIN CERTIFICATE-----` block"),
            "{e}"
        );
        let e = tls_config(Some(
            "-----BEGIN CERTIFICATE-----\nbm90IGEgY2VydA==\n-----END CERTIFICATE-----\n",
        ))
        .unwrap_err();
        assert!(e.contains("not a usable CA certificate"), "{e}");
    }
}

//! The WebSocket session: the opening handshake (with the ws/wss mismatch
//! diagnoses), the hello/spec exchange of docs/remote-protocol.md, and one
//! request/reply under the per-request deadline and frame cap.

use super::tls::looks_like_tls;
use super::transport::Transport;
use super::RemotePolicy;
use crate::wire::{self, PROTOCOL_VERSION};
use crate::{PolicyError, IMAGE_SHAPE};
use d3il_protocol::{EndpointSecret, ObsType, TaskSpec};
use rmpv::Value;
use std::io;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::http::header::{HeaderValue, AUTHORIZATION};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

/// Largest k and H a server may announce (far above any D3IL baseline).
const MAX_HISTORY: u64 = d3il_protocol::PolicyManifest::MAX_HISTORY as u64;
const MAX_HORIZON: u64 = d3il_protocol::PolicyManifest::MAX_HORIZON as u64;

/// The WebSocket opening handshake over `stream`, within the stream's
/// deadline; with `secret`, the request carries `Authorization: Bearer
/// <secret>` (docs/remote-protocol.md, "Shared secret").
pub(super) fn open(
    url: &str,
    secret: Option<&EndpointSecret>,
    stream: Transport,
    tls: bool,
    first_byte: &Arc<OnceLock<u8>>,
    deadline: Duration,
    frame_limit: u64,
) -> Result<WebSocket<Transport>, PolicyError> {
    let limit = usize::try_from(frame_limit).unwrap_or(usize::MAX);
    let config = WebSocketConfig::default()
        .max_message_size(Some(limit))
        .max_frame_size(Some(limit));
    let mut request = url
        .into_client_request()
        .map_err(|e| PolicyError::BadEndpoint {
            url: url.into(),
            reason: format!("not a WebSocket URL ({e}); use ws://host:port/path"),
        })?;
    if let Some(secret) = secret {
        let value = HeaderValue::from_str(&format!("Bearer {}", secret.expose())).map_err(|_| {
            PolicyError::BadEndpoint {
                url: url.into(),
                reason: "the endpoint secret is not a valid header value; use visible ASCII characters only".into(),
            }
        })?;
        request.headers_mut().insert(AUTHORIZATION, value);
    }
    let (ws, _resp) = tungstenite::client::client_with_config(request, stream, Some(config))
        .map_err(|e| match e {
            tungstenite::HandshakeError::Failure(tungstenite::Error::Http(resp))
                if matches!(resp.status().as_u16(), 401 | 403) =>
            {
                PolicyError::Unauthorized {
                    url: url.into(),
                    status: resp.status().as_u16(),
                    answer: answer_text(resp.body().as_deref()),
                    sent_secret: secret.is_some(),
                }
            }
            tungstenite::HandshakeError::Failure(_)
                if !tls && looks_like_tls(first_byte.get().copied()) =>
            {
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
    Ok(ws)
}

/// ": " and the first line of a refusal's body (at most 200 characters,
/// control characters dropped), or nothing when it has no text.
fn answer_text(body: Option<&[u8]>) -> String {
    let text = String::from_utf8_lossy(body.unwrap_or_default());
    let line: String = text
        .lines()
        .next()
        .unwrap_or_default()
        .chars()
        .filter(|c| !c.is_control())
        .take(200)
        .collect();
    let line = line.trim();
    if line.is_empty() {
        String::new()
    } else {
        format!(": {line}")
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
    /// Read the server's hello (its k, H, E), send the task spec and wait
    /// until the server is ready.
    pub(super) fn greet(
        &mut self,
        task: &TaskSpec,
        obs_type: ObsType,
        seed: u64,
    ) -> Result<(), PolicyError> {
        self.ws
            .get_mut()
            .set_deadline(Instant::now() + self.deadline);
        let hello = self.receive("hello")?;
        self.expect_type(&hello, "hello", "hello")?;
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
        self.shape.history = k as usize;
        self.shape.horizon = h as usize;
        self.shape.execute = e as usize;

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
        let reply = self.request("spec", wire::map(spec))?;
        self.expect_type(&reply, "ready", "spec")
    }

    pub(super) fn expect_type(
        &mut self,
        v: &Value,
        want: &str,
        request: &str,
    ) -> Result<(), PolicyError> {
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
    pub(super) fn request(&mut self, request: &str, msg: Value) -> Result<Value, PolicyError> {
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
    pub(super) fn receive(&mut self, request: &str) -> Result<Value, PolicyError> {
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

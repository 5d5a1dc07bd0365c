//! Client for remote policy servers (docs/remote-protocol.md): a blocking
//! WebSocket with msgpack frames, a deadline on every request and a cap on the
//! size of every reply.
//!
//! - [`transport`]: URL, address check, TCP and the deadline stream;
//! - [`tls`]: `wss://` trust store, handshake and its error messages;
//! - [`session`]: WebSocket handshake, hello/spec, request/reply.

mod session;
mod tls;
mod transport;

use crate::wire;
use crate::{ActionChunks, Policy, PolicyError, PolicyShape, Query, IMAGE_SHAPE};
use d3il_protocol::{EndpointSecret, Limits, ObsType, TaskSpec};
use rmpv::Value;
use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};
use transport::{Endpoint, Transport};
use tungstenite::WebSocket;

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

impl RemotePolicy {
    /// Connect (sending `secret` in the handshake, if any), read the
    /// server's hello, send the task spec and wait until the server is ready.
    /// Every step is bounded by `limits.remote_deadline_ms`.
    pub fn connect(
        url: &str,
        secret: Option<&EndpointSecret>,
        task: &TaskSpec,
        obs_type: ObsType,
        seed: u64,
        limits: &Limits,
    ) -> Result<Self, PolicyError> {
        let ep = Endpoint::parse(url)?;
        let deadline = Duration::from_millis(limits.remote_deadline_ms.max(1));
        let frame_limit = limits.remote_frame_bytes.max(1024);
        // One deadline covers the TLS handshake (wss://) and the WebSocket handshake.
        let stream = transport::connect_tcp(url, &ep, limits, deadline)?;
        let first_byte = Arc::clone(&stream.first_byte);
        let stream = if ep.tls {
            tls::handshake(url, &ep, stream, limits, deadline)?
        } else {
            Transport::Plain(stream)
        };
        let ws = session::open(
            url,
            secret,
            stream,
            ep.tls,
            &first_byte,
            deadline,
            frame_limit,
        )?;
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
        p.greet(task, obs_type, seed)?;
        Ok(p)
    }

    pub fn url(&self) -> &str {
        &self.url
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
    use tls::tls_config;

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
            None,
            &spec,
            ObsType::State,
            0,
            &Limits::default(),
        )
        .unwrap_err();
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadEndpoint);
        assert!(e.to_string().contains("loopback/private"), "{e}");
        // Every IPv6 form of loopback is refused the same way.
        for u in [
            "ws://[::ffff:127.0.0.1]:9/",
            "ws://[::127.0.0.1]:9/",
            "ws://[64:ff9b::7f00:1]:9/",
        ] {
            let e = RemotePolicy::connect(u, None, &spec, ObsType::State, 0, &Limits::default())
                .unwrap_err();
            assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadEndpoint, "{u}");
            assert!(e.to_string().contains("loopback/private"), "{u}: {e}");
        }
        // wss:// gets the same address checks before any TLS.
        let e = RemotePolicy::connect(
            "wss://127.0.0.1:9/",
            None,
            &spec,
            ObsType::State,
            0,
            &Limits::default(),
        )
        .unwrap_err();
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadEndpoint);
        assert!(e.to_string().contains("loopback/private"), "{e}");
        let e = RemotePolicy::connect(
            "http://x/",
            None,
            &spec,
            ObsType::State,
            0,
            &Limits::default(),
        )
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

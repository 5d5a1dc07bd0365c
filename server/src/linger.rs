//! Reading on after an early answer (a "lingering close").
//!
//! Uploads are refused before their file is read (the quota, the method's
//! owner, a duplicate seed, the disk quota: `intake::upload`), so a refused
//! request costs no disk. But a client that sends the whole body before it
//! reads the answer (`d3il submit`, the Python client, browsers) is still
//! writing when the answer comes; if the server then closed with unread
//! bytes, the kernel would reset the connection and the client would see a
//! broken pipe instead of the answer. So a request body the handler dropped
//! unread is read to its end and discarded by a background task while the
//! answer goes out: the client finishes sending, reads the answer, and the
//! connection stays usable.
//!
//! Bounded: at most `cap` bytes (the upload limit; a body declared longer is
//! not read at all), and it stops when the client sends nothing for `idle`
//! or, sending or not, when `deadline` has passed since the drain began
//! (a client trickling a byte now and then holds the connection no
//! longer than that). Until it stops, the connection keeps its place under
//! the server's and its client's connection caps (`app::serve_listener`).
//! A request with `Expect: 100-continue` is not read on: its client sends
//! the body only when asked, and an early answer tells it not to.

use hyper::body::{Body, Bytes, Frame, Incoming, SizeHint};
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

/// How far a drain reads on.
#[derive(Debug, Clone)]
pub struct LingerLimits {
    /// Bytes at most.
    pub cap: u64,
    /// Stop when nothing arrives for this long.
    pub idle: Duration,
    /// Stop this long after the drain began, whatever arrives.
    pub deadline: Duration,
    /// Counts the drains cut off at `deadline` (`/metrics`:
    /// `d3il_rate_limit_refusals_total{limit="linger_deadline"}`).
    pub cut: prometheus_client::metrics::counter::Counter,
}

/// A request body that, when dropped before its end, is drained in the
/// background (see the module documentation).
pub struct LingeringBody {
    inner: Option<Incoming>,
    limits: LingerLimits,
}

impl LingeringBody {
    /// Wraps the body of a request; `linger` false (the request asked
    /// `Expect: 100-continue`) drops an unread body as hyper does.
    pub fn new(inner: Incoming, linger: bool, limits: LingerLimits) -> LingeringBody {
        LingeringBody {
            inner: Some(inner),
            limits: LingerLimits {
                cap: if linger { limits.cap } else { 0 },
                ..limits
            },
        }
    }

    /// Whether `req` lets the server read its body unasked.
    pub fn may_linger<B>(req: &axum::http::Request<B>) -> bool {
        !req.headers()
            .get(axum::http::header::EXPECT)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.trim().eq_ignore_ascii_case("100-continue"))
    }
}

impl Body for LingeringBody {
    type Data = Bytes;
    type Error = hyper::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, hyper::Error>>> {
        match self.get_mut().inner.as_mut() {
            Some(b) => Pin::new(b).poll_frame(cx),
            None => Poll::Ready(None),
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.as_ref().is_none_or(Body::is_end_stream)
    }

    fn size_hint(&self) -> SizeHint {
        self.inner
            .as_ref()
            .map(Body::size_hint)
            .unwrap_or_else(|| SizeHint::with_exact(0))
    }
}

impl Drop for LingeringBody {
    fn drop(&mut self) {
        let Some(body) = self.inner.take() else {
            return;
        };
        let cap = self.limits.cap;
        if body.is_end_stream() || cap == 0 || body.size_hint().lower() > cap {
            return;
        }
        // Dropped outside a runtime (never in the server): nothing to linger on.
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            rt.spawn(drain(body, self.limits.clone()));
        }
    }
}

/// Reads `body` to its end, discarding it, unless it passes `cap` bytes,
/// nothing arrives for `idle` or `deadline` passes; then drops it (hyper
/// closes the connection).
async fn drain(mut body: Incoming, limits: LingerLimits) {
    let LingerLimits {
        cap,
        idle,
        deadline,
        cut,
    } = limits;
    let end = tokio::time::Instant::now() + deadline;
    let mut read = 0u64;
    loop {
        let frame = std::future::poll_fn(|cx| Pin::new(&mut body).poll_frame(cx));
        let wait = idle.min(end.saturating_duration_since(tokio::time::Instant::now()));
        if wait.is_zero() {
            tracing::debug!("stopped reading an unread request body after {deadline:?} in all");
            cut.inc();
            return;
        }
        match tokio::time::timeout(wait, frame).await {
            Ok(Some(Ok(f))) => {
                read += f.data_ref().map_or(0, |d| d.len() as u64);
                if read > cap {
                    tracing::debug!("stopped reading an unread request body past {cap} bytes");
                    return;
                }
            }
            Ok(None) | Ok(Some(Err(_))) => return,
            Err(_) => {
                tracing::debug!(
                    "stopped reading an unread request body (idle for {idle:?}, or {deadline:?} in all)"
                );
                if tokio::time::Instant::now() >= end {
                    cut.inc();
                }
                return;
            }
        }
    }
}

//! Rate limits with a fixed one-minute window: per API token
//! ([`RateLimiter`]), and per client address for anonymous requests and
//! failed token checks ([`ClientLimits`]). Clients over a limit get 429 with
//! `Retry-After` (seconds until the window resets).

use std::collections::HashMap;
use std::hash::Hash;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

const WINDOW: Duration = Duration::from_secs(60);

/// Keys kept before windows that are over are pruned (bounds the memory an
/// attacker with many addresses can make us hold).
const PRUNE_AT: usize = 10_000;

pub struct RateLimiter<K = i64> {
    per_window: u32,
    windows: Mutex<HashMap<K, (Instant, u32)>>,
    /// Requests refused by this limit (`/metrics`).
    pub refusals: prometheus_client::metrics::counter::Counter,
}

impl<K: Hash + Eq + Copy> RateLimiter<K> {
    pub fn new(per_minute: u32) -> Self {
        RateLimiter {
            per_window: per_minute,
            windows: Mutex::new(HashMap::new()),
            refusals: Default::default(),
        }
    }

    /// The configured requests per minute.
    pub fn per_minute(&self) -> u32 {
        self.per_window
    }

    /// Counts one request for `key`; `Err(seconds)` when over the limit
    /// (the request is refused).
    pub fn check(&self, key: K) -> Result<(), u64> {
        self.count(key, 1).inspect_err(|_| {
            self.refusals.inc();
        })
    }

    /// `Err(seconds)` if `key` is over the limit now (the request is
    /// refused), without counting.
    pub fn peek(&self, key: K) -> Result<(), u64> {
        self.count(key, 0).inspect_err(|_| {
            self.refusals.inc();
        })
    }

    /// Counts one event for `key` that refuses nothing (a failed token
    /// check already answered 401).
    pub fn record(&self, key: K) {
        let _ = self.count(key, 1);
    }

    fn count(&self, key: K, n: u32) -> Result<(), u64> {
        let now = Instant::now();
        let mut w = self.windows.lock().unwrap_or_else(|p| p.into_inner());
        if w.len() >= PRUNE_AT {
            w.retain(|_, (start, _)| now.duration_since(*start) < WINDOW);
        }
        let entry = w.entry(key).or_insert((now, 0));
        if now.duration_since(entry.0) >= WINDOW {
            *entry = (now, 0);
        }
        if entry.1 >= self.per_window {
            let left = WINDOW.saturating_sub(now.duration_since(entry.0));
            return Err(left.as_secs().max(1));
        }
        entry.1 += n;
        Ok(())
    }
}

/// The per-address limits: requests without credentials, and failed token
/// checks (past that limit the address's credentialed requests get 429
/// until its minute is over, so tokens cannot be guessed quickly).
pub struct ClientLimits {
    pub anonymous: RateLimiter<IpAddr>,
    pub failed_auth: RateLimiter<IpAddr>,
}

impl ClientLimits {
    pub fn new(anonymous_per_minute: u32, failed_auth_per_minute: u32) -> Self {
        ClientLimits {
            anonymous: RateLimiter::new(anonymous_per_minute),
            failed_auth: RateLimiter::new(failed_auth_per_minute),
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn refuses_after_the_limit_with_a_retry_time() {
        let r = super::RateLimiter::new(2);
        assert!(r.check(1).is_ok());
        assert!(r.check(1).is_ok());
        let wait = r.check(1).unwrap_err();
        assert!((1..=60).contains(&wait));
        assert!(r.check(2).is_ok(), "limits are per token");
    }

    #[test]
    fn peek_does_not_count() {
        let r = super::RateLimiter::<u8>::new(1);
        for _ in 0..5 {
            assert!(r.peek(7).is_ok());
        }
        assert!(r.check(7).is_ok());
        assert!(r.peek(7).is_err());
    }
}

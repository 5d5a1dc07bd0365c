//! Per-token rate limiting: a fixed one-minute window per token. Clients over
//! the limit get 429 with `Retry-After` (seconds until the window resets).

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

const WINDOW: Duration = Duration::from_secs(60);

pub struct RateLimiter {
    per_window: u32,
    windows: Mutex<HashMap<i64, (Instant, u32)>>,
}

impl RateLimiter {
    pub fn new(per_minute: u32) -> Self {
        RateLimiter {
            per_window: per_minute,
            windows: Mutex::new(HashMap::new()),
        }
    }

    /// Counts one request for `token_id`; `Err(seconds)` when over the limit.
    pub fn check(&self, token_id: i64) -> Result<(), u64> {
        let now = Instant::now();
        let mut w = self.windows.lock().unwrap_or_else(|p| p.into_inner());
        let entry = w.entry(token_id).or_insert((now, 0));
        if now.duration_since(entry.0) >= WINDOW {
            *entry = (now, 0);
        }
        if entry.1 >= self.per_window {
            let left = WINDOW.saturating_sub(now.duration_since(entry.0));
            return Err(left.as_secs().max(1));
        }
        entry.1 += 1;
        Ok(())
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
}

//! Per-caller rate limit of mission submissions (docs/architecture.md,
//! "Overload"): a token bucket per caller, `burst` deep, refilled at
//! `per_minute`. A flood from one client is refused at once with
//! RESOURCE_EXHAUSTED and leaves other callers' budgets alone.
//!
//! This limits an API, so it reads the wall clock (`Instant`), passed in by
//! the caller; nothing a robot does depends on it.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Instant;

/// Callers remembered before idle (full) buckets are forgotten.
const MAX_CALLERS: usize = 10_000;

pub(crate) struct RateLimiter {
    per_second: f64,
    burst: f64,
    buckets: Mutex<HashMap<String, (f64, Instant)>>,
}

impl RateLimiter {
    /// `per_minute` = 0 admits everything.
    pub(crate) fn new(per_minute: u32, burst: u32) -> Self {
        Self { per_second: per_minute as f64 / 60.0, burst: burst.max(1) as f64, buckets: Mutex::new(HashMap::new()) }
    }

    /// Admits one request from `key` at `now`, or says how many seconds until
    /// one would be admitted.
    pub(crate) fn check(&self, key: &str, now: Instant) -> Result<(), f64> {
        if self.per_second <= 0.0 {
            return Ok(());
        }
        let mut buckets = self.buckets.lock().unwrap_or_else(|p| p.into_inner());
        if buckets.len() >= MAX_CALLERS && !buckets.contains_key(key) {
            let (rate, burst) = (self.per_second, self.burst);
            buckets.retain(|_, (tokens, at)| *tokens + now.saturating_duration_since(*at).as_secs_f64() * rate < burst);
        }
        let (tokens, at) = buckets.entry(key.to_string()).or_insert((self.burst, now));
        *tokens = (*tokens + now.saturating_duration_since(*at).as_secs_f64() * self.per_second).min(self.burst);
        *at = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err((1.0 - *tokens) / self.per_second)
        }
    }

    pub(crate) fn per_minute(&self) -> f64 {
        self.per_second * 60.0
    }

    pub(crate) fn burst(&self) -> u32 {
        self.burst as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_burst_is_admitted_then_the_rate_and_callers_are_apart() {
        let limit = RateLimiter::new(60, 3);
        let t0 = Instant::now();
        for _ in 0..3 {
            assert!(limit.check("alice", t0).is_ok());
        }
        let wait = limit.check("alice", t0).unwrap_err();
        assert!((wait - 1.0).abs() < 1e-9, "one a second: {wait}");
        assert!(limit.check("bob", t0).is_ok(), "another caller has its own budget");
        assert!(limit.check("alice", t0 + Duration::from_millis(500)).is_err());
        assert!(limit.check("alice", t0 + Duration::from_millis(1000)).is_ok());
        // A long pause refills to the burst, not beyond.
        let later = t0 + Duration::from_secs(3600);
        for _ in 0..3 {
            assert!(limit.check("alice", later).is_ok());
        }
        assert!(limit.check("alice", later).is_err());
    }

    #[test]
    fn zero_per_minute_admits_everything() {
        let limit = RateLimiter::new(0, 1);
        let t0 = Instant::now();
        assert!((0..1000).all(|_| limit.check("alice", t0).is_ok()));
    }
}

//! Doing something at most once per period, whatever the rate of what causes it: a component's status
//! published twice a second, a warning about recurring bad input logged once a second.

use std::time::{Duration, Instant};

/// How often a component publishes its status.
pub const STATUS_PERIOD: Duration = Duration::from_millis(500);
/// How often a warning about recurring bad input is logged.
pub const WARNING_PERIOD: Duration = Duration::from_secs(1);

/// When something last happened; it may happen again once a period has passed.
#[derive(Debug, Clone, Copy, Default)]
pub struct Throttle {
    last: Option<Instant>,
}

impl Throttle {
    /// Whether `period` has passed since the last yes (or there was none); a yes starts the next period.
    pub fn ready(&mut self, period: Duration) -> bool {
        self.ready_at(period, Instant::now())
    }

    /// [`Throttle::ready`] at `now`, for a caller that has read the clock already.
    pub fn ready_at(&mut self, period: Duration, now: Instant) -> bool {
        let ready = self
            .last
            .is_none_or(|at| now.saturating_duration_since(at) >= period);
        if ready {
            self.last = Some(now);
        }
        ready
    }

    /// Logs `message` as a warning if [`WARNING_PERIOD`] has passed since the last one it logged; the
    /// message is not even made otherwise.
    pub fn warn(&mut self, message: impl FnOnce() -> String) {
        if self.ready(WARNING_PERIOD) {
            tracing::warn!("{}", message());
        }
    }

    /// Makes the next [`Throttle::ready`] say yes.
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yes_once_per_period_and_again_after_a_reset() {
        let mut throttle = Throttle::default();
        assert!(throttle.ready(WARNING_PERIOD));
        assert!(!throttle.ready(WARNING_PERIOD));
        assert!(throttle.ready(Duration::ZERO));
        throttle.reset();
        assert!(throttle.ready(WARNING_PERIOD));
    }
}

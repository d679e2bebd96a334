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
        let ready = self.last.is_none_or(|at| at.elapsed() >= period);
        if ready {
            self.last = Some(Instant::now());
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

//! Time on the runtime clock.
//!
//! A [`Timestamp`] counts nanoseconds since the UNIX epoch on the runtime's clock. The real-time clock
//! reads the wall clock once at start and advances with the monotonic clock from then on, so timestamps
//! never go backwards within a run and still mean something across machines and recordings.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::signal::RunSignal;

/// A point in time on the runtime clock, in nanoseconds since the UNIX epoch.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
pub struct Timestamp(pub i64);

impl Timestamp {
    /// The earliest representable time; used as "never".
    pub const ZERO: Timestamp = Timestamp(0);

    /// From nanoseconds since the epoch.
    pub const fn from_nanos(nanos: i64) -> Self {
        Timestamp(nanos)
    }

    /// From microseconds since the epoch.
    pub const fn from_micros(micros: i64) -> Self {
        Timestamp(micros.saturating_mul(1_000))
    }

    /// From milliseconds since the epoch.
    pub const fn from_millis(millis: i64) -> Self {
        Timestamp(millis.saturating_mul(1_000_000))
    }

    /// From seconds since the epoch.
    pub fn from_secs_f64(secs: f64) -> Self {
        Timestamp((secs * 1e9) as i64)
    }

    /// Nanoseconds since the epoch.
    pub const fn as_nanos(self) -> i64 {
        self.0
    }

    /// Seconds since the epoch, as a float.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    /// `self - earlier` in nanoseconds (negative when `earlier` is later).
    #[inline]
    pub const fn nanos_since(self, earlier: Timestamp) -> i64 {
        self.0.saturating_sub(earlier.0)
    }

    /// This time moved forward by `duration`.
    #[must_use]
    pub fn after(self, duration: Duration) -> Timestamp {
        Timestamp(
            self.0
                .saturating_add(i64::try_from(duration.as_nanos()).unwrap_or(i64::MAX)),
        )
    }

    /// The duration from `earlier` to `self`, zero if `earlier` is later.
    pub fn duration_since(self, earlier: Timestamp) -> Duration {
        Duration::from_nanos(u64::try_from(self.nanos_since(earlier)).unwrap_or(0))
    }
}

impl fmt::Display for Timestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let secs = self.0.div_euclid(1_000_000_000);
        let nanos = self.0.rem_euclid(1_000_000_000);
        write!(f, "{secs}.{nanos:09}")
    }
}

/// The runtime's time base.
///
/// Real time today; replay-driven, external (e.g. GNSS) and network-synchronised clocks implement the same
/// trait, so components never know which one drives them.
pub trait Clock: Send + Sync + fmt::Debug {
    /// The current time.
    fn now(&self) -> Timestamp;

    /// Sleeps until `deadline` or until `signal` asks the caller to wake (stop, pause, a property change).
    /// Returns `true` if the deadline was reached.
    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool;

    /// A one-line description for logs and recordings (`real time, epoch 2026-…`).
    fn describe(&self) -> String;

    /// Takes a reference from the diagram's time source: at `measured_at` on this clock, the component
    /// `source` says the true time was `reference`. Only a clock disciplined by that component uses it;
    /// returns whether it did.
    fn take_reference(&self, source: &str, measured_at: Timestamp, reference: Timestamp) -> bool {
        let _ = (source, measured_at, reference);
        false
    }

    /// From now on the clock may not step, only slew: the diagram is running and deadlines are set.
    fn forbid_steps(&self) {}

    /// Where a disciplined clock stands, for telemetry; `None` for a clock that follows no source.
    fn status(&self) -> Option<crate::disciplined::ClockStatus> {
        None
    }

    /// Holds the clock still (`true`) or lets it go on (`false`), for a clock that stops with the diagram:
    /// simulated time stands still while the diagram is paused. Real time goes on; the default ignores it.
    fn hold(&self, held: bool) {
        let _ = held;
    }

    /// Whether waiting on the clock takes no real time: it jumps to the deadline (simulated time run as
    /// fast as possible). A thread with nothing to do until a deadline then waits on the clock rather
    /// than sleeping.
    fn jumps(&self) -> bool {
        false
    }
}

/// Real time: the wall clock read once at creation, advanced by the monotonic clock.
#[derive(Debug)]
pub struct RealTimeClock {
    start_instant: Instant,
    start_nanos: i64,
}

impl RealTimeClock {
    /// A clock starting now.
    pub fn new() -> Self {
        let since_epoch = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or(Duration::ZERO);
        RealTimeClock {
            start_instant: Instant::now(),
            start_nanos: i64::try_from(since_epoch.as_nanos()).unwrap_or(i64::MAX),
        }
    }

    /// A shared clock starting now.
    pub fn shared() -> Arc<dyn Clock> {
        Arc::new(Self::new())
    }
}

impl Default for RealTimeClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for RealTimeClock {
    fn now(&self) -> Timestamp {
        let elapsed = self.start_instant.elapsed().as_nanos();
        Timestamp(
            self.start_nanos
                .saturating_add(i64::try_from(elapsed).unwrap_or(i64::MAX)),
        )
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        wait_in_real_time(self, deadline, signal)
    }

    fn describe(&self) -> String {
        format!(
            "real time (monotonic, epoch read at start: {})",
            Timestamp(self.start_nanos)
        )
    }
}

/// Waits until `clock` (one that advances with real time) reaches `deadline`, parked meanwhile, or until
/// `signal` asks for attention (then `false`). Looks again after each wake-up, so a clock that is slewed or
/// stepped meanwhile is followed.
pub fn wait_in_real_time(clock: &dyn Clock, deadline: Timestamp, signal: &RunSignal) -> bool {
    loop {
        if signal.wants_attention() {
            return false;
        }
        let now = clock.now();
        if now >= deadline {
            return true;
        }
        signal.park_timeout(deadline.duration_since(now));
    }
}

/// Simulated time: the clock of a diagram whose clock source is a simulator.
///
/// It starts at a fixed `epoch`, so that a simulation run twice stamps its samples alike, and advances
/// `time_scale` simulated seconds per real second; at time scale 0 it advances only when waited on,
/// straight to the deadline, so a diagram run in one thread (a sequential diagram) runs as fast as its
/// components compute, each tick at its exact simulated time.
#[derive(Debug)]
pub struct SimulatedClock {
    epoch: Timestamp,
    time_scale: f64,
    /// At time scale 0: simulated nanoseconds since the epoch, moved by waits.
    jumped_nanos: AtomicI64,
    started: Instant,
    /// Real time the clock was held still: the spans before, and since when it is held now.
    held: std::sync::Mutex<(Duration, Option<Instant>)>,
}

impl SimulatedClock {
    /// A clock at `epoch` now, advancing `time_scale` seconds per real second (0: only when waited on).
    /// A negative or non-finite scale is taken as 0.
    pub fn new(epoch: Timestamp, time_scale: f64) -> Self {
        SimulatedClock {
            epoch,
            time_scale: if time_scale.is_finite() && time_scale > 0.0 {
                time_scale
            } else {
                0.0
            },
            jumped_nanos: AtomicI64::new(0),
            started: Instant::now(),
            held: std::sync::Mutex::new((Duration::ZERO, None)),
        }
    }

    /// Real time since the start, less the time held still.
    fn running_time(&self) -> Duration {
        let now = Instant::now();
        let (before, since) = *self
            .held
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let holding = since.map_or(Duration::ZERO, |since| now.saturating_duration_since(since));
        now.saturating_duration_since(self.started)
            .saturating_sub(before + holding)
    }

    /// Simulated seconds per real second; 0 when it runs as fast as possible.
    pub fn time_scale(&self) -> f64 {
        self.time_scale
    }
}

impl Clock for SimulatedClock {
    fn now(&self) -> Timestamp {
        if self.jumps() {
            return Timestamp(
                self.epoch
                    .0
                    .saturating_add(self.jumped_nanos.load(Ordering::Acquire)),
            );
        }
        let elapsed = self.running_time().as_secs_f64() * self.time_scale;
        Timestamp(self.epoch.0.saturating_add((elapsed * 1e9) as i64))
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        if !self.jumps() {
            loop {
                if signal.wants_attention() {
                    return false;
                }
                let now = self.now();
                if now >= deadline {
                    return true;
                }
                let simulated = deadline.duration_since(now).as_secs_f64();
                signal.park_timeout(Duration::from_secs_f64(simulated / self.time_scale));
            }
        }
        if signal.wants_attention() {
            return false;
        }
        self.jumped_nanos
            .fetch_max(deadline.nanos_since(self.epoch), Ordering::AcqRel);
        true
    }

    fn describe(&self) -> String {
        if self.jumps() {
            format!("simulated time from {}, as fast as the diagram runs", self.epoch)
        } else {
            format!(
                "simulated time from {}, {} simulated seconds per real second",
                self.epoch, self.time_scale
            )
        }
    }

    fn jumps(&self) -> bool {
        self.time_scale == 0.0
    }

    fn hold(&self, held: bool) {
        let mut state = self
            .held
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match (held, state.1) {
            (true, None) => state.1 = Some(Instant::now()),
            (false, Some(since)) => {
                state.0 += since.elapsed();
                state.1 = None;
            }
            _ => {}
        }
    }
}

/// A clock that moves only when told to; waiting on it jumps straight to the deadline.
///
/// Used by the offline harness so periodic components run as fast as possible with exact timestamps.
#[derive(Debug, Default)]
pub struct ManualClock {
    now_nanos: AtomicI64,
}

impl ManualClock {
    /// A clock standing at `start`.
    pub fn new(start: Timestamp) -> Self {
        ManualClock {
            now_nanos: AtomicI64::new(start.0),
        }
    }

    /// Moves the clock to `time` (never backwards).
    pub fn set(&self, time: Timestamp) {
        self.now_nanos.fetch_max(time.0, Ordering::AcqRel);
    }

    /// Moves the clock forward by `duration`.
    pub fn advance(&self, duration: Duration) {
        let nanos = i64::try_from(duration.as_nanos()).unwrap_or(i64::MAX);
        self.now_nanos.fetch_add(nanos, Ordering::AcqRel);
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Timestamp {
        Timestamp(self.now_nanos.load(Ordering::Acquire))
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        if signal.wants_attention() {
            return false;
        }
        self.set(deadline);
        true
    }

    fn describe(&self) -> String {
        "manual (moved by its owner)".to_owned()
    }

    fn jumps(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPOCH: Timestamp = Timestamp(1_767_225_600_000_000_000);

    #[test]
    fn simulated_time_as_fast_as_possible_jumps_to_each_deadline_and_never_back() {
        let clock = SimulatedClock::new(EPOCH, 0.0);
        let signal = RunSignal::new();
        assert!(clock.jumps());
        assert_eq!(clock.now(), EPOCH);
        let later = EPOCH.after(Duration::from_hours(1));
        let started = Instant::now();
        assert!(clock.wait_until(later, &signal));
        assert!(
            started.elapsed() < Duration::from_millis(100),
            "no real time spent"
        );
        assert_eq!(clock.now(), later);
        assert!(clock.wait_until(EPOCH, &signal));
        assert_eq!(clock.now(), later, "never backwards");
    }

    #[test]
    fn simulated_time_at_a_scale_runs_that_much_faster_and_stands_still_when_held() {
        let clock = SimulatedClock::new(EPOCH, 10.0);
        assert!(!clock.jumps());
        std::thread::sleep(Duration::from_millis(50));
        let first = clock.now().nanos_since(EPOCH);
        assert!(first >= 500_000_000, "{first} ns after 50 ms at 10×");
        clock.hold(true);
        let held = clock.now();
        std::thread::sleep(Duration::from_millis(50));
        assert!(clock.now().nanos_since(held) < 20_000_000, "held still");
        clock.hold(false);
        std::thread::sleep(Duration::from_millis(20));
        assert!(clock.now() > held);
        // Waiting for a simulated second takes a tenth of one.
        let deadline = clock.now().after(Duration::from_secs(1));
        let started = Instant::now();
        assert!(clock.wait_until(deadline, &RunSignal::new()));
        let waited = started.elapsed();
        assert!(
            waited >= Duration::from_millis(90) && waited < Duration::from_millis(600),
            "{waited:?}"
        );
    }
}

//! A runtime clock that follows a time source in the diagram (paper §2.3.1: "any component implementing
//! the necessary interface can behave as a time source for the entire application"), such as a GNSS
//! receiver's UTC.
//!
//! The clock is the monotonic clock plus an offset. The source gives references (the true time at a
//! moment read on this clock); the first one steps the offset, every later one only *slews* it, at most
//! [`MAX_SLEW`] seconds per second, so the clock never goes backwards after the first lock and never runs
//! more than 0.1 % fast or slow. Among recent references the one that makes the clock latest is trusted:
//! a reference can only arrive late (serial buffering, a busy thread), never early, so the latest one is
//! the one delayed least.
//!
//! A source that filters its own references (a clock synchronisation keeping its least-delayed exchange)
//! can also have the clock's *rate* estimated: it hands every raw measurement to
//! [`DisciplinedClock::observe`], and the slope of those over the last minute keeps the clock on the
//! source's pace between references and in holdover, instead of re-slewing its drift. (Filtered references
//! repeat an old measurement and would flatten the slope.)

use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::signal::RunSignal;
use crate::time::{Clock, Timestamp};

/// The most the offset moves per second of clock once locked: 1 ms/s.
pub const MAX_SLEW: f64 = 1e-3;
/// How many recent references the estimate looks at.
const WINDOW: usize = 8;
/// With no reference for this long the clock is in holdover; for ten times this long, lost.
const HOLDOVER_AFTER: Duration = Duration::from_secs(3);
/// An error larger than this after lock keeps the state at `slewing` rather than `locked`.
const LOCKED_WITHIN_NS: i64 = 10_000_000;
/// The largest rate correction trusted: crystals are within ±100 ppm; more is a wrong estimate.
const MAX_RATE: f64 = 500e-6;
/// The raw measurements a rate is estimated from (a minute of a clock master's exchanges), and the span
/// they must cover first.
const RATE_HISTORY: usize = 240;
const RATE_MIN_SPAN_NS: i64 = 2_000_000_000;
/// How fast the error may grow without references, per second of holdover: an estimated rate's wander
/// (temperature, ageing), or a crystal's whole tolerance when no rate is estimated.
const WANDER_WITH_RATE: f64 = 2e-6;
const WANDER_WITHOUT_RATE: f64 = 100e-6;

/// Where a disciplined clock stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockState {
    /// No reference yet: the clock is the machine's wall clock.
    Acquiring,
    /// Following the source: the last error was under 10 ms.
    Locked,
    /// Following the source, still slewing away a larger error.
    Slewing,
    /// No reference for 3 s: running on, at the last rate.
    Holdover,
    /// No reference for 30 s.
    Lost,
    /// A clock Kairos only measures (the system clock, kept by PTP or chrony) is further from its
    /// reference than the bound the user set.
    Alarm,
    /// The clock master of a rig (`kairos serve --clock-master`): this clock is the reference the
    /// others follow, so it agrees with them by definition.
    Master,
}

impl ClockState {
    /// The state a clock is in for want of references, `since_reference_s` after its last one: acquiring
    /// (none yet), holdover (none for 3 s) or lost (none for 30 s); `None` while they are fresh.
    pub fn of_silence(since_reference_s: Option<f64>) -> Option<ClockState> {
        let holdover = HOLDOVER_AFTER.as_secs_f64();
        match since_reference_s {
            None => Some(ClockState::Acquiring),
            Some(since) if since > 10.0 * holdover => Some(ClockState::Lost),
            Some(since) if since > holdover => Some(ClockState::Holdover),
            Some(_) => None,
        }
    }
}

/// What a clock tells telemetry about itself.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ClockStatus {
    /// The component that is the time source.
    pub source: String,
    /// Where the clock stands.
    pub state: ClockState,
    /// The source's time minus this clock's at the last reference (after the correction so far), ns.
    pub error_ns: i64,
    /// What this clock adds to the machine's monotonic time (the total correction), ns since the epoch.
    pub offset_ns: i64,
    /// How far the first reference stepped the clock from the machine's wall clock, ns (0 when it came
    /// too late to step).
    pub step_ns: i64,
    /// References taken in.
    pub references: u64,
    /// Seconds since the last reference, when there was one.
    pub since_reference_s: Option<f64>,
    /// How far from its source the clock may be, when the source can tell (a clock master: half the
    /// round trip of the exchange used, the most an asymmetric path can bias it), ns; it grows with the
    /// time since the last reference (2 ppm with an estimated rate, else 100 ppm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_bound_ns: Option<i64>,
    /// The rate correction applied (the source's pace against this machine's), parts per million, when
    /// it is estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_ppm: Option<f64>,
}

/// The offset's course: from `from` at monotonic time `anchor`, moving towards `target` at
/// [`MAX_SLEW`], both moving on at `rate`.
#[derive(Debug, Clone, Copy)]
struct Course {
    /// Nanoseconds of monotonic time.
    anchor: i64,
    /// Nanoseconds of offset, at the anchor.
    from: i64,
    /// Nanoseconds of offset wanted at the anchor.
    target: i64,
    /// Offset gained per nanosecond of monotonic time: the source's pace against this machine's.
    rate: f64,
}

impl Course {
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_precision_loss,
        reason = "nanoseconds of slew over a run fit an f64's 53 bits"
    )]
    fn offset_at(self, monotonic_ns: i64) -> i64 {
        let elapsed = monotonic_ns.saturating_sub(self.anchor).max(0);
        let most = (elapsed as f64 * MAX_SLEW) as i64;
        let wanted = self.target.saturating_sub(self.from);
        // |rate| + MAX_SLEW < 1: the clock always runs forwards.
        let paced = (elapsed as f64 * self.rate) as i64;
        self.from
            .saturating_add(paced)
            .saturating_add(wanted.clamp(-most, most))
    }
}

#[derive(Debug)]
struct Discipline {
    /// Recent references as (error against the clock's offset-free time, monotonic time taken).
    recent: VecDeque<(i64, i64)>,
    /// The raw measurements a rate is estimated from, as `recent`, when it is.
    history: VecDeque<(i64, i64)>,
    /// Their slope, once they span [`RATE_MIN_SPAN_NS`].
    rate: f64,
    references: u64,
    last_reference_ns: Option<i64>,
    last_error_ns: i64,
    step_ns: i64,
}

/// A clock disciplined by one component of the diagram. See the module's documentation.
#[derive(Debug)]
pub struct DisciplinedClock {
    source: String,
    start: Instant,
    /// The course, published as three atomics behind a sequence counter so `now` never takes a lock.
    version: AtomicU64,
    anchor_ns: AtomicI64,
    from_ns: AtomicI64,
    target_ns: AtomicI64,
    /// The course's rate, an `f64`'s bits.
    rate_bits: AtomicU64,
    discipline: Mutex<Discipline>,
    /// Whether the rate is estimated from the references.
    estimates_rate: bool,
    /// A test-only drift of the machine's own clock, parts per billion.
    drift_ppb: i64,
    steps_allowed: AtomicBool,
    /// How many recent references the estimate looks at.
    window: usize,
    /// The source's bound on the error, ns; negative while unknown.
    error_bound_ns: AtomicI64,
}

impl DisciplinedClock {
    /// A clock that `source` (a component's id) disciplines; until its first reference it reads the
    /// machine's wall clock.
    pub fn new(source: impl Into<String>) -> Self {
        let wall = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
        DisciplinedClock {
            source: source.into(),
            start: Instant::now(),
            version: AtomicU64::new(0),
            anchor_ns: AtomicI64::new(0),
            from_ns: AtomicI64::new(wall),
            target_ns: AtomicI64::new(wall),
            rate_bits: AtomicU64::new(0.0_f64.to_bits()),
            estimates_rate: false,
            drift_ppb: 0,
            discipline: Mutex::new(Discipline {
                recent: VecDeque::with_capacity(WINDOW),
                history: VecDeque::new(),
                rate: 0.0,
                references: 0,
                last_reference_ns: None,
                last_error_ns: 0,
                step_ns: 0,
            }),
            steps_allowed: AtomicBool::new(true),
            window: WINDOW,
            error_bound_ns: AtomicI64::new(-1),
        }
    }

    /// Trusts each reference as it comes (a source that filters its own, such as a clock synchronisation
    /// that keeps its least-delayed exchange), rather than the latest of the last 8.
    #[must_use]
    pub fn trusting_each_reference(mut self) -> Self {
        self.window = 1;
        self
    }

    /// Estimates the clock's rate from the raw measurements handed to [`DisciplinedClock::observe`] (see the
    /// module's documentation): for a source that filters its references, such as a clock master's
    /// least-delayed exchanges.
    #[must_use]
    pub fn estimating_rate(mut self) -> Self {
        self.estimates_rate = true;
        self
    }

    /// Runs the machine's own clock `ppm` parts per million fast (slow when negative): a test-only
    /// stand-in for a machine whose crystal is off.
    #[must_use]
    pub fn drifted_by_ppm(mut self, ppm: f64) -> Self {
        #[allow(clippy::cast_possible_truncation, reason = "a drift in parts per billion")]
        let ppb = (ppm * 1e3).round() as i64;
        self.drift_ppb = ppb;
        self
    }

    /// The rate correction now applied (offset gained per nanosecond): 0 until one is estimated.
    pub fn rate(&self) -> f64 {
        self.course().rate
    }

    /// Starts `offset_ns` away from the machine's wall clock: a test-only stand-in for a machine whose
    /// clock is wrong.
    #[must_use]
    pub fn shifted_by(self, offset_ns: i64) -> Self {
        let wall = self.from_ns.load(Ordering::Acquire).saturating_add(offset_ns);
        self.from_ns.store(wall, Ordering::Release);
        self.target_ns.store(wall, Ordering::Release);
        self
    }

    /// The machine's monotonic time since this clock was made, ns: the uncorrected time the offset is
    /// added to (the "uncorrected" time of [`ClockStatus::offset_ns`]).
    pub fn monotonic_ns(&self) -> i64 {
        let elapsed = i64::try_from(self.start.elapsed().as_nanos()).unwrap_or(i64::MAX);
        // Every read of the clock comes here: the test-only drift costs nothing when off.
        if self.drift_ppb == 0 {
            return elapsed;
        }
        let drift = i128::from(elapsed) * i128::from(self.drift_ppb) / 1_000_000_000;
        elapsed.saturating_add(i64::try_from(drift).unwrap_or(0))
    }

    fn course(&self) -> Course {
        loop {
            let before = self.version.load(Ordering::Acquire);
            let course = Course {
                anchor: self.anchor_ns.load(Ordering::Acquire),
                from: self.from_ns.load(Ordering::Acquire),
                target: self.target_ns.load(Ordering::Acquire),
                rate: f64::from_bits(self.rate_bits.load(Ordering::Acquire)),
            };
            if before.is_multiple_of(2) && self.version.load(Ordering::Acquire) == before {
                return course;
            }
            std::hint::spin_loop();
        }
    }

    /// Publishes a new course; callers hold the discipline's lock, so there is one writer at a time.
    fn publish(&self, course: Course) {
        self.version.fetch_add(1, Ordering::AcqRel);
        self.anchor_ns.store(course.anchor, Ordering::Release);
        self.from_ns.store(course.from, Ordering::Release);
        self.target_ns.store(course.target, Ordering::Release);
        self.rate_bits.store(course.rate.to_bits(), Ordering::Release);
        self.version.fetch_add(1, Ordering::AcqRel);
    }

    /// Takes in a reference from `source`: at `measured_at` on this clock, the true time was `reference`.
    /// Returns false (and changes nothing) for any other component.
    pub fn take_reference(&self, source: &str, measured_at: Timestamp, reference: Timestamp) -> bool {
        if source != self.source {
            return false;
        }
        let Ok(mut discipline) = self.discipline.lock() else {
            return false;
        };
        let now_monotonic = self.monotonic_ns();
        let course = self.course();
        // The monotonic time at which `measured_at` was read, and the offset the clock had then.
        let offset_then = course.offset_at(now_monotonic);
        let measured_monotonic = measured_at.as_nanos().saturating_sub(offset_then);
        let wanted_offset = reference.as_nanos().saturating_sub(measured_monotonic);
        discipline.recent.push_back((wanted_offset, now_monotonic));
        while discipline.recent.len() > self.window {
            discipline.recent.pop_front();
        }
        let rate = discipline.rate;
        // A late reference asks for a smaller offset than a prompt one: trust the largest, each carried
        // to now at the rate.
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_precision_loss,
            reason = "ns of drift"
        )]
        let best = discipline
            .recent
            .iter()
            .map(|(offset, at)| offset.saturating_add(((now_monotonic - at) as f64 * rate) as i64))
            .max()
            .unwrap_or(wanted_offset);
        let first = discipline.references == 0;
        let step = first && self.steps_allowed.load(Ordering::Acquire);
        discipline.references += 1;
        discipline.last_reference_ns = Some(now_monotonic);
        // After the first step the clock agrees with its source.
        discipline.last_error_ns = if step {
            discipline.step_ns = best.saturating_sub(offset_then);
            0
        } else {
            wanted_offset.saturating_sub(offset_then)
        };
        if step {
            // The first lock steps the clock: from here on it only slews.
            self.publish(Course {
                anchor: now_monotonic,
                from: best,
                target: best,
                rate,
            });
        } else {
            self.publish(Course {
                anchor: now_monotonic,
                from: offset_then,
                target: best,
                rate,
            });
        }
        true
    }

    /// Takes in one raw measurement from `source` for the rate estimate only (with
    /// [`DisciplinedClock::estimating_rate`]): at `measured_at` on this clock, the true time was
    /// `reference`. It takes effect at the next reference.
    pub fn observe(&self, source: &str, measured_at: Timestamp, reference: Timestamp) {
        if source != self.source || !self.estimates_rate {
            return;
        }
        let Ok(mut discipline) = self.discipline.lock() else {
            return;
        };
        let now_monotonic = self.monotonic_ns();
        let measured_monotonic = measured_at
            .as_nanos()
            .saturating_sub(self.course().offset_at(now_monotonic));
        let base = reference.as_nanos().saturating_sub(measured_monotonic);
        discipline.history.push_back((base, now_monotonic));
        while discipline.history.len() > RATE_HISTORY {
            discipline.history.pop_front();
        }
        if let Some(rate) = estimate_rate(&discipline.history) {
            discipline.rate = rate;
        }
    }

    /// Records how far from its source this clock may be, as the source measured it (see
    /// [`ClockStatus::error_bound_ns`]).
    pub fn set_error_bound(&self, bound_ns: i64) {
        self.error_bound_ns.store(bound_ns.max(0), Ordering::Relaxed);
    }

    /// Where the clock stands.
    pub fn clock_status(&self) -> ClockStatus {
        let discipline = self.discipline.lock().ok();
        let monotonic = self.monotonic_ns();
        let offset_ns = self.course().offset_at(monotonic);
        let (references, last, error_ns, step_ns) = discipline.as_ref().map_or((0, None, 0, 0), |d| {
            (d.references, d.last_reference_ns, d.last_error_ns, d.step_ns)
        });
        #[allow(clippy::cast_precision_loss, reason = "seconds for display")]
        let since_reference_s = last.map(|at| (monotonic - at) as f64 * 1e-9);
        let state =
            ClockState::of_silence(since_reference_s).unwrap_or(if error_ns.abs() > LOCKED_WITHIN_NS {
                ClockState::Slewing
            } else {
                ClockState::Locked
            });
        let wander = if self.estimates_rate {
            WANDER_WITH_RATE
        } else {
            WANDER_WITHOUT_RATE
        };
        #[allow(clippy::cast_possible_truncation, reason = "nanoseconds of wander")]
        let error_bound_ns = Some(self.error_bound_ns.load(Ordering::Relaxed))
            .filter(|bound| *bound >= 0)
            .map(|bound| bound.saturating_add((since_reference_s.unwrap_or(0.0) * 1e9 * wander) as i64));
        ClockStatus {
            source: self.source.clone(),
            state,
            error_ns,
            offset_ns,
            step_ns,
            references,
            since_reference_s,
            error_bound_ns,
            rate_ppm: self.estimates_rate.then(|| self.course().rate * 1e6),
        }
    }
}

/// The slope of `history`'s offsets against their times (least squares), once they span
/// [`RATE_MIN_SPAN_NS`]: the rate that keeps the clock on its source's pace, within [`MAX_RATE`].
#[allow(
    clippy::cast_precision_loss,
    reason = "nanoseconds as f64, relative to the first"
)]
fn estimate_rate(history: &VecDeque<(i64, i64)>) -> Option<f64> {
    let (&(first_offset, first_at), &(_, last_at)) = (history.front()?, history.back()?);
    if history.len() < 4 || last_at - first_at < RATE_MIN_SPAN_NS {
        return None;
    }
    let count = history.len() as f64;
    let points = history
        .iter()
        .map(|(offset, at)| ((at - first_at) as f64, (offset - first_offset) as f64));
    let (sum_t, sum_o) = points
        .clone()
        .fold((0.0, 0.0), |(t, o), (pt, po)| (t + pt, o + po));
    let (mean_t, mean_o) = (sum_t / count, sum_o / count);
    let (covariance, variance) = points.fold((0.0, 0.0), |(c, v), (t, o)| {
        (c + (t - mean_t) * (o - mean_o), v + (t - mean_t) * (t - mean_t))
    });
    (variance > 0.0).then(|| (covariance / variance).clamp(-MAX_RATE, MAX_RATE))
}

impl Clock for DisciplinedClock {
    fn now(&self) -> Timestamp {
        let monotonic = self.monotonic_ns();
        Timestamp(monotonic.saturating_add(self.course().offset_at(monotonic)))
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        crate::time::wait_in_real_time(self, deadline, signal)
    }

    fn describe(&self) -> String {
        format!(
            "disciplined by component '{}' (slewed at most 1 ms/s after the first lock)",
            self.source
        )
    }

    fn take_reference(&self, source: &str, measured_at: Timestamp, reference: Timestamp) -> bool {
        DisciplinedClock::take_reference(self, source, measured_at, reference)
    }

    fn forbid_steps(&self) {
        self.steps_allowed.store(false, Ordering::Release);
    }

    fn status(&self) -> Option<ClockStatus> {
        Some(self.clock_status())
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::{ClockState, DisciplinedClock, MAX_SLEW};
    use crate::time::{Clock, Timestamp};

    const DAY: i64 = 86_400_000_000_000;

    #[test]
    fn the_first_reference_steps_the_clock_and_only_its_source_counts() {
        let clock = DisciplinedClock::new("gnss");
        assert_eq!(clock.clock_status().state, ClockState::Acquiring);
        let before = clock.now();
        // The receiver says it is a day earlier than the machine thinks.
        assert!(!clock.take_reference("other", before, Timestamp(before.0 - DAY)));
        assert!(clock.take_reference("gnss", before, Timestamp(before.0 - DAY)));
        let after = clock.now();
        assert!(
            (after.0 - (before.0 - DAY)).abs() < 50_000_000,
            "stepped to the receiver's time"
        );
        assert_eq!(clock.clock_status().state, ClockState::Locked);
    }

    #[test]
    fn after_lock_the_clock_slews_at_most_a_millisecond_a_second_and_never_goes_back() {
        let clock = DisciplinedClock::new("gnss");
        let now = clock.now();
        clock.take_reference("gnss", now, now);
        // Now the receiver keeps saying the clock is 1 s ahead: it may only slow down, never step back.
        for _ in 0..8 {
            let now = clock.now();
            clock.take_reference("gnss", now, Timestamp(now.0 - 1_000_000_000));
        }
        assert_eq!(clock.clock_status().state, ClockState::Slewing);
        let offset_before = clock.clock_status().offset_ns;
        let started = std::time::Instant::now();
        let mut previous = clock.now();
        while started.elapsed() < Duration::from_millis(200) {
            let reading = clock.now();
            assert!(reading >= previous, "the clock went backwards");
            previous = reading;
        }
        let slewed = offset_before - clock.clock_status().offset_ns;
        #[allow(clippy::cast_precision_loss, reason = "a bound in nanoseconds")]
        let most = started.elapsed().as_nanos() as f64 * MAX_SLEW + 10_000.0;
        #[allow(clippy::cast_precision_loss, reason = "a bound in nanoseconds")]
        let slewed_f = slewed as f64;
        assert!(
            slewed > 0 && slewed_f <= most,
            "slewed {slewed} ns, at most {most}"
        );
    }

    #[test]
    fn once_steps_are_forbidden_a_first_reference_only_slews() {
        let clock = DisciplinedClock::new("gnss");
        clock.forbid_steps();
        let now = clock.now();
        clock.take_reference("gnss", now, Timestamp(now.0 - DAY));
        let after = clock.now();
        assert!(after >= now, "no step back");
        let status = clock.clock_status();
        assert_eq!((status.state, status.step_ns), (ClockState::Slewing, 0));
        assert!(status.error_ns < -DAY / 2);
    }

    /// The true time, on a clock that does not drift: the wall clock at `start`, then the monotonic clock.
    fn truth(start: (std::time::Instant, i64)) -> i64 {
        start.1 + i64::try_from(start.0.elapsed().as_nanos()).unwrap_or(i64::MAX)
    }

    /// One exact reference: the clock read between two reads of the truth close together.
    fn exact_reference(clock: &DisciplinedClock, start: (std::time::Instant, i64)) {
        loop {
            let (before, measured, after) = (truth(start), clock.now(), truth(start));
            if after - before < 20_000 {
                let reference = Timestamp(i64::midpoint(before, after));
                clock.observe("master", measured, reference);
                clock.take_reference("master", measured, reference);
                return;
            }
        }
    }

    #[test]
    fn a_drifting_machine_has_its_rate_estimated_and_keeps_pace_between_references() {
        // This machine's crystal runs 100 ppm fast.
        let clock = DisciplinedClock::new("master")
            .trusting_each_reference()
            .estimating_rate()
            .drifted_by_ppm(100.0);
        let start = (std::time::Instant::now(), clock.now().0 - 250_000_000);
        let began = std::time::Instant::now();
        while began.elapsed() < Duration::from_millis(2500) {
            exact_reference(&clock, start);
            std::thread::sleep(Duration::from_millis(50));
        }
        let rate_ppm = clock.clock_status().rate_ppm.unwrap_or_default();
        assert!(
            (rate_ppm + 100.0).abs() < 2.0,
            "estimated {rate_ppm} ppm against -100"
        );
        // Without references for 300 ms, a clock without the rate would be 30 µs off; this one keeps pace.
        std::thread::sleep(Duration::from_millis(300));
        let (before, reading, after) = (truth(start), clock.now().0, truth(start));
        let error = reading - i64::midpoint(before, after);
        assert!(
            error.abs() < 5_000 + (after - before),
            "{error} ns off after 300 ms of holdover"
        );
        // And the bound the status gives grows with the time since the last reference.
        clock.set_error_bound(1_000);
        assert!(clock.clock_status().error_bound_ns.unwrap_or_default() > 1_000);
    }

    #[test]
    fn late_references_do_not_pull_the_clock_back() {
        let clock = DisciplinedClock::new("gnss");
        let now = clock.now();
        clock.take_reference("gnss", now, now);
        let offset = clock.clock_status().offset_ns;
        // A reference that arrived 80 ms late says the clock is 80 ms ahead; the prompt one wins.
        let now = clock.now();
        clock.take_reference("gnss", now, Timestamp(now.0 - 80_000_000));
        std::thread::sleep(Duration::from_millis(20));
        assert!(clock.clock_status().offset_ns >= offset - 1_000_000);
    }
}

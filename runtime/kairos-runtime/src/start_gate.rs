//! Every birth before any first cycle, as RTMaps starts a diagram: a source does not produce while a
//! slower neighbour (a Python worker importing numpy on a loaded machine, a camera opening) is still
//! being born, so nothing it writes is overwritten or missed before its reader exists, and a periodic
//! source does not count the start-up as missed ticks.

use std::collections::BTreeSet;
use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use kairos_sdk_core::RunSignal;

/// How long the born wait for the others: past it they start, and the log names who was still being
/// born (a birth that never returns must not hold the rest of the diagram for ever).
pub const START_GATE_LIMIT: Duration = Duration::from_secs(10);

/// How often a waiting thread looks at its stop request.
const STOP_CHECK: Duration = Duration::from_millis(50);

/// The components whose birth has not returned yet, and the thread-holding ones' wait.
#[derive(Debug)]
pub struct StartGate {
    unborn: Mutex<Unborn>,
    all_born: Condvar,
    limit: Duration,
}

#[derive(Debug)]
struct Unborn {
    ids: BTreeSet<String>,
    /// Opened by the limit: every later arrival goes straight on.
    forced_open: bool,
}

impl StartGate {
    /// A gate for `ids`, each of which must [`StartGate::arrive`] once.
    pub fn new(ids: impl IntoIterator<Item = String>, limit: Duration) -> Self {
        StartGate {
            unborn: Mutex::new(Unborn {
                ids: ids.into_iter().collect(),
                forced_open: false,
            }),
            all_born: Condvar::new(),
            limit,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Unborn> {
        self.unborn.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Says that `id`'s birth returned (well or not), without waiting.
    pub fn arrive(&self, id: &str) {
        let mut unborn = self.lock();
        unborn.ids.remove(id);
        if unborn.ids.is_empty() {
            self.all_born.notify_all();
        }
    }

    /// Says that `id` was born, then waits until every other component was, the limit passed, or `id` is
    /// asked to stop. Returns whether it may start (false: stop asked).
    pub fn arrive_and_wait(&self, id: &str, signal: &RunSignal) -> bool {
        let started = Instant::now();
        let mut unborn = self.lock();
        unborn.ids.remove(id);
        if unborn.ids.is_empty() {
            self.all_born.notify_all();
        }
        loop {
            if unborn.ids.is_empty() || unborn.forced_open {
                return true;
            }
            if signal.stop_requested() {
                return false;
            }
            if started.elapsed() >= self.limit {
                unborn.forced_open = true;
                let slow: Vec<&str> = unborn.ids.iter().map(String::as_str).collect();
                tracing::warn!(
                    "{} still being born after {} s: the rest of the diagram starts without waiting for it",
                    slow.join(", "),
                    self.limit.as_secs_f64()
                );
                self.all_born.notify_all();
                return true;
            }
            unborn = self
                .all_born
                .wait_timeout(unborn, STOP_CHECK)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

    #[test]
    fn the_born_wait_for_the_last_birth_and_no_longer() {
        let gate = Arc::new(StartGate::new(
            ["fast".into(), "slow".into()],
            Duration::from_secs(10),
        ));
        // Measured from before the spawn: a thread started late under load still waits until the end.
        let started = Instant::now();
        let fast = {
            let gate = Arc::clone(&gate);
            std::thread::Builder::new()
                .name("fast".to_owned())
                .spawn(move || {
                    assert!(gate.arrive_and_wait("fast", &RunSignal::new()));
                    started.elapsed()
                })
                .unwrap()
        };
        std::thread::sleep(Duration::from_millis(300));
        assert!(!fast.is_finished(), "the fast one waits for the slow one");
        gate.arrive("slow");
        let waited = fast.join().unwrap();
        assert!(
            waited >= Duration::from_millis(300) && waited < Duration::from_secs(2),
            "{waited:?}"
        );
    }

    #[test]
    fn a_birth_that_never_returns_holds_the_rest_only_to_the_limit_and_a_stop_ends_the_wait() {
        let gate = StartGate::new(
            ["a".into(), "b".into(), "hung".into()],
            Duration::from_millis(200),
        );
        let waited = Instant::now();
        assert!(gate.arrive_and_wait("a", &RunSignal::new()));
        assert!(waited.elapsed() >= Duration::from_millis(200));
        let at_once = Instant::now();
        assert!(
            gate.arrive_and_wait("b", &RunSignal::new()),
            "the gate stays open"
        );
        assert!(at_once.elapsed() < Duration::from_millis(100));

        let gate = StartGate::new(["a".into(), "hung".into()], Duration::from_mins(1));
        let signal = RunSignal::new();
        signal.request_stop();
        assert!(!gate.arrive_and_wait("a", &signal));
    }
}

//! Checking clocks: every host following a master locked to it within the bound before anything starts.

use std::time::Duration;

use anyhow::bail;
use kairos_protocol::{ClockState, ClockTelemetry, RequestBody};

use crate::host::Host;

/// Checks, before anything starts, that every host whose clock follows a master is locked to it within
/// `bound`. A host that is not is named with its state and error, and nothing starts, unless
/// `start_unlocked` (then it is only warned about, and the hosts not locked are returned in words, for the
/// recordings). A host following no master starts on its own clock, which is said.
pub(crate) fn check_clocks(
    hosts: &mut [Host],
    bound: Duration,
    start_unlocked: bool,
) -> anyhow::Result<Option<String>> {
    let bound_ns = i64::try_from(bound.as_nanos()).unwrap_or(i64::MAX);
    let mut unlocked = Vec::new();
    for host in hosts.iter_mut() {
        let status = host.call(RequestBody::Status)?;
        let Some(clock) = clock_of(&status) else {
            tracing::warn!(
                "host '{}' follows no clock master: it reaches the start instant on its own clock \
                 (`kairos serve --clock-slave-of` synchronises it)",
                host.name()
            );
            continue;
        };
        if let Some(why) = not_ready(host.name(), &clock, bound_ns) {
            unlocked.push(why);
        } else if clock.state == ClockState::Master {
            tracing::info!("host '{}' is the clock master", host.name());
        } else {
            tracing::info!(
                "host '{}': clock locked, within ±{:.1} µs",
                host.name(),
                worst_error_ns(&clock).unsigned_abs() as f64 * 1e-3
            );
        }
    }
    if unlocked.is_empty() {
        return Ok(None);
    }
    let list = unlocked.join("; ");
    if start_unlocked {
        tracing::warn!("starting with clocks not locked within {bound:?}, as asked: {list}");
        return Ok(Some(format!("not locked within {bound:?}: {list}")));
    }
    bail!(
        "not every host's clock is locked to its master within {bound:?}, so nothing was started: {list}; \
         wait for them to lock, raise --lock-bound, or pass --start-unlocked to start anyway"
    )
}

/// A host's clock, from its answer to `status` (`None`: it follows no master).
pub fn clock_of(status: &serde_json::Value) -> Option<ClockTelemetry> {
    serde_json::from_value(status.get("clock")?.clone()).ok()
}

/// The most the clock may be off its master: the bound the master gives (half the exchange's round trip)
/// where there is one, else the last error.
fn worst_error_ns(clock: &ClockTelemetry) -> i64 {
    clock.error_bound_ns.unwrap_or(clock.error_ns)
}

/// Why `clock` is not ready for a start within `bound_ns`, in words naming `host`; `None` when it is.
fn not_ready(host: &str, clock: &ClockTelemetry, bound_ns: i64) -> Option<String> {
    let ms = |ns: i64| ns as f64 * 1e-6;
    match clock.state {
        ClockState::Master => None,
        ClockState::Locked if worst_error_ns(clock).abs() <= bound_ns => None,
        ClockState::Acquiring => Some(format!(
            "host '{host}': clock acquiring (no exchange with its master yet)"
        )),
        ClockState::Locked => Some(format!(
            "host '{host}': clock locked to its master (within 10 ms), but error {}, error bound \
             ±{:.3} ms is over the lock bound {:.3} ms",
            kairos_protocol::error_ms(clock.error_ns),
            ms(worst_error_ns(clock).abs()),
            ms(bound_ns)
        )),
        state => Some(format!(
            "host '{host}': clock {state}, error {}{}",
            kairos_protocol::error_ms(clock.error_ns),
            clock
                .error_bound_ns
                .map_or_else(String::new, |b| format!(", error bound ±{:.3} ms", ms(b.abs())))
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clock(state: ClockState, error_ns: i64, bound_ns: Option<i64>) -> ClockTelemetry {
        ClockTelemetry {
            source: "master 10.0.0.1:7401".to_owned(),
            state,
            error_ns,
            step_ns: 0,
            references: 10,
            since_reference_s: Some(0.1),
            error_bound_ns: bound_ns,
            rate_ppm: None,
        }
    }

    #[test]
    fn a_locked_clock_over_the_bound_says_error_and_bound_apart() {
        let within = clock(ClockState::Locked, 3_000, Some(11_000));
        assert_eq!(not_ready("b", &within, 1_000_000), None);
        let why = not_ready("b", &within, 1_000).unwrap_or_default();
        assert!(
            why.contains("error +0.003 ms")
                && why.contains("error bound ±0.011 ms")
                && why.contains("lock bound 0.001 ms"),
            "{why}"
        );
        assert_eq!(not_ready("a", &clock(ClockState::Master, 0, Some(0)), 0), None);
        let acquiring = not_ready("c", &clock(ClockState::Acquiring, 0, None), 1_000).unwrap_or_default();
        assert!(acquiring.contains("clock acquiring"), "{acquiring}");
        let holdover =
            not_ready("d", &clock(ClockState::Holdover, -2_000_000, None), 1_000_000).unwrap_or_default();
        assert!(holdover.contains("clock holdover, error -2.000 ms"), "{holdover}");
    }

    #[test]
    fn a_state_from_a_newer_runtime_reads_as_unknown_and_is_not_ready() {
        let status = serde_json::json!({"clock": {"source": "x", "state": "wandering", "error_ns": 5, "step_ns": 0, "references": 1}});
        let clock = clock_of(&status).unwrap_or_else(|| clock(ClockState::Locked, 0, None));
        assert_eq!(clock.state, ClockState::Unknown);
        assert!(not_ready("e", &clock, i64::MAX).is_some());
        assert!(clock_of(&serde_json::json!({"state": "idle"})).is_none());
    }
}

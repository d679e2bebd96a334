//! Checking clocks: every host following a master locked to it within the bound before anything starts.

use std::time::Duration;

use anyhow::bail;
use kairos_protocol::RequestBody;

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
        let clock = &status["clock"];
        let Some(state) = clock["state"].as_str() else {
            tracing::warn!(
                "host '{}' follows no clock master: it reaches the start instant on its own clock \
                 (`kairos serve --clock-slave-of` synchronises it)",
                host.name()
            );
            continue;
        };
        if state == "master" {
            tracing::info!("host '{}' is the clock master", host.name());
            continue;
        }
        // The master's bound where it gives one (half the exchange's round trip), else the last error.
        let error_ns = clock["error_bound_ns"]
            .as_i64()
            .or_else(|| clock["error_ns"].as_i64())
            .unwrap_or(i64::MAX);
        if state == "locked" && error_ns.abs() <= bound_ns {
            tracing::info!(
                "host '{}': clock locked, within ±{:.1} µs",
                host.name(),
                error_ns.unsigned_abs() as f64 * 1e-3
            );
        } else if state == "acquiring" {
            unlocked.push(format!(
                "host '{}': clock acquiring (no exchange with its master yet)",
                host.name()
            ));
        } else {
            unlocked.push(format!(
                "host '{}': clock {state}, error {:+.3} ms",
                host.name(),
                error_ns as f64 * 1e-6
            ));
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

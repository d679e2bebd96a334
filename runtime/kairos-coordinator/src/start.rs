//! The coordinated start and stop: every host at one instant on the master's clock.

use std::time::Duration;

use kairos_protocol::RequestBody;

use crate::clocks::check_clocks;
use crate::host::Host;

/// How far ahead of now the hosts are told to stop: time for every request to arrive.
pub const STOP_LEAD: Duration = Duration::from_millis(200);

/// How far ahead of now the hosts are told to start: time for every request to arrive.
pub const START_LEAD: Duration = Duration::from_millis(500);

/// A host that started later than this after the agreed instant is said to have: its first samples are
/// late against the other hosts'.
pub const LATE_START: Duration = Duration::from_millis(1);

/// Whether a part that started `late_ns` after the agreed instant started apart from the others.
pub fn started_late(late_ns: i64) -> bool {
    u128::try_from(late_ns).is_ok_and(|late| late > LATE_START.as_nanos())
}

/// Starts every host's part and, with `start_here`, this machine's, at one instant [`START_LEAD`] ahead,
/// each host waiting for it on its own clock. First every host's clock is checked ([`check_clocks`]); a
/// start forced with clocks not locked hands `start_here` (and every host) the hosts in words, for the
/// recordings.
///
/// # Errors
///
/// A clock not locked, a host refusing, or `start_here` failing: every host is stopped again. When a host
/// refuses after `start_here` succeeded, the caller stops its own part.
pub fn start_together(
    hosts: &mut [Host],
    bound: Duration,
    start_unlocked: bool,
    start_here: impl FnOnce(Option<&str>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    use kairos_sdk_core::Clock as _;
    let forced = check_clocks(hosts, bound, start_unlocked)?;
    let wall = kairos_sdk_core::RealTimeClock::new();
    let at = wall.now().after(START_LEAD);
    let asked = start_all_at(hosts, at.as_nanos(), forced.as_deref())?;
    while wall.now() < at {
        std::thread::sleep(Duration::from_micros(200));
    }
    if let Err(error) = start_here(forced.as_deref()) {
        stop_all(hosts);
        return Err(error);
    }
    let lateness = confirm_started(hosts, &asked)?;
    for (host, late_ns) in hosts.iter().zip(lateness) {
        match late_ns {
            Some(late) if started_late(late) => tracing::warn!(
                "host '{}' started its part {:.1} ms after the agreed instant (more than {} ms): its first \
                 samples are late against the other hosts'",
                host.name(),
                late as f64 * 1e-6,
                LATE_START.as_millis()
            ),
            Some(late) => tracing::info!(
                "host '{}' started its part (+{:.0} µs after the agreed instant)",
                host.name(),
                late as f64 * 1e-3
            ),
            None => tracing::info!("host '{}' started its part", host.name()),
        }
    }
    Ok(())
}

/// Asks every host to start at `at` (ns since the UNIX epoch on its clock), without waiting: each answers
/// once started. Collect the answers with [`confirm_started`].
/// `forced`: the hosts whose clocks are not locked, when the start is forced.
fn start_all_at(hosts: &mut [Host], at: i64, forced: Option<&str>) -> anyhow::Result<Vec<u64>> {
    hosts
        .iter_mut()
        .map(|host| {
            host.send(RequestBody::Start {
                at_ns: Some(at),
                forced: forced.map(str::to_owned),
                start_unlocked: false,
                lock_bound_ns: None,
            })
        })
        .collect()
}

/// The hosts' answers to [`start_all_at`]: how late each started (ns after the instant, as it says);
/// the first refusal, after stopping every host.
fn confirm_started(hosts: &mut [Host], ids: &[u64]) -> anyhow::Result<Vec<Option<i64>>> {
    let mut refused = None;
    let mut lateness = Vec::new();
    for (host, id) in hosts.iter_mut().zip(ids) {
        match host.wait(*id) {
            Ok(reply) => lateness.push(reply["late_ns"].as_i64()),
            Err(error) => {
                refused.get_or_insert(error);
            }
        }
    }
    match refused {
        None => Ok(lateness),
        Some(error) => {
            stop_all(hosts);
            Err(error)
        }
    }
}

/// Stops every host's part, saying which could not be stopped.
pub fn stop_all(hosts: &mut [Host]) {
    for host in hosts {
        match host.call(RequestBody::Stop { at_ns: None }) {
            Ok(_) => tracing::info!("host '{}' stopped", host.name()),
            Err(error) => tracing::warn!("{error}"),
        }
    }
}

//! Matching links: every link between hosts seen by both ends before anything starts.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use anyhow::bail;
use kairos_protocol::{CrossLinkTelemetry, LinkList, LinkNetwork, RequestBody};

use crate::host::Host;
use crate::plan::{CrossLink, Plan, place};

/// How long the links between hosts may take to match once every part is deployed.
pub const LINK_MATCH_WAIT: Duration = Duration::from_secs(5);

/// Waits until every link of `plan` has matched (its sender sees its receiver), here and on every host;
/// a link that does not within [`LINK_MATCH_WAIT`] is an error naming both ends.
pub(crate) fn wait_for_links(
    plan: &Plan,
    hosts: &mut [Host],
    networks: &BTreeMap<Option<String>, LinkNetwork>,
) -> anyhow::Result<()> {
    if plan.links.is_empty() {
        return Ok(());
    }
    let deadline = std::time::Instant::now() + LINK_MATCH_WAIT;
    loop {
        let mut matched: Vec<String> = kairos_pack_link::network::ends()
            .into_iter()
            .filter(|end| end.matched && end.role == "sender")
            .map(|end| end.key)
            .collect();
        for host in hosts.iter_mut() {
            let list: LinkList = serde_json::from_value(host.call(RequestBody::Links)?)?;
            matched.extend(
                list.links
                    .into_iter()
                    .filter(|end| end.matched && end.role == "sender")
                    .map(|end| end.key),
            );
        }
        let waiting: Vec<&CrossLink> = plan.links.iter().filter(|l| !matched.contains(&l.key)).collect();
        if waiting.is_empty() {
            return Ok(());
        }
        if std::time::Instant::now() >= deadline {
            let mut why = format!(
                "{} link(s) between hosts did not match within {} s, so nothing was started:",
                waiting.len(),
                LINK_MATCH_WAIT.as_secs()
            );
            for link in waiting {
                let _ = write!(why, "\n  {} -> {}", link.from, link.to);
            }
            let _ = write!(why, "\n  the hosts' link endpoints:");
            for (host, network) in networks {
                let _ = write!(
                    why,
                    "\n    {} listens on [{}], connects to [{}]",
                    place(host.as_ref()),
                    network.listen.join(", "),
                    network.connect.join(", ")
                );
            }
            let _ = write!(
                why,
                "\n  check that each listening address is this host's and that a firewall lets the others reach it \
                 (set it with `zenoh: \"tcp/ADDRESS:PORT\"` in the hosts section)"
            );
            bail!(why);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Each link of `plan` as its two ends count it, from the ends' statuses (`status_of(host, component)`;
/// `None` for this machine). `stopped`: every part has stopped, so the counts are final and whatever never
/// arrived after the last sample received was lost too, not only the gaps between those received.
pub fn cross_links(
    plan: &Plan,
    status_of: impl Fn(Option<&str>, &str) -> serde_json::Value,
    stopped: bool,
) -> Vec<CrossLinkTelemetry> {
    let count = |status: &serde_json::Value, key: &str| status[key].as_u64().unwrap_or(0);
    plan.links
        .iter()
        .map(|link| {
            let sending_end = status_of(link.sender.0.as_deref(), &link.sender.1);
            let receiving_end = status_of(link.receiver.0.as_deref(), &link.receiver.1);
            let (received, gaps) = (count(&receiving_end, "received"), count(&receiving_end, "lost"));
            // The two ends' statuses are read at different instants: a receiver may have seen more than
            // the sender's last status says it sent. What it saw was sent.
            let sent = count(&sending_end, "sent").max(received + gaps);
            let lost = if stopped { sent - received } else { gaps };
            CrossLinkTelemetry {
                from: link.connection.from.to_string(),
                to: link.connection.to.to_string(),
                from_host: link.sender.0.clone(),
                to_host: link.receiver.0.clone(),
                sent,
                received,
                lost,
                matched: sending_end["matched"].as_bool().unwrap_or(false),
                last_sample_age_ms: receiving_end["last_sample_age_ms"].as_u64(),
                quiet_after_ms: receiving_end["quiet_after_ms"].as_u64(),
                transit_p50_ns: receiving_end["transit_p50_ns"].as_i64(),
                transit_max_ns: receiving_end["transit_max_ns"].as_i64(),
            }
        })
        .collect()
}

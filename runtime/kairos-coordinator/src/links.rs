//! Matching links: every link between hosts seen by both ends before anything starts.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use anyhow::bail;
use kairos_protocol::{LinkList, LinkNetwork, RequestBody};

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

//! The coordinator: one diagram over several machines, as `kairos deploy`, `kairos serve` (coordinating a
//! diagram for its client, the studio's Run over hosts) and `kairos run` with hosts do it.
//!
//! The diagram is split by each component's `host`; each part goes to its host's `kairos serve` over the
//! control protocol, and the part without a host runs here. Everything starts, or nothing does: every
//! host is reached and every part accepted before anything starts, and a failure on the way names the
//! host and its reason. One module per job:
//!
//! | module | job |
//! | --- | --- |
//! | [`plan`] | split the diagram, place the links, list the packs each part needs, the hosts' networks |
//! | [`host`] | a session with one host, through `kairos-client` |
//! | [`ship`] | send a host the packs it lacks |
//! | [`links`] | wait until every link between hosts has matched |
//! | [`clocks`] | check every host's clock is locked before the start |
//! | [`start`] | start and stop every host at one instant |
//! | [`watch`] | watch the running deployment: hosts lost and back |

pub mod clocks;
pub mod host;
pub mod links;
pub mod plan;
pub mod ship;
pub mod start;
pub mod watch;

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::bail;
use kairos_diagram::Diagram;
use kairos_protocol::{LinkNetwork, RequestBody};
use kairos_sdk_core::Registry;

pub use host::{Host, Reach};
pub use links::LINK_MATCH_WAIT;
pub use plan::{CrossLink, Networks, PackNeed, Plan, deployment_name, networks, split};
pub use ship::ship_packs;
pub use start::{START_LEAD, STOP_LEAD, start_together, stop_all};
pub use watch::Watch;

use links::wait_for_links;

/// Splits `diagram` over its hosts, deploys each host's part (shipping the packs it lacks) and prepares
/// this machine's with `prepare_here`, joins this machine's links and waits for every link to match: what
/// `prepare_here` made, and the hosts to watch. Token files and certificates are found in `folder`; tokens
/// go over plain `ws://` off this machine only with `clear_text_tokens`. Nothing is started. Both `kairos
/// deploy` and a server coordinating a diagram for its client (the studio's Run) deploy this way.
///
/// Deploying is in two phases: every host prepares its part (validated and built beside what it runs)
/// and this machine prepares its own, and only when all are accepted does any host commit. A part refused
/// anywhere changes no host: each keeps what it ran.
///
/// # Errors
///
/// An unreachable host, a refused part or pack, a link that does not match: named with the reason.
pub fn deploy_everywhere<T>(
    diagram: &Diagram,
    registry: &Registry,
    folder: &Path,
    clear_text_tokens: bool,
    prepare_here: impl FnOnce(&Diagram) -> anyhow::Result<T>,
) -> anyhow::Result<(T, Watch)> {
    let plan = split(diagram, registry, &deployment_name())?;
    let networks = networks(diagram, &plan, folder)?;
    let reach = Reach::new(folder, clear_text_tokens);
    let here = plan.parts.get(&None).cloned().unwrap_or_default();
    let (mut hosts, prepared) = deploy_remote(diagram, &plan, &networks, &reach, || prepare_here(&here))?;
    if let Some(network) = networks.get(&None) {
        kairos_pack_link::network::join(network)?;
    }
    kairos_pack_link::network::prepare(&here)?;
    wait_for_links(&plan, &mut hosts, &networks)?;
    for link in &plan.links {
        tracing::info!("linked {} -> {}", link.from, link.to);
    }
    Ok((
        prepared,
        Watch::new(diagram.clone(), plan, networks, reach, hosts),
    ))
}

/// Reaches every host of `plan`, ships the packs each lacks, has each prepare its part with its link
/// network, prepares this machine's part with `prepare_here`, and then commits every host's; or fails
/// naming the host and its reason, every prepared part abandoned. Nothing is started.
fn deploy_remote<T>(
    diagram: &Diagram,
    plan: &Plan,
    networks: &BTreeMap<Option<String>, LinkNetwork>,
    reach: &Reach,
    prepare_here: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<(Vec<Host>, T)> {
    let mut hosts = Vec::new();
    for name in plan.parts.keys().flatten() {
        let Some(spec) = diagram.hosts.get(name) else {
            bail!("no host '{name}' in the diagram's hosts");
        };
        hosts.push(Host::reach(name, spec, reach)?);
    }
    for host in &mut hosts {
        let key = Some(host.name().to_owned());
        ship_packs(host, plan.packs.get(&key).map_or(&[], Vec::as_slice))?;
    }
    let mut tickets = Vec::new();
    for host in &mut hosts {
        let key = Some(host.name().to_owned());
        let part = plan.parts.get(&key).map(Diagram::to_ron).unwrap_or_default();
        let prepared = host.call(RequestBody::PrepareDeploy {
            diagram: part,
            network: networks.get(&key).cloned(),
        });
        match prepared.and_then(|reply| ticket_of(host.name(), &reply)) {
            Ok(ticket) => tickets.push(ticket),
            Err(e) => {
                abandon(&mut hosts, &tickets);
                return Err(unchanged(&e));
            }
        }
    }
    let local = match prepare_here() {
        Ok(prepared) => prepared,
        Err(e) => {
            abandon(&mut hosts, &tickets);
            return Err(unchanged(&e));
        }
    };
    for (index, ticket) in tickets.iter().enumerate() {
        if let Err(e) = hosts[index].commit(*ticket) {
            let committed: Vec<String> = hosts[..index].iter().map(|h| h.name().to_owned()).collect();
            abandon(&mut hosts[index + 1..], &tickets[index + 1..]);
            return Err(if committed.is_empty() {
                unchanged(&e)
            } else {
                e.context(format!(
                    "committed on {} before it failed: run the deploy again",
                    committed.join(", ")
                ))
            });
        }
    }
    Ok((hosts, local))
}

/// The ticket of a `prepare_deploy` reply.
fn ticket_of(host: &str, reply: &serde_json::Value) -> anyhow::Result<u64> {
    reply["ticket"].as_u64().ok_or_else(|| {
        anyhow::anyhow!("host '{host}' answered prepare_deploy without a ticket: is it an older kairos?")
    })
}

/// Drops the parts `hosts` prepared (in order, one ticket each); a host that does not answer drops its
/// own when the next prepare replaces it, and never commits it.
fn abandon(hosts: &mut [Host], tickets: &[u64]) {
    for (host, ticket) in hosts.iter_mut().zip(tickets) {
        if let Err(e) = host.call(RequestBody::AbandonDeploy { ticket: *ticket }) {
            tracing::warn!("{e:#}");
        }
    }
}

/// A refusal before any commit, saying that nothing changed.
fn unchanged(error: &anyhow::Error) -> anyhow::Error {
    anyhow::anyhow!("{error:#}\nno host was changed: each keeps the diagram it had, running or not")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_host_that_takes_tls_is_the_one_connected_to() {
        let source = r#"Diagram(format: 1,
            hosts: {
                "a": Host(endpoint: "ws://10.0.0.1:7600", zenoh: "tcp/10.0.0.1:7447"),
                "b": Host(endpoint: "wss://10.0.0.2:7600", certificate: "b.pem"),
                "c": Host(endpoint: "ws://10.0.0.3:7600"),
            },
            components: [], connections: [])"#;
        let diagram = kairos_diagram::parse(source)
            .map(|parsed| parsed.diagram)
            .unwrap();
        let linked_part = Diagram {
            components: vec![kairos_diagram::ComponentInstance::new(
                "out",
                kairos_pack_link::SENDER,
            )],
            ..diagram.clone()
        };
        let plan = Plan {
            parts: ["a", "b", "c"]
                .into_iter()
                .map(|host| (Some(host.to_owned()), linked_part.clone()))
                .collect(),
            ..Plan::default()
        };
        let folder = tempfile::tempdir().unwrap();
        // Without the certificate to trust, b's TLS endpoint is refused with the fix.
        let error = networks(&diagram, &plan, folder.path()).unwrap_err().to_string();
        assert!(error.contains("cannot read its certificate"), "{error}");
        std::fs::write(folder.path().join("b.pem"), "PEM").unwrap();
        let networks = networks(&diagram, &plan, folder.path()).unwrap();
        let connects = |host: &str| networks[&Some(host.to_owned())].connect.clone();
        assert_eq!(networks[&Some("b".to_owned())].listen, ["tls/10.0.0.2:7447"]);
        // a and c reach b over TLS; b, taking TLS, connects to no clear-text host; a joins c once.
        assert_eq!(connects("a"), ["tls/10.0.0.2:7447", "tcp/10.0.0.3:7447"]);
        assert!(connects("b").is_empty());
        assert_eq!(connects("c"), ["tls/10.0.0.2:7447"]);
        assert_eq!(networks[&Some("c".to_owned())].trusted_certificates, ["PEM"]);
    }
}

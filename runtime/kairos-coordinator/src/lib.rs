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

/// Splits `diagram` over its hosts, deploys each host's part (shipping the packs it lacks), joins this
/// machine's links and waits for every link to match: this machine's part, and the hosts to watch. Token
/// files and certificates are found in `folder`; tokens go over plain `ws://` off this machine only with
/// `clear_text_tokens`. Nothing is started. Both `kairos deploy` and a server coordinating a diagram for
/// its client (the studio's Run) deploy this way.
///
/// # Errors
///
/// An unreachable host, a refused part or pack, a link that does not match: named with the reason.
pub fn deploy_everywhere(
    diagram: &Diagram,
    registry: &Registry,
    folder: &Path,
    clear_text_tokens: bool,
) -> anyhow::Result<(Diagram, Watch)> {
    let plan = split(diagram, registry, &deployment_name())?;
    let networks = networks(diagram, &plan, folder)?;
    let reach = Reach::new(folder, clear_text_tokens);
    let mut hosts = deploy_remote(diagram, &plan, &networks, &reach)?;
    let here = plan.parts.get(&None).cloned().unwrap_or_default();
    if let Some(network) = networks.get(&None) {
        kairos_pack_link::network::join(network)?;
    }
    kairos_pack_link::network::prepare(&here)?;
    wait_for_links(&plan, &mut hosts, &networks)?;
    for link in &plan.links {
        tracing::info!("linked {} -> {}", link.from, link.to);
    }
    Ok((here, Watch::new(diagram.clone(), plan, networks, reach, hosts)))
}

/// Reaches every host of `plan` and deploys each part with its link network, or fails naming the host
/// and its reason. Nothing is started.
fn deploy_remote(
    diagram: &Diagram,
    plan: &Plan,
    networks: &BTreeMap<Option<String>, LinkNetwork>,
    reach: &Reach,
) -> anyhow::Result<Vec<Host>> {
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
    for host in &mut hosts {
        let key = Some(host.name().to_owned());
        let part = plan.parts.get(&key).map(Diagram::to_ron).unwrap_or_default();
        host.call(RequestBody::Deploy {
            diagram: part,
            network: networks.get(&key).cloned(),
            folder: None,
        })?;
    }
    Ok(hosts)
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

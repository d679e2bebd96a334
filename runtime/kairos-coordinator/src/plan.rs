//! Planning: a diagram split over its hosts, each connection between two hosts turned into a link pair,
//! the packs each part needs, and the Zenoh network each host joins.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail};
use kairos_diagram::{Connection, Diagram, PortRef, ReaderPolicy, Value};
use kairos_protocol::LinkNetwork;
use kairos_sdk_core::Registry;
use kairos_sdk_core::host::RegistryValidation as _;

/// A diagram split over its hosts.
#[derive(Debug, Default)]
pub struct Plan {
    /// The parts, by host name, and the one without a host (`None`, run by the deploying machine). Each
    /// connection between two hosts became a `link.sender` in the producer's part and a `link.receiver`
    /// in the consumer's.
    pub parts: BTreeMap<Option<String>, Diagram>,
    /// Those connections.
    pub links: Vec<CrossLink>,
    /// The packs each part needs, as loaded here: shipped to a host that lacks them.
    pub packs: BTreeMap<Option<String>, Vec<PackNeed>>,
}

/// A pack a part needs, as the deploying machine has it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PackNeed {
    /// Its name.
    pub name: String,
    /// Its version.
    pub version: String,
    /// The library it was loaded from here; `None` for a pack built into `kairos`.
    pub library: Option<PathBuf>,
}

/// The packs of `part`'s components, as `library` has them.
fn packs_needed(part: &Diagram, library: &kairos_diagram::LibraryInfo) -> Vec<PackNeed> {
    let mut needs: Vec<PackNeed> = Vec::new();
    for component in &part.components {
        let Some(pack) = library
            .components
            .get(&component.type_name)
            .and_then(|c| library.packs.get(&c.pack))
        else {
            continue;
        };
        if needs.iter().any(|n| n.name == pack.name) {
            continue;
        }
        needs.push(PackNeed {
            name: pack.name.clone(),
            version: pack.version.clone(),
            library: (pack.origin != "built-in").then(|| PathBuf::from(&pack.origin)),
        });
    }
    needs
}

/// A connection between two hosts.
#[derive(Debug, Clone)]
pub struct CrossLink {
    /// `camera.image on host 'car'`.
    pub from: String,
    /// `viewer.in on this machine`.
    pub to: String,
    /// The Zenoh key its samples travel under.
    pub key: String,
    /// The connection it carries.
    pub connection: Connection,
    /// The producer's host and the id of the `link.sender` added there.
    pub sender: (Option<String>, String),
    /// The consumer's host and the id of the `link.receiver` added there.
    pub receiver: (Option<String>, String),
}

/// Where a part runs, in words.
pub(crate) fn place(host: Option<&String>) -> String {
    host.map_or_else(|| "this machine".to_owned(), |h| format!("host '{h}'"))
}

/// An id for a component added to `part`, unused by the diagram and the part.
fn free_id(diagram: &Diagram, part: &Diagram, wanted: &str) -> String {
    let taken = |id: &str| diagram.component(id).is_some() || part.component(id).is_some();
    let mut id = wanted.to_owned();
    let mut suffix = 2;
    while taken(&id) {
        id = format!("{wanted}_{suffix}");
        suffix += 1;
    }
    id
}

/// Splits `diagram` by each component's `host`, links between hosts included. `deployment` tells this
/// deployment's keys from any other's on the same network.
///
/// # Errors
///
/// A connection whose ends are not both in the diagram (validation refuses those first).
pub fn split(diagram: &Diagram, registry: &Registry, deployment: &str) -> anyhow::Result<Plan> {
    let host_of: BTreeMap<&str, Option<&String>> = diagram
        .components
        .iter()
        .map(|c| (c.id.as_str(), c.host.as_ref()))
        .collect();
    let mut plan = Plan::default();
    let new_part = || Diagram {
        packs: diagram.packs.clone(),
        ..Diagram::default()
    };
    for component in &diagram.components {
        let part = plan.parts.entry(component.host.clone()).or_insert_with(new_part);
        let mut placed = component.clone();
        placed.host = None;
        part.components.push(placed);
    }
    let infos = registry.instance_infos(diagram);
    for connection in &diagram.connections {
        let (Some(&from), Some(&to)) = (
            host_of.get(connection.from.component.as_str()),
            host_of.get(connection.to.component.as_str()),
        ) else {
            bail!(
                "the connection {} -> {} names a component the diagram lacks",
                connection.from,
                connection.to
            );
        };
        if from == to {
            plan.parts
                .entry(from.cloned())
                .or_insert_with(new_part)
                .connections
                .push(connection.clone());
            continue;
        }
        // An instance's own descriptor where its ports depend on its properties, else its type's.
        let info = |id: &str| {
            infos.get(id).and_then(|r| r.as_ref().ok()).or_else(|| {
                let component = diagram.component(id)?;
                registry.component(&component.type_name).map(|r| &r.info)
            })
        };
        let data_type = info(&connection.from.component)
            .and_then(|i| i.outputs.iter().find(|o| o.name == connection.from.port))
            .map(|o| o.data_type.to_string())
            .with_context(|| {
                format!(
                    "the connection {} -> {}: no such output",
                    connection.from, connection.to
                )
            })?;
        let policy = connection.policy.or_else(|| {
            info(&connection.to.component)
                .and_then(|i| i.inputs.iter().find(|p| p.name == connection.to.port))
                .map(|p| p.default_policy)
        });
        let reliable = policy == Some(ReaderPolicy::NeverSkipping);
        let link = place_link(
            &mut plan,
            diagram,
            connection,
            (from, to),
            &data_type,
            reliable,
            deployment,
        );
        plan.links.push(link);
    }
    for part in plan.parts.values_mut() {
        // A part runs as the whole would: sequential if the diagram is (validation keeps a sequential
        // diagram on one host), its groups with their thread settings.
        part.sequential = diagram.sequential;
        part.groups = diagram
            .groups
            .iter()
            .filter(|(name, _)| {
                part.components
                    .iter()
                    .any(|c| part.group_of(c) == Some(name.as_str()))
            })
            .map(|(name, settings)| (name.clone(), settings.clone()))
            .collect();
        if diagram
            .clock_source
            .as_ref()
            .is_some_and(|source| part.component(source).is_some())
        {
            part.clock_source.clone_from(&diagram.clock_source);
        }
        // A host needs the packs of its own part only (links are built in).
        let used: Vec<&str> = part
            .components
            .iter()
            .filter_map(|c| c.type_name.split_once('.').map(|(pack, _)| pack))
            .collect();
        part.packs.retain(|pack| used.contains(&pack.name.as_str()));
    }
    let library = registry.library_info();
    plan.packs = plan
        .parts
        .iter()
        .map(|(host, part)| (host.clone(), packs_needed(part, &library)))
        .collect();
    Ok(plan)
}

/// A link component of `type_name` carrying `key`.
fn link_component(
    type_name: &str,
    id: &str,
    key: &str,
    reliable: bool,
    peer: &str,
) -> kairos_diagram::ComponentInstance {
    let mut component = kairos_diagram::ComponentInstance::new(id, type_name);
    for (name, value) in [
        ("key", Value::Text(key.to_owned())),
        ("reliable", Value::Bool(reliable)),
        ("peer", Value::Text(peer.to_owned())),
    ] {
        component.properties.insert(name.to_owned(), value);
    }
    component
}

/// Puts the two ends of `connection`, between the hosts `from` and `to`, into their parts: a sender
/// reading the output on the producer's host (the connection's subsampling applied there, so what is
/// dropped never travels), a receiver on the consumer's whose output the consumer reads with the
/// connection's policy and buffer size.
fn place_link(
    plan: &mut Plan,
    diagram: &Diagram,
    connection: &Connection,
    (from, to): (Option<&String>, Option<&String>),
    data_type: &str,
    reliable: bool,
    deployment: &str,
) -> CrossLink {
    let new_part = || Diagram {
        packs: diagram.packs.clone(),
        ..Diagram::default()
    };
    let key = format!(
        "kairos/{deployment}/{}/{}/{}/{}",
        connection.from.component, connection.from.port, connection.to.component, connection.to.port
    );
    let from_words = format!("{} on {}", connection.from, place(from));
    let to_words = format!("{} on {}", connection.to, place(to));

    let producing = plan.parts.entry(from.cloned()).or_insert_with(new_part);
    let sender_id = free_id(
        diagram,
        producing,
        &format!("link_to_{}_{}", connection.to.component, connection.to.port),
    );
    let mut sender = link_component(kairos_pack_link::SENDER, &sender_id, &key, reliable, &to_words);
    // What the producer's host says a cut may last and keep (the coordinating machine: the defaults).
    let host_spec = from.and_then(|host| diagram.hosts.get(host));
    let ride_out_s = host_spec
        .and_then(|spec| spec.ride_out_s)
        .unwrap_or(kairos_diagram::DEFAULT_RIDE_OUT_S);
    let ride_out_mb = host_spec
        .and_then(|spec| spec.ride_out_mb)
        .unwrap_or(kairos_diagram::DEFAULT_RIDE_OUT_MB);
    sender
        .properties
        .insert("ride_out_s".to_owned(), Value::F64(ride_out_s));
    sender
        .properties
        .insert("ride_out_mb".to_owned(), Value::F64(ride_out_mb));
    // Images and point clouds travel behind the light streams (an IMU, a pose): a full queue of frames
    // then holds back neither their puts nor their delivery.
    let bulk = matches!(data_type, "image" | "point_cloud");
    sender.properties.insert("bulk".to_owned(), Value::Bool(bulk));
    producing.components.push(sender);
    producing.connections.push(Connection {
        policy: Some(if reliable {
            ReaderPolicy::NeverSkipping
        } else {
            ReaderPolicy::Fifo
        }),
        buffer_size: connection.buffer_size,
        subsampling: connection.subsampling,
        ..Connection::new(connection.from.clone(), PortRef::new(&sender_id, "in"))
    });

    let consuming = plan.parts.entry(to.cloned()).or_insert_with(new_part);
    let receiver_id = free_id(
        diagram,
        consuming,
        &format!("link_from_{}_{}", connection.from.component, connection.from.port),
    );
    let queue = connection
        .buffer_size
        .and_then(|q| i64::try_from(q).ok())
        .unwrap_or(64);
    let mut receiver = link_component(
        kairos_pack_link::RECEIVER,
        &receiver_id,
        &key,
        reliable,
        &from_words,
    );
    receiver
        .properties
        .insert("data_type".to_owned(), Value::Text(data_type.to_owned()));
    receiver.properties.insert("queue".to_owned(), Value::I64(queue));
    receiver
        .properties
        .insert("origin".to_owned(), Value::Text(connection.from.to_string()));
    consuming.components.push(receiver);
    consuming.connections.push(Connection {
        from: PortRef::new(&receiver_id, kairos_pack_link::SAMPLES_OUTPUT),
        subsampling: None,
        ..connection.clone()
    });
    CrossLink {
        from: from_words,
        to: to_words,
        key,
        connection: connection.clone(),
        sender: (from.cloned(), sender_id),
        receiver: (to.cloned(), receiver_id),
    }
}

/// Each part's link network, by host (`None`: the deploying machine).
pub type Networks = BTreeMap<Option<String>, LinkNetwork>;

/// Each part's link network: every host with links listens on its own Zenoh endpoint and connects to the
/// hosts after it, or to those before it that take TLS where it does not; this machine, when its part has
/// links, connects to them all. Whoever connects to a `tls/` endpoint trusts the certificates of the hosts
/// section (read from `folder`, the diagram's).
///
/// # Errors
///
/// A `tls/` endpoint of a host without a `certificate`, or a certificate file that cannot be read.
pub fn networks(
    diagram: &Diagram,
    plan: &Plan,
    folder: &Path,
) -> anyhow::Result<BTreeMap<Option<String>, LinkNetwork>> {
    let has_links = |part: &Diagram| {
        part.components
            .iter()
            .any(|c| kairos_pack_link::is_link(&c.type_name))
    };
    let linked: Vec<(&String, String)> = plan
        .parts
        .iter()
        .filter(|(_, part)| has_links(part))
        .filter_map(|(host, _)| host.as_ref())
        .filter_map(|host| diagram.hosts.get(host).map(|spec| (host, spec.zenoh_endpoint())))
        .collect();
    let mut trusted = Vec::new();
    for (host, endpoint) in linked.iter().filter(|(_, e)| e.starts_with("tls/")) {
        let Some(file) = diagram
            .hosts
            .get(*host)
            .and_then(|spec| spec.certificate.as_ref())
        else {
            bail!(
                "host '{host}' takes its links over TLS ({endpoint}) but has no `certificate` to trust in the \
                 hosts section: give it the host's certificate (its kairos serve --tls-cert), or a tcp/ zenoh \
                 endpoint"
            );
        };
        let path = folder.join(file);
        let pem = std::fs::read_to_string(&path)
            .with_context(|| format!("host '{host}': cannot read its certificate {}", path.display()))?;
        if !trusted.contains(&pem) {
            trusted.push(pem);
        }
    }
    // Each pair is joined once. The side that connects chooses the transport, so a host that asked for
    // TLS is the one connected to: its samples never cross in clear because the other side listens on TCP.
    let is_tls = |index: usize| linked[index].1.starts_with("tls/");
    let mut networks = BTreeMap::new();
    for (index, (host, endpoint)) in linked.iter().enumerate() {
        let connect = (0..linked.len())
            .filter(|&other| other != index)
            .filter(|&other| match (is_tls(index), is_tls(other)) {
                (false, true) => true,
                (true, false) => false,
                _ => other > index,
            })
            .map(|other| linked[other].1.clone())
            .collect();
        networks.insert(
            Some((*host).clone()),
            LinkNetwork {
                listen: vec![endpoint.clone()],
                connect,
                trusted_certificates: trusted.clone(),
            },
        );
    }
    if plan.parts.get(&None).is_some_and(has_links) {
        networks.insert(
            None,
            LinkNetwork {
                listen: Vec::new(),
                connect: linked.iter().map(|(_, e)| e.clone()).collect(),
                trusted_certificates: trusted,
            },
        );
    }
    Ok(networks)
}

/// A name for this deployment's keys: the deploying process and the time it started.
pub fn deployment_name() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{:x}{:x}", std::process::id(), nanos & 0xffff_ffff)
}

#[cfg(test)]
mod tests {
    use kairos_diagram::{ComponentInstance, ThreadSettings};

    use super::*;

    fn on(id: &str, host: Option<&str>, group: Option<&str>) -> ComponentInstance {
        let mut component = ComponentInstance::new(id, "core.counter");
        component.host = host.map(str::to_owned);
        component.group = group.map(str::to_owned);
        component
    }

    #[test]
    fn each_part_keeps_its_own_groups_with_their_settings_and_the_sequential_switch() {
        let mut diagram = Diagram {
            components: vec![
                on("a1", Some("a"), Some("on_a")),
                on("a2", Some("a"), Some("on_a")),
                on("here", None, Some("here")),
            ],
            ..Diagram::default()
        };
        let fast = ThreadSettings {
            priority: Some(10),
            ..ThreadSettings::default()
        };
        diagram.groups.insert("on_a".into(), fast.clone());
        diagram.groups.insert("here".into(), ThreadSettings::default());
        let plan = split(&diagram, &Registry::new(), "test").unwrap();
        let part_a = &plan.parts[&Some("a".to_owned())];
        assert_eq!(part_a.groups.keys().collect::<Vec<_>>(), ["on_a"]);
        assert_eq!(part_a.groups["on_a"], fast);
        assert_eq!(part_a.component("a2").unwrap().group.as_deref(), Some("on_a"));
        assert_eq!(plan.parts[&None].groups.keys().collect::<Vec<_>>(), ["here"]);

        let sequential = Diagram {
            components: vec![on("s1", Some("a"), None), on("s2", Some("a"), None)],
            sequential: true,
            ..Diagram::default()
        };
        let plan = split(&sequential, &Registry::new(), "test").unwrap();
        assert!(plan.parts[&Some("a".to_owned())].sequential);
    }
}

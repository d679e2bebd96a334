//! The live ROS 2 graph as `rmw_zenoh` advertises it: every publisher and subscription declares a
//! liveliness token `@ros2_lv/<domain>/<session>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>/
//! <topic>/<type>/<type hash>/<qos>` (`MP` a publisher, `MS` a subscription; names with `/` as `%`), so
//! asking for the tokens under `@ros2_lv/<domain>/**` lists the topics, as `ros2 topic list -t` does, and
//! the services (`SS` a server, `SC` a client), as `ros2 service list -t` does. The studio's topic and
//! service pickers ask this of its runtime, which reaches the ROS 2 machine the diagram will.

use std::collections::BTreeMap;
use std::time::Duration;

use zenoh::Wait as _;

/// One topic on the graph: its name, its type, and how many publishers and subscriptions it has.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topic {
    /// `/imu/data`.
    pub name: String,
    /// `sensor_msgs/msg/Imu`.
    pub type_name: String,
    pub publishers: u32,
    pub subscriptions: u32,
}

/// One service on the graph: its name, its type, and how many servers and clients it has.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Service {
    /// `/reset`.
    pub name: String,
    /// `std_srvs/srv/Trigger`.
    pub type_name: String,
    pub servers: u32,
    pub clients: u32,
}

/// What a graph advertises.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Graph {
    pub topics: Vec<Topic>,
    pub services: Vec<Service>,
}

/// Why the graph could not be listed.
#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    /// No session to the router.
    #[error(transparent)]
    Session(kairos_sdk::ComponentError),
    /// The question could not be asked.
    #[error("cannot ask {router} for the ROS 2 graph: {source}")]
    Query { router: String, source: zenoh::Error },
    /// Nothing answered at the router's address.
    #[error(
        "no ROS 2 router or peer answered at {0} (is `ros2 run rmw_zenoh_cpp rmw_zenohd` running there, and \
         its port open?)"
    )]
    Unreachable(String),
}

/// The topics and services of domain `domain` that `router` (a Zenoh endpoint: `rmw_zenoh`'s router, or a
/// peer) lists within `wait`, by name.
///
/// # Errors
///
/// The router cannot be reached, or refuses the question.
pub fn graph(router: &str, domain: i64, wait: Duration) -> Result<Graph, GraphError> {
    let session = crate::names::open_session(router).map_err(GraphError::Session)?;
    // The session connects in the background: an empty graph and an absent router must not look alike.
    let deadline = std::time::Instant::now() + wait;
    while !connected(&session) {
        if std::time::Instant::now() >= deadline {
            return Err(GraphError::Unreachable(router.to_owned()));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let replies = session
        .liveliness()
        .get(format!("@ros2_lv/{domain}/**"))
        .timeout(wait)
        .wait()
        .map_err(|source| GraphError::Query {
            router: router.to_owned(),
            source,
        })?;
    let mut tokens = Vec::new();
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            tokens.push(sample.key_expr().as_str().to_owned());
        }
    }
    drop(session);
    Ok(Graph {
        topics: topics_of(&tokens),
        services: services_of(&tokens),
    })
}

/// Whether `session` has reached a router or a peer.
fn connected(session: &zenoh::Session) -> bool {
    let info = session.info();
    info.routers_zid().wait().next().is_some() || info.peers_zid().wait().next().is_some()
}

/// The entities of kinds `kinds` (the first counted first, the second second) the liveliness `tokens`
/// advertise, by name then type, with how many of each kind; tokens of other kinds and layouts are passed
/// over.
fn entities_of(tokens: &[String], kinds: [&str; 2]) -> BTreeMap<(String, String), [u32; 2]> {
    let mut found: BTreeMap<(String, String), [u32; 2]> = BTreeMap::new();
    for token in tokens {
        let fields: Vec<&str> = token.split('/').collect();
        let [
            "@ros2_lv",
            _domain,
            _session,
            _node_id,
            _entity_id,
            kind,
            _enclave,
            _namespace,
            _node,
            name,
            dds_type,
            _hash,
            _qos,
        ] = fields.as_slice()
        else {
            continue;
        };
        let Some(which) = kinds.iter().position(|k| k == kind) else {
            continue;
        };
        let Some(type_name) = ros_type_of(dds_type) else {
            continue;
        };
        found.entry((name.replace('%', "/"), type_name)).or_default()[which] += 1;
    }
    found
}

/// The topics the liveliness `tokens` advertise, by name then type.
pub fn topics_of(tokens: &[String]) -> Vec<Topic> {
    entities_of(tokens, ["MP", "MS"])
        .into_iter()
        .map(|((name, type_name), [publishers, subscriptions])| Topic {
            name,
            type_name,
            publishers,
            subscriptions,
        })
        .collect()
}

/// The services the liveliness `tokens` advertise, by name then type.
pub fn services_of(tokens: &[String]) -> Vec<Service> {
    entities_of(tokens, ["SS", "SC"])
        .into_iter()
        .map(|((name, type_name), [servers, clients])| Service {
            name,
            type_name,
            servers,
            clients,
        })
        .collect()
}

/// `sensor_msgs::msg::dds_::Imu_` as ROS 2 names it: `sensor_msgs/msg/Imu`.
fn ros_type_of(dds_type: &str) -> Option<String> {
    let (package, rest) = dds_type.split_once("::")?;
    let (interface, rest) = rest.split_once("::dds_::")?;
    let name = rest.strip_suffix('_')?;
    Some(format!("{package}/{interface}/{name}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_read_from_liveliness_tokens_as_rmw_zenoh_writes_them() {
        let tokens = [
            // The design document's publisher, a second one on the same topic, a subscription on a
            // namespaced topic, a node and a service server (not topics), and a token of another layout.
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,7:,:,:,,",
            "@ros2_lv/2/aa/0/11/MP/%/%/talker2/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,7:,:,:,,",
            "@ros2_lv/2/bb/0/3/MS/%/%robot1/planner/%robot1%cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_y/::,10:,:,:,,",
            "@ros2_lv/2/bb/0/0/NN/%/%robot1/planner",
            "@ros2_lv/2/bb/0/4/SS/%/%robot1/planner/%plan/nav_msgs::srv::dds_::GetPlan_/RIHS01_z/::,10:,:,:,,",
            "@ros2_lv/2/cc/0/5/MP/%/%/old/%chatter",
        ]
        .map(str::to_owned);
        assert_eq!(
            topics_of(&tokens),
            [
                Topic {
                    name: "/chatter".into(),
                    type_name: "std_msgs/msg/String".into(),
                    publishers: 2,
                    subscriptions: 0,
                },
                Topic {
                    name: "/robot1/cmd_vel".into(),
                    type_name: "geometry_msgs/msg/Twist".into(),
                    publishers: 0,
                    subscriptions: 1,
                },
            ]
        );
        assert_eq!(
            services_of(&tokens),
            [Service {
                name: "/plan".into(),
                type_name: "nav_msgs/srv/GetPlan".into(),
                servers: 1,
                clients: 0,
            }]
        );
    }
}

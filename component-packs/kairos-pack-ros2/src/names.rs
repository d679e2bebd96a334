//! How `rmw_zenoh` names ROS 2 on Zenoh: key expressions, liveliness tokens, `QoS` in words, attachments,
//! and the Zenoh session that reaches ROS 2 nodes. Shared by the publisher and the subscriber.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError, Weak};

use kairos_sdk::descriptor::Property;
use kairos_sdk::{ComponentError, Context};
use zenoh::Wait as _;
use zenoh::liveliness::LivelinessToken;

/// The message types the components carry: those Kairos has definitions of (docs/ros2.md lists them).
pub const TYPES: [&str; 13] = [
    "std_msgs/msg/String",
    "std_msgs/msg/Float64",
    "std_msgs/msg/Int64",
    "std_msgs/msg/Bool",
    "std_msgs/msg/Float64MultiArray",
    "std_msgs/msg/UInt8MultiArray",
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/NavSatFix",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/PointCloud2",
    "geometry_msgs/msg/PoseStamped",
    "can_msgs/msg/Frame",
];

/// The ROS 2 releases whose `rmw_zenoh` conventions differ: Humble's carries no type hashes.
pub const DISTROS: [&str; 2] = ["jazzy", "humble"];

/// What Humble's `rmw_zenoh` writes where later releases write a type hash.
pub const NO_TYPE_HASH: &str = "TypeHashNotSupported";

/// The properties every ROS 2 component has: where ROS 2 is, under which node, and which release.
pub fn node_properties() -> [Property; 5] {
    [
        Property::i64("domain_id", 0)
            .range(0.0, 232.0)
            .doc("The ROS 2 domain (ROS_DOMAIN_ID)"),
        Property::text("router", "tcp/localhost:7447").doc(
            "The Zenoh endpoint to connect to: rmw_zenoh's router (`ros2 run rmw_zenoh_cpp rmw_zenohd`) on \
             this machine by default, or another machine's (tcp/192.168.1.10:7447)",
        ),
        Property::text("node", "kairos").doc("The ROS 2 node name the topic is listed under"),
        Property::text("namespace", "/").doc("The node's namespace"),
        Property::choice("distro", &DISTROS, "jazzy").doc(
            "The ROS 2 release the other nodes run: jazzy for Jazzy, Kilted and Rolling (topics keyed by \
             their type hash), humble for Humble (rmw_zenoh 0.1: no type hashes)",
        ),
    ]
}

/// The properties of a topic's publisher and subscriber besides their node's.
pub fn topic_properties() -> [Property; 2] {
    [
        Property::choice("durability", &["volatile", "transient_local"], "volatile").doc(
            "volatile: messages from now on; transient_local: also the last `depth` messages published \
             before (a map, a static transform), as rmw_zenoh keeps and asks for them",
        ),
        Property::i64("depth", 10).range(1.0, 10_000.0).doc(
            "The history depth (keep last): how many messages a transient-local topic keeps or asks for",
        ),
    ]
}

/// The type hash a key expression and a liveliness token carry for `ros_type` on `distro`.
pub fn type_hash_on(distro: &str, ros_type: &str) -> Option<String> {
    if distro == "humble" {
        return Some(NO_TYPE_HASH.to_owned());
    }
    kairos_pack_recording::ros2::write::type_hash(ros_type)
}

/// The key expression on which a transient-local publisher answers for the messages it keeps, and under
/// which it declares its liveliness, as `zenoh-ext`'s advanced publisher does (Zenoh 1.3 and later):
/// `<topic key>/@adv/pub/<session>/uhlc/_`, `uhlc` saying that its messages are told apart by their
/// timestamps (from the session's clock), by which a subscription that gets one twice keeps one.
pub fn cache_key(topic_key: &str, session: &str) -> String {
    format!("{topic_key}/@adv/pub/{session}/uhlc/_")
}

/// The most messages a history query asks for (`_max` in its parameters), if it says.
pub fn most_asked(parameters: &str) -> Option<usize> {
    parameters
        .split(';')
        .find_map(|pair| pair.strip_prefix("_max="))
        .and_then(|value| value.parse().ok())
}

/// `sensor_msgs/msg/Imu` as DDS and `rmw_zenoh` name it: `sensor_msgs::msg::dds_::Imu_`; a service
/// (`std_srvs/srv/Trigger`) as `std_srvs::srv::dds_::Trigger_`.
pub fn dds_type_name(ros_type: &str) -> String {
    let mut parts: Vec<&str> = ros_type.split('/').collect();
    let name = parts.pop().unwrap_or_default();
    let package = parts.first().copied().unwrap_or_default();
    let interface = if parts.get(1) == Some(&"srv") {
        "srv"
    } else {
        "msg"
    };
    format!("{package}::{interface}::dds_::{name}_")
}

/// A ROS 2 name's slashes as `%`, as liveliness tokens carry names (`/` alone is `%`).
pub fn mangled(name: &str) -> String {
    name.replace('/', "%")
}

/// The key expression of a topic's samples.
pub fn topic_key(domain: i64, topic: &str, ros_type: &str, type_hash: &str) -> String {
    format!(
        "{domain}/{}/{}/{type_hash}",
        topic.trim_matches('/'),
        dds_type_name(ros_type)
    )
}

/// A `QoS` in words as liveliness tokens carry it: each field left empty when it is `rmw_zenoh`'s default
/// (reliable, volatile, keep last, depth 42, no deadline, lifespan or liveliness lease); otherwise the
/// number of rmw's enumeration (best effort 2, transient local 1).
pub fn qos_words(reliable: bool, transient_local: bool, depth: i64) -> String {
    let reliability = if reliable { "" } else { "2" };
    let durability = if transient_local { "1" } else { "" };
    let depth = if depth == 42 {
        String::new()
    } else {
        depth.to_string()
    };
    format!("{reliability}:{durability}:,{depth}:,:,:,,")
}

/// Where a ROS 2 entity is declared: its domain, session, node and namespace.
#[derive(Debug, Clone)]
pub struct NodeName {
    pub domain: i64,
    pub session: String,
    pub node: String,
    pub namespace: String,
}

impl NodeName {
    /// The node's liveliness token (`NN`).
    pub fn node_token(&self) -> String {
        format!(
            "@ros2_lv/{}/{}/0/0/NN/%/{}/{}",
            self.domain,
            self.session,
            mangled(&self.namespace),
            self.node
        )
    }

    /// A publisher's (`MP`), subscription's (`MS`), service server's (`SS`) or client's (`SC`) liveliness
    /// token; `entity` numbers it in the session.
    pub fn entity_token(
        &self,
        entity: u64,
        kind: &str,
        topic: &str,
        ros_type: &str,
        type_hash: &str,
        qos: &str,
    ) -> String {
        format!(
            "@ros2_lv/{}/{}/0/{entity}/{kind}/%/{}/{}/{}/{}/{type_hash}/{qos}",
            self.domain,
            self.session,
            mangled(&self.namespace),
            self.node,
            mangled(topic),
            dds_type_name(ros_type),
        )
    }
}

/// What a sample's attachment says: its publisher's sequence number, source time and `GID`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    pub sequence: i64,
    pub source_time_ns: i64,
    pub gid: [u8; 16],
}

impl Attachment {
    /// The 33 bytes on the wire (`zenoh-ext`'s serialisation of `(i64, i64, [u8; 16])`).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(33);
        bytes.extend_from_slice(&self.sequence.to_le_bytes());
        bytes.extend_from_slice(&self.source_time_ns.to_le_bytes());
        bytes.push(16);
        bytes.extend_from_slice(&self.gid);
        bytes
    }

    /// Reads an attachment; `None` for one in another layout (before `rmw_zenoh` 0.6, fields were named).
    pub fn parse(bytes: &[u8]) -> Option<Attachment> {
        if bytes.len() != 33 || bytes[16] != 16 {
            return None;
        }
        Some(Attachment {
            sequence: i64::from_le_bytes(bytes[..8].try_into().ok()?),
            source_time_ns: i64::from_le_bytes(bytes[8..16].try_into().ok()?),
            gid: bytes[17..].try_into().ok()?,
        })
    }
}

/// A `GID` for an entity: the first 16 bytes of the SHA-256 of its liveliness token (unique as the token).
pub fn gid_of(token: &str) -> [u8; 16] {
    use sha2::Digest as _;
    let digest = sha2::Sha256::digest(token.as_bytes());
    let mut gid = [0; 16];
    gid.copy_from_slice(&digest[..16]);
    gid
}

/// Checks a ROS 2 topic name (`/imu/data`): a leading slash, then words of letters, digits and `_`.
pub fn check_topic(topic: &str) -> Result<(), ComponentError> {
    let valid = topic.starts_with('/')
        && topic.len() > 1
        && topic[1..].split('/').all(|word| {
            !word.is_empty()
                && !word.starts_with(|c: char| c.is_ascii_digit())
                && word.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        });
    if valid {
        Ok(())
    } else {
        Err(ComponentError::failed(format_args!(
            "topic {topic:?} is not a ROS 2 topic name: a leading /, then words of letters, digits and _ \
             separated by / (/imu/data)"
        )))
    }
}

/// A ROS 2 node on one Zenoh session, shared by the components of this process that name the same
/// router, domain, node and namespace: one node in `ros2 node list`, each component an entity of it.
pub struct SharedNode {
    /// The session (closed when the last component lets the node go).
    pub session: zenoh::Session,
    /// Its names.
    pub name: NodeName,
    _token: LivelinessToken,
    next_entity: AtomicU64,
}

impl SharedNode {
    /// A number for a new publisher or subscription, unique in the session (the node is 0).
    pub fn entity_id(&self) -> u64 {
        self.next_entity.fetch_add(1, Ordering::Relaxed)
    }

    /// Declares a new entity of this node in ROS 2's graph (`kind` `MP`, `MS`, `SS` or `SC`, named `name`,
    /// of `ros_type` with `type_hash` and `qos`): its liveliness token, and the token's key, which its
    /// GID is made from.
    pub fn declare_entity(
        &self,
        kind: &str,
        name: &str,
        ros_type: &str,
        type_hash: &str,
        qos: &str,
    ) -> Result<(LivelinessToken, String), ComponentError> {
        let key = self
            .name
            .entity_token(self.entity_id(), kind, name, ros_type, type_hash, qos);
        let token = self
            .session
            .liveliness()
            .declare_token(key.clone())
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot declare {key}: {e}")))?;
        Ok((token, key))
    }
}

impl std::fmt::Debug for SharedNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedNode")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl Drop for SharedNode {
    fn drop(&mut self) {
        let _ = self.session.close().wait();
    }
}

/// The node a component's properties name: the process's, if another component already opened it.
pub fn node(ctx: &Context) -> Result<Arc<SharedNode>, ComponentError> {
    type Nodes = Mutex<HashMap<(String, i64, String, String), Weak<SharedNode>>>;
    static NODES: OnceLock<Nodes> = OnceLock::new();
    let node = ctx.text_property("node")?;
    if node.is_empty()
        || node.starts_with(|c: char| c.is_ascii_digit())
        || !node.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    {
        return Err(ComponentError::failed(format_args!(
            "node {node:?} is not a ROS 2 node name: letters, digits and _, not starting with a digit"
        )));
    }
    let namespace = ctx.text_property("namespace")?;
    if namespace != "/" {
        check_topic(&namespace).map_err(|_| {
            ComponentError::failed(format_args!(
                "namespace {namespace:?} is not a ROS 2 namespace (/ or /robot1)"
            ))
        })?;
    }
    let router = ctx.text_property("router")?;
    let domain = ctx.i64_property("domain_id")?;
    let key = (router.clone(), domain, node.clone(), namespace.clone());
    let mut nodes = NODES
        .get_or_init(Nodes::default)
        .lock()
        .unwrap_or_else(PoisonError::into_inner);
    if let Some(shared) = nodes.get(&key).and_then(Weak::upgrade) {
        return Ok(shared);
    }
    let session = open_session(&router)?;
    let name = NodeName {
        domain,
        session: session.zid().to_string(),
        node,
        namespace,
    };
    let token = session
        .liveliness()
        .declare_token(name.node_token())
        .wait()
        .map_err(|e| ComponentError::failed(format_args!("cannot declare the node's liveliness: {e}")))?;
    let shared = Arc::new(SharedNode {
        session,
        name,
        _token: token,
        next_entity: AtomicU64::new(1),
    });
    nodes.retain(|_, node| node.strong_count() > 0);
    nodes.insert(key, Arc::downgrade(&shared));
    Ok(shared)
}

/// A Zenoh session as `rmw_zenoh`'s peers open theirs: a peer, connecting to `router`, with no multicast
/// scouting (ROS 2 nodes are found through the router, or the peer connected to).
pub fn open_session(router: &str) -> Result<zenoh::Session, ComponentError> {
    let mut config = zenoh::Config::default();
    let endpoints = if router.is_empty() {
        "[]".to_owned()
    } else {
        serde_json::to_string(&[router]).unwrap_or_else(|_| "[]".to_owned())
    };
    for (key, value) in [
        ("mode", "\"peer\"".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("connect/endpoints", endpoints),
        ("listen/endpoints", "[\"tcp/127.0.0.1:0\"]".to_owned()),
    ] {
        config
            .insert_json5(key, &value)
            .map_err(|e| ComponentError::failed(format_args!("the Zenoh setting {key} = {value}: {e}")))?;
    }
    zenoh::open(config)
        .wait()
        .map_err(|e| ComponentError::failed(format_args!("cannot open a Zenoh session to {router}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_written_as_rmw_zenoh_s_design_document_gives_them() {
        // The design document's own example.
        assert_eq!(
            topic_key(
                0,
                "/chatter",
                "std_msgs/msg/String",
                "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
            ),
            "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
        assert_eq!(
            topic_key(2, "/robot1/chatter", "std_msgs/msg/String", "H"),
            "2/robot1/chatter/std_msgs::msg::dds_::String_/H"
        );
        assert_eq!(qos_words(true, false, 10), "::,10:,:,:,,");
        assert_eq!(qos_words(false, false, 10), "2::,10:,:,:,,");
        assert_eq!(qos_words(true, false, 42), "::,:,:,:,,");
        assert_eq!(qos_words(true, true, 1), ":1:,1:,:,:,,");
        assert_eq!(
            cache_key("0/map/nav_msgs::msg::dds_::OccupancyGrid_/H", "8b20"),
            "0/map/nav_msgs::msg::dds_::OccupancyGrid_/H/@adv/pub/8b20/uhlc/_"
        );
        assert_eq!(most_asked("_max=5;_anyke"), Some(5));
        assert_eq!(most_asked("_anyke"), None);
        assert_eq!(
            type_hash_on("humble", "std_msgs/msg/String").as_deref(),
            Some(NO_TYPE_HASH)
        );
        let node = NodeName {
            domain: 2,
            session: "8b20917502ee955ac4476e0266340d5c".to_owned(),
            node: "talker".to_owned(),
            namespace: "/".to_owned(),
        };
        assert_eq!(
            node.node_token(),
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/0/NN/%/%/talker"
        );
        assert_eq!(
            node.entity_token(
                10,
                "MP",
                "/chatter",
                "std_msgs/msg/String",
                "RIHS01_x",
                &qos_words(true, false, 7)
            ),
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,7:,:,:,,"
        );
    }

    #[test]
    fn an_attachment_is_33_bytes_and_reads_back() {
        let attachment = Attachment {
            sequence: 7,
            source_time_ns: 1_795_000_000_123_456_789,
            gid: gid_of("token"),
        };
        let bytes = attachment.to_bytes();
        assert_eq!(bytes.len(), 33);
        assert_eq!(&bytes[..8], &7_i64.to_le_bytes());
        assert_eq!(Attachment::parse(&bytes), Some(attachment));
        assert_eq!(Attachment::parse(&bytes[..32]), None);
    }

    #[test]
    fn topic_names_are_checked() {
        assert!(check_topic("/imu/data").is_ok());
        for bad in ["imu", "/", "/imu//data", "/imu data", "/9lives"] {
            assert!(check_topic(bad).is_err(), "{bad}");
        }
    }
}

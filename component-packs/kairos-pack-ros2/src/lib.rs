//! Live ROS 2 topics, with no ROS installed: `ros2.publisher` and `ros2.subscriber` speak to ROS 2 nodes
//! running `rmw_zenoh` (ROS 2's Zenoh middleware) on Zenoh, as that middleware maps ROS 2 onto it, so
//! `ros2 topic echo` sees a Kairos topic and a Kairos diagram receives a ROS 2 node's.
//!
//! The conventions followed are those of `rmw_zenoh_cpp` 0.6 and later (its `docs/design.md`; ROS 2 Jazzy
//! 0.2.4 and later, Kilted, Rolling; checked against 0.10.4): a topic's samples go on the key expression
//! `<domain>/<topic without its outer slashes>/<package>::msg::dds_::<Type>_/<type hash>`, each with a
//! 33-byte attachment (sequence number and source time as little-endian `i64`, then 16, then the
//! publisher's 16-byte `GID`), its payload the message in CDR; and each node, publisher and subscription
//! declares a liveliness token under `@ros2_lv/<domain>/...`, which is how ROS 2's graph tools list them.
//! Humble's `rmw_zenoh` (0.1) differs only in carrying `TypeHashNotSupported` for the type hash (the
//! `distro` property). Transient-local topics follow `zenoh-ext`'s advanced publisher and subscriber (Zenoh
//! 1.3 and later), which `rmw_zenoh` uses for them: see `docs/ros2.md`.

pub mod graph;
pub mod names;
pub mod publisher;
pub mod service_client;
pub mod service_server;
pub mod services;
pub mod subscriber;

use kairos_sdk::Registry;

/// Registers the pack "ros2".
pub fn register(registry: &mut Registry) {
    registry
        .pack("ros2", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<publisher::Publisher>(publisher::descriptor())
        .component_described::<subscriber::Subscriber>(subscriber::descriptor(), subscriber::describe)
        .component::<service_client::ServiceClient>(service_client::descriptor())
        .component::<service_server::ServiceServer>(service_server::descriptor());
}

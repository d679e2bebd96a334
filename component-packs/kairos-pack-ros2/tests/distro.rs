//! A publisher keys its topic as the ROS 2 release it is told the other nodes run: Humble's `rmw_zenoh`
//! carries `TypeHashNotSupported` where later releases carry the type hash, in the key expression and in
//! the liveliness token, and a node of one release matches only a topic keyed for it.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failure here is a failed test"
)]

use std::net::TcpListener;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use kairos_pack_ros2::publisher::{Publisher, descriptor};
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Timestamp};
use zenoh::Wait as _;

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The key expression and the liveliness token a publisher told `distro` uses, as a node listening on
/// loopback sees them.
fn keyed_for(distro: &str) -> (String, Vec<String>) {
    let port = free_port();
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("listen/endpoints", format!("[\"tcp/127.0.0.1:{port}\"]")),
    ] {
        config.insert_json5(key, &value).unwrap();
    }
    let node = zenoh::open(config).wait().unwrap();
    let keys = Arc::new(Mutex::new(Vec::new()));
    let _subscriber = node
        .declare_subscriber("0/release/**")
        .callback({
            let keys = Arc::clone(&keys);
            move |sample| keys.lock().unwrap().push(sample.key_expr().to_string())
        })
        .wait()
        .unwrap();
    let mut publisher = Harness::new(descriptor(), Publisher::default());
    publisher
        .set_property("topic", "/release")
        .and_then(|h| h.set_property("router", format!("tcp/127.0.0.1:{port}")))
        .and_then(|h| h.set_property("distro", distro))
        .unwrap();
    let start = Instant::now();
    let mut tick = 0;
    while keys.lock().unwrap().is_empty() && start.elapsed() < Duration::from_secs(10) {
        tick += 1;
        publisher
            .push("in", Payload::F64(1.5), Timestamp::from_millis(tick))
            .run()
            .unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    let tokens = node
        .liveliness()
        .get("@ros2_lv/0/**")
        .wait()
        .unwrap()
        .iter()
        .filter_map(|reply| Some(reply.result().ok()?.key_expr().to_string()))
        .filter(|token| token.contains("/MP/"))
        .collect();
    let key = keys.lock().unwrap().first().cloned().expect("a message");
    (key, tokens)
}

#[test]
fn humble_s_topics_carry_no_type_hash_and_later_releases_carry_theirs() {
    let (key, tokens) = keyed_for("humble");
    assert_eq!(
        key,
        "0/release/std_msgs::msg::dds_::Float64_/TypeHashNotSupported"
    );
    assert!(
        tokens.iter().any(|t| t.ends_with(
            "/MP/%/%/kairos/%release/std_msgs::msg::dds_::Float64_/TypeHashNotSupported/::,10:,:,:,,"
        )),
        "{tokens:?}"
    );
    let (key, tokens) = keyed_for("jazzy");
    // REP 2011's hash of std_msgs/msg/Float64, as rosbags computes it.
    let hash = "RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a";
    assert_eq!(key, format!("0/release/std_msgs::msg::dds_::Float64_/{hash}"));
    assert!(tokens.iter().any(|t| t.contains(hash)), "{tokens:?}");
}

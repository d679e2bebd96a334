//! A reliable link whose receiver still matches but goes silent, then dead: the sender's heartbeat
//! says both in its status, Zenoh's matching never moving, and says when the receiver is back.
//!
//! The far end is a Zenoh peer of its own (another session, over TCP on loopback), playing a link
//! receiver that can be made to stop receiving while it keeps matching: first still answering with a
//! frozen count (silent), then not answering at all (dead). Zenoh's own matching never changes, which
//! is the fault seen in the field after a reconnection that flapped once more.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failure here is a failed test"
)]

use std::net::TcpListener;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use kairos_diagram::{ComponentInstance, Diagram};
use kairos_pack_link::{LinkSender, network};
use kairos_protocol::LinkNetwork;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Timestamp, Value};
use zenoh::Wait as _;

const KEY: &str = "test/heartbeat";

/// How the fake receiver behaves.
const RECEIVING: u8 = 0;
/// Drops every sample and answers the count it had when frozen.
const FROZEN: u8 = 1;
/// Drops every sample and every question.
const DEAD: u8 = 2;

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The far end: the sequence numbers it received, in order, and its newest.
struct FarEnd {
    mode: Arc<AtomicU8>,
    received: Arc<Mutex<Vec<u64>>>,
    _session: zenoh::Session,
    _subscriber: zenoh::pubsub::Subscriber<()>,
    _queryable: zenoh::query::Queryable<()>,
}

fn far_end(port: u16) -> FarEnd {
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("connect/endpoints", format!("[\"tcp/127.0.0.1:{port}\"]")),
    ] {
        config.insert_json5(key, &value).unwrap();
    }
    let session = zenoh::open(config).wait().unwrap();
    let mode = Arc::new(AtomicU8::new(RECEIVING));
    let received = Arc::new(Mutex::new(Vec::new()));
    let newest = Arc::new(AtomicU64::new(u64::MAX));
    let subscriber = session
        .declare_subscriber(KEY)
        .callback({
            let (mode, received, newest) = (mode.clone(), received.clone(), newest.clone());
            move |sample| {
                if mode.load(Ordering::Acquire) != RECEIVING {
                    return;
                }
                let frame = sample.payload().to_bytes();
                let sequence = kairos_sample_frame::decode(&frame).unwrap().sequence;
                let mut received = received.lock().unwrap();
                // In order, as a link receiver takes them: a repeat is not taken again.
                if received.last().is_none_or(|last| sequence > *last) {
                    received.push(sequence);
                    newest.store(sequence, Ordering::Release);
                }
            }
        })
        .wait()
        .unwrap();
    let queryable = session
        .declare_queryable(format!("{KEY}/newest"))
        .callback({
            let (mode, newest) = (mode.clone(), newest.clone());
            move |query| {
                if mode.load(Ordering::Acquire) != DEAD {
                    let answer = newest.load(Ordering::Acquire).to_string();
                    query.reply(query.key_expr().clone(), answer).wait().unwrap();
                }
            }
        })
        .wait()
        .unwrap();
    FarEnd {
        mode,
        received,
        _session: session,
        _subscriber: subscriber,
        _queryable: queryable,
    }
}

/// The sender in the SDK's harness, as the engine runs it: one `core` call per sample pushed.
fn sender(ride_out_s: f64) -> Harness {
    let mut harness = Harness::new(kairos_pack_link::sender_descriptor(), LinkSender::default());
    harness
        .set_property("key", KEY)
        .and_then(|h| h.set_property("reliable", true))
        .and_then(|h| h.set_property("peer", "host 'b'"))
        .and_then(|h| h.set_property("ride_out_s", ride_out_s))
        .unwrap();
    harness
}

/// Sends a sample every 5 ms for `how_long`, or until `until` says so on the sender's status.
fn send_for(
    link: &mut Harness,
    how_long: Duration,
    until: impl Fn(&serde_json::Value) -> bool,
) -> Option<Duration> {
    let start = Instant::now();
    let mut sequence = 0_i64;
    while start.elapsed() < how_long {
        sequence += 1;
        link.push("in", Payload::F64(1.0), Timestamp(sequence * 5_000_000));
        link.run().unwrap();
        if until(&link.status().unwrap()) {
            return Some(start.elapsed());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

#[test]
fn a_matched_receiver_that_goes_silent_then_dead_is_said_and_so_is_its_return() {
    let port = free_port();
    network::join(&LinkNetwork {
        listen: vec![format!("tcp/127.0.0.1:{port}")],
        ..LinkNetwork::default()
    })
    .unwrap();
    let mut end = ComponentInstance::new("link_to_b", kairos_pack_link::SENDER);
    end.properties.insert("key".into(), Value::Text(KEY.into()));
    end.properties.insert("reliable".into(), Value::Bool(true));
    network::prepare(&Diagram {
        components: vec![end],
        ..Diagram::default()
    })
    .unwrap();
    let far = far_end(port);
    let mut link = sender(5.0);
    let matched = |status: &serde_json::Value| status["matched"] == true;
    send_for(&mut link, Duration::from_secs(5), |_| {
        network::matched(&network::sender(KEY).unwrap())
    })
    .expect("the far end never matched");

    // Healthy: answered, never silent.
    send_for(&mut link, Duration::from_millis(2500), |_| false);
    let status = link.status().unwrap();
    assert!(matched(&status) && status["answering"] == true, "{status}");
    assert!(status["silent_s"].is_null(), "{status}");

    // Silent: still answering, with a count that no longer moves.
    far.mode.store(FROZEN, Ordering::Release);
    let said = send_for(&mut link, Duration::from_secs(6), |status| {
        status["silent_s"].as_f64().is_some_and(|silent| silent >= 2.0)
    });
    let said = said.expect("a receiver that answers but receives nothing was never said silent");
    assert!(said < Duration::from_millis(3500), "said silent after {said:?}");
    let status = link.status().unwrap();
    assert!(matched(&status), "a silent receiver is not a cut: {status}");

    // Dead: no answer at all, while Zenoh still says it matches.
    far.mode.store(DEAD, Ordering::Release);
    let said = send_for(&mut link, Duration::from_secs(6), |status| {
        status["answering"] == false
    })
    .expect("a receiver that stopped answering was never said");
    assert!(said < Duration::from_secs(3), "said after {said:?}");
    assert!(
        network::matched(&network::sender(KEY).unwrap()),
        "Zenoh's matching must not have moved"
    );
    let status = link.status().unwrap();
    assert!(matched(&status), "{status}");

    // Back: answering and receiving again. What the far end dropped meanwhile is a gap a real receiver
    // counts; the link itself was never cut, so nothing is sent twice.
    far.mode.store(RECEIVING, Ordering::Release);
    let back = send_for(&mut link, Duration::from_secs(5), |status| {
        status["answering"] == true && status["silent_s"].is_null()
    });
    assert!(back.is_some(), "{}", link.status().unwrap());
    let status = link.status().unwrap();
    assert_eq!(status["put_again"], 0, "{status}");
    let received = far.received.lock().unwrap().clone();
    let gaps = received.windows(2).filter(|pair| pair[1] != pair[0] + 1).count();
    assert_eq!(
        gaps, 1,
        "one gap, where the far end dropped what came: {received:?}"
    );
}

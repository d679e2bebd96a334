//! `ros2.subscriber`: a ROS 2 topic from nodes running `rmw_zenoh`, each message a sample of the Kairos
//! type its ROS message maps to.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::time::Duration;

use kairos_pack_recording::decode::DecodeError;
use kairos_pack_recording::ros2::write::definition_of;
use kairos_pack_recording::ros2::{Definitions, data_type_of, header_stamp, to_payload};
use kairos_sdk::DeviceKind;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, Timestamp,
    Value,
};
use zenoh::Wait as _;
use zenoh::key_expr::KeyExpr;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber as ZenohSubscriber;
use zenoh::query::{ConsolidationMode, QueryTarget};
use zenoh::sample::{Sample as ZenohSample, SampleKind};

use crate::names::{self, Attachment};

/// Messages received and not yet written, at most: past it, the newest are dropped and counted.
const QUEUE: usize = 1024;
/// How long one wait for a message lasts, so stop and control requests get through.
const RECEIVE_WAIT: Duration = Duration::from_millis(100);
/// How long a transient-local subscription waits, as it starts, for the publishers' kept messages.
const HISTORY_WAIT: Duration = Duration::from_secs(2);

fn base() -> Descriptor {
    let mut descriptor = Descriptor::new(
        "ros2.subscriber",
        "ros2",
        "Receives a ROS 2 topic from nodes running rmw_zenoh: each message a sample of the Kairos type its \
         ROS message maps to (docs/ros2.md), stamped with its header's time",
    )
    .label("ROS 2 subscriber")
    .property(
        Property::text("topic", "/chatter")
            .doc("The ROS 2 topic (/imu/data)")
            .device(DeviceKind::Ros2Topic),
    )
    .property(
        Property::choice("type", &names::TYPES, "std_msgs/msg/String")
            .doc("The topic's ROS message type (`ros2 topic info` says it)"),
    );
    for property in names::node_properties()
        .into_iter()
        .chain(names::topic_properties())
    {
        descriptor = descriptor.property(property);
    }
    descriptor
}

/// The output for messages of `ros_type`.
fn with_output(ros_type: &str) -> ComponentInfo {
    base()
        .output("out", data_type_of(ros_type), "Each message received")
        .build()
}

/// The descriptor of `ros2.subscriber` as listed (a `std_msgs/msg/String` topic).
pub fn descriptor() -> ComponentInfo {
    with_output(names::TYPES[0])
}

/// The descriptor of one `ros2.subscriber`: its output typed from its `type`.
pub fn describe(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    let ros_type = properties
        .get("type")
        .and_then(Value::as_text)
        .unwrap_or(names::TYPES[0]);
    Ok(with_output(ros_type))
}

/// One message as it arrived.
struct Arrived {
    payload: Vec<u8>,
    attachment: Option<Vec<u8>>,
}

impl Arrived {
    fn of(sample: &ZenohSample) -> Arrived {
        Arrived {
            payload: sample.payload().to_bytes().into_owned(),
            attachment: sample.attachment().map(|a| a.to_bytes().into_owned()),
        }
    }
}

/// A history query for a transient-local topic: the last `depth` messages each publisher that matches
/// `pattern` kept, whatever key they come back on (`_anyke`: they come on the topic's own key).
fn history_query(pattern: &str, depth: i64) -> String {
    format!("{pattern}?_max={depth};_anyke")
}

/// `ros2.subscriber`. See [`descriptor`].
#[derive(Default)]
pub struct Subscriber {
    node: Option<Arc<names::SharedNode>>,
    token: Option<LivelinessToken>,
    subscription: Option<ZenohSubscriber<()>>,
    /// For a transient-local subscription: publishers that come later, each asked for what it kept.
    late_publishers: Option<ZenohSubscriber<()>>,
    /// Kept messages received as the subscription started, written before the live ones.
    kept: std::collections::VecDeque<Arrived>,
    messages: Option<Receiver<Arrived>>,
    definitions: Option<Definitions>,
    data_type: Option<DataType>,
    /// The last sequence number seen from each publisher (by `GID`): a jump is messages lost.
    last_sequence: HashMap<[u8; 16], i64>,
    received: u64,
    lost: u64,
    /// Messages received twice (a kept one also live), written once.
    repeated: u64,
    undecodable: u64,
    dropped: Arc<AtomicU64>,
    key: String,
}

impl Subscriber {
    /// What the topic's transient-local publishers kept, as they answer within [`HISTORY_WAIT`].
    fn ask_history(
        &self,
        session: &zenoh::Session,
        topic: &KeyExpr<'static>,
        depth: i64,
    ) -> Result<std::collections::VecDeque<Arrived>, ComponentError> {
        let query = history_query(&format!("{}/@adv/**", self.key), depth);
        let replies = session
            .get(query.as_str())
            .target(QueryTarget::All)
            .consolidation(ConsolidationMode::None)
            .timeout(HISTORY_WAIT)
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot ask for {query}: {e}")))?;
        let mut kept = std::collections::VecDeque::new();
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result()
                && sample.key_expr().intersects(topic)
            {
                kept.push_back(Arrived::of(sample));
            }
        }
        Ok(kept)
    }

    /// Asks each transient-local publisher that appears later (its liveliness token) for what it kept;
    /// the answers join the live messages.
    fn watch_late_publishers(
        &self,
        session: &zenoh::Session,
        topic: KeyExpr<'static>,
        depth: i64,
        messages: SyncSender<Arrived>,
    ) -> Result<ZenohSubscriber<()>, ComponentError> {
        let publishers = format!("{}/@adv/pub/**", self.key);
        let asking = session.clone();
        let dropped = Arc::clone(&self.dropped);
        session
            .liveliness()
            .declare_subscriber(publishers.clone())
            .callback(move |token| {
                if token.kind() != SampleKind::Put {
                    return;
                }
                let (messages, dropped, topic) = (messages.clone(), Arc::clone(&dropped), topic.clone());
                let query = history_query(token.key_expr().as_str(), depth);
                let asked = asking
                    .get(query.as_str())
                    .target(QueryTarget::All)
                    .consolidation(ConsolidationMode::None)
                    .callback(move |reply| {
                        let Ok(sample) = reply.result() else { return };
                        if sample.key_expr().intersects(&topic)
                            && let Err(TrySendError::Full(_)) = messages.try_send(Arrived::of(sample))
                        {
                            dropped.fetch_add(1, Ordering::Relaxed);
                        }
                    })
                    .wait();
                if let Err(why) = asked {
                    tracing::warn!("cannot ask a late publisher for what it kept ({query}): {why}");
                }
            })
            .wait()
            .map_err(|e| {
                ComponentError::failed(format_args!("cannot watch for publishers on {publishers}: {e}"))
            })
    }

    fn write(&mut self, ctx: &mut Context, arrived: &Arrived) -> ComponentResult {
        let attachment = arrived.attachment.as_deref().and_then(Attachment::parse);
        if let Some(attachment) = attachment {
            // A publisher numbers its messages one by one: one already passed was written (a kept
            // message that also came live, or the other way round).
            let last = self.last_sequence.get(&attachment.gid).copied();
            if last.is_some_and(|last| attachment.sequence <= last) {
                self.repeated += 1;
                return Ok(());
            }
            self.last_sequence.insert(attachment.gid, attachment.sequence);
            if let Some(last) = last
                && attachment.sequence > last + 1
            {
                self.lost += u64::try_from(attachment.sequence - last - 1).unwrap_or(0);
            }
        }
        self.received += 1;
        let (Some(definitions), Some(data_type)) = (&self.definitions, &self.data_type) else {
            return Err(ComponentError::Stopped);
        };
        let decoded = definitions
            .decode(&arrived.payload)
            .map_err(DecodeError::from)
            .and_then(|value| {
                Ok((
                    to_payload(definitions, &value, data_type)?,
                    header_stamp(definitions, &value),
                ))
            });
        match decoded {
            Ok((payload, stamp)) => {
                // The header's stamp, else the publisher's source time, else now.
                let stamp = stamp
                    .filter(|s| s.as_nanos() > 0)
                    .or_else(|| attachment.map(|a| Timestamp(a.source_time_ns)));
                match stamp {
                    Some(stamp) => ctx.write_at("out", payload, stamp),
                    None => ctx.write("out", payload),
                }
            }
            Err(why) => {
                if self.undecodable == 0 {
                    tracing::warn!(
                        "a message on {} cannot be decoded: {why}; such messages are counted and skipped",
                        self.key
                    );
                }
                self.undecodable += 1;
                Ok(())
            }
        }
    }
}

impl Component for Subscriber {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let topic = ctx.text_property("topic")?;
        names::check_topic(&topic)?;
        let ros_type = ctx.text_property("type")?;
        let definition = definition_of(&ros_type);
        let hash = names::type_hash_on(&ctx.text_property("distro")?, &ros_type);
        let (Some(hash), false) = (hash, definition.is_empty()) else {
            return Err(ComponentError::failed(format_args!(
                "{ros_type} is not a type Kairos reads live (docs/ros2.md lists them)"
            )));
        };
        let definitions = Definitions::parse(&ros_type, &definition).map_err(ComponentError::failed)?;
        let node = names::node(ctx)?;
        let transient_local = ctx.text_property("durability")? == "transient_local";
        let depth = ctx.i64_property("depth")?;
        let (token, _) = node.declare_entity(
            "MS",
            &topic,
            &ros_type,
            &hash,
            &names::qos_words(true, transient_local, depth),
        )?;
        // Any type hash: publishers of another ROS 2 release hash the same message differently.
        self.key = names::topic_key(node.name.domain, &topic, &ros_type, "*");
        let (sender, receiver): (SyncSender<Arrived>, _) = sync_channel(QUEUE);
        let dropped = Arc::clone(&self.dropped);
        let live = sender.clone();
        let subscriber = node
            .session
            .declare_subscriber(self.key.clone())
            .callback(move |sample| {
                if let Err(TrySendError::Full(_)) = live.try_send(Arrived::of(&sample)) {
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
            })
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot subscribe to {}: {e}", self.key)))?;
        if transient_local {
            // Subscribed first, so nothing published meanwhile is missed: then what the publishers kept,
            // written before what came live (a message in both is written once, by its number).
            let topic = KeyExpr::try_from(self.key.clone())
                .map_err(|e| ComponentError::failed(format_args!("{}: {e}", self.key)))?;
            self.kept = self.ask_history(&node.session, &topic, depth)?;
            self.late_publishers = Some(self.watch_late_publishers(&node.session, topic, depth, sender)?);
        }
        tracing::info!(
            "receiving {topic} ({ros_type}) on {}{}",
            self.key,
            if transient_local {
                format!(", with the {} message(s) its publishers kept", self.kept.len())
            } else {
                String::new()
            }
        );
        self.definitions = Some(definitions);
        self.data_type = Some(data_type_of(&ros_type));
        self.subscription = Some(subscriber);
        self.token = Some(token);
        self.messages = Some(receiver);
        self.node = Some(node);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if let Some(kept) = self.kept.pop_front() {
            return self.write(ctx, &kept);
        }
        let Some(messages) = &self.messages else {
            return Err(ComponentError::Stopped);
        };
        match messages.recv_timeout(RECEIVE_WAIT) {
            Ok(arrived) => self.write(ctx, &arrived),
            // Nothing yet: the loop comes back, for stop and control requests.
            Err(_) => Ok(()),
        }
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "ros2",
            "key": self.key,
            "received": self.received,
            "lost": self.lost,
            "repeated": self.repeated,
            "undecodable": self.undecodable,
            "dropped": self.dropped.load(Ordering::Relaxed),
        }))
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        // The subscription leaves ROS 2's graph before its node does (with the last of its components).
        self.late_publishers = None;
        self.subscription = None;
        self.token = None;
        self.node = None;
        Ok(())
    }
}

impl std::fmt::Debug for Subscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscriber")
            .field("key", &self.key)
            .field("received", &self.received)
            .field("lost", &self.lost)
            .finish_non_exhaustive()
    }
}

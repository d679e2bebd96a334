//! `ros2.publisher`: each sample of its input published as a ROS 2 topic, as a ROS 2 node on `rmw_zenoh`
//! publishes.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, PoisonError};

use kairos_pack_recording::ros2::write::{encode, ros_type_of};
use kairos_sdk::DeviceKind;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{Component, ComponentError, ComponentInfo, ComponentResult, Context, TypeFilter};
use zenoh::Wait as _;
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher as ZenohPublisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Queryable;
use zenoh::time::Timestamp;

use crate::names::{self, Attachment, SharedNode};

/// The descriptor of `ros2.publisher`.
pub fn descriptor() -> ComponentInfo {
    let mut descriptor = Descriptor::new(
        "ros2.publisher",
        "ros2",
        "Publishes each sample as a ROS 2 topic, to ROS 2 nodes running rmw_zenoh: an image as a \
         sensor_msgs/Image, an IMU sample as a sensor_msgs/Imu, ... (docs/ros2.md), listed by `ros2 topic list`",
    )
    .label("ROS 2 publisher")
    .input("in", TypeFilter::Any, "The samples to publish, each as the ROS message of its type")
    .property(
        Property::text("topic", "")
            .doc(
                "The ROS 2 topic (/camera/image); empty: the input's source output as a ROS name (camera.image \
                 as /camera/image)",
            )
            .device(DeviceKind::Ros2Topic),
    )
    .property(
        Property::choice("reliability", &["reliable", "best_effort"], "reliable")
            .doc("The ROS 2 reliability it advertises; over TCP samples travel reliably either way, and a full queue drops"),
    )
    ;
    for property in names::node_properties()
        .into_iter()
        .chain(names::topic_properties())
    {
        descriptor = descriptor.property(property);
    }
    descriptor.build()
}

/// The topic once declared: the first sample says its type.
struct Declared {
    publisher: ZenohPublisher<'static>,
    ros_type: &'static str,
    gid: [u8; 16],
    _token: LivelinessToken,
    /// For a transient-local topic: the last messages, and where late subscriptions ask for them.
    kept: Option<Kept>,
}

/// A message as published: its payload, attachment and timestamp (the bytes shared, not copied, with the
/// put and with every reply).
type Published = (ZBytes, ZBytes, Timestamp);

/// The messages a transient-local publisher keeps for subscriptions that come later, the oldest first.
type Cache = Arc<Mutex<VecDeque<Published>>>;

struct Kept {
    cache: Cache,
    depth: usize,
    _queryable: Queryable<()>,
    _token: LivelinessToken,
}

impl Kept {
    /// Keeps a transient-local topic's last `depth` messages on `topic_key` and answers for them on
    /// `cache_key`, as `zenoh-ext`'s advanced publisher does for `rmw_zenoh`: each reply the message as
    /// published (its key, payload and attachment), the last `_max` of them when the query says.
    fn declare(
        session: &zenoh::Session,
        topic_key: &str,
        cache_key: &str,
        depth: usize,
    ) -> Result<Kept, ComponentError> {
        let cache: Cache = Arc::default();
        let answered = Arc::clone(&cache);
        let reply_key = topic_key.to_owned();
        let queryable = session
            .declare_queryable(cache_key.to_owned())
            .callback(move |query| {
                let kept = answered.lock().unwrap_or_else(PoisonError::into_inner).clone();
                let asked = names::most_asked(query.parameters().as_str()).unwrap_or(usize::MAX);
                for (payload, attachment, timestamp) in kept.iter().skip(kept.len().saturating_sub(asked)) {
                    if let Err(why) = query
                        .reply(reply_key.clone(), payload.clone())
                        .attachment(attachment.clone())
                        .timestamp(*timestamp)
                        .wait()
                    {
                        tracing::warn!("a late subscription to {reply_key} asked for its history: {why}");
                        return;
                    }
                }
            })
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot keep history on {cache_key}: {e}")))?;
        // The token under which subscriptions that came first find this publisher and ask it.
        let token = session
            .liveliness()
            .declare_token(cache_key.to_owned())
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot declare {cache_key}: {e}")))?;
        Ok(Kept {
            cache,
            depth,
            _queryable: queryable,
            _token: token,
        })
    }

    fn keep(&self, published: Published) {
        let mut cache = self.cache.lock().unwrap_or_else(PoisonError::into_inner);
        if cache.len() >= self.depth {
            cache.pop_front();
        }
        cache.push_back(published);
    }
}

/// `ros2.publisher`. See [`descriptor`].
#[derive(Default)]
pub struct Publisher {
    node: Option<Arc<SharedNode>>,
    topic: String,
    declared: Option<Declared>,
    key: String,
    sequence: i64,
    scratch: Vec<u8>,
    refused: u64,
}

impl Publisher {
    /// Declares the topic for `ros_type`: its liveliness token, then its publisher.
    fn declare(&mut self, ctx: &Context, ros_type: &'static str) -> ComponentResult {
        let Some(node) = &self.node else {
            return Err(ComponentError::Stopped);
        };
        let session = &node.session;
        let hash = names::type_hash_on(&ctx.text_property("distro")?, ros_type).ok_or_else(|| {
            ComponentError::failed(format_args!("no ROS 2 type hash is known for {ros_type}"))
        })?;
        let reliable = ctx.text_property("reliability")? == "reliable";
        let transient_local = ctx.text_property("durability")? == "transient_local";
        let depth = ctx.i64_property("depth")?;
        let qos = names::qos_words(reliable, transient_local, depth);
        let (token, token_key) = node.declare_entity("MP", &self.topic, ros_type, &hash, &qos)?;
        self.key = names::topic_key(node.name.domain, &self.topic, ros_type, &hash);
        // As `rmw_zenoh` for keep-last history: a full queue drops. Over TCP every sample travels reliably;
        // best effort is what ROS 2's graph is told (Zenoh's reliability switch is not in its stable API).
        let publisher = session
            .declare_publisher(self.key.clone())
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot publish on {}: {e}", self.key)))?;
        let kept = if transient_local {
            let cache_key = names::cache_key(&self.key, &node.name.session);
            Some(Kept::declare(
                session,
                &self.key,
                &cache_key,
                usize::try_from(depth).unwrap_or(1),
            )?)
        } else {
            None
        };
        tracing::info!(
            "publishing {} as {ros_type} on {}{}",
            self.topic,
            self.key,
            if kept.is_some() {
                ", keeping the last messages for late subscriptions"
            } else {
                ""
            }
        );
        self.declared = Some(Declared {
            publisher,
            ros_type,
            gid: names::gid_of(&token_key),
            _token: token,
            kept,
        });
        Ok(())
    }
}

impl Component for Publisher {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let mut topic = ctx.text_property("topic")?;
        if topic.is_empty() {
            let source = ctx
                .inputs()
                .first()
                .and_then(kairos_sdk::InputPort::source)
                .unwrap_or("kairos");
            topic = kairos_pack_recording::ros2::write::ros_topic(source);
        }
        names::check_topic(&topic)?;
        self.node = Some(names::node(ctx)?);
        self.topic = topic;
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let ros_type = ros_type_of(&sample.payload);
        if self.declared.is_none() {
            self.declare(ctx, ros_type)?;
        }
        let (Some(declared), Some(node)) = (&self.declared, &self.node) else {
            return Err(ComponentError::Stopped);
        };
        if declared.ros_type != ros_type {
            self.refused += 1;
            return Err(ComponentError::failed(format_args!(
                "{} carries {}, and a {} sample came: one topic, one type",
                self.topic,
                declared.ros_type,
                sample.payload.data_type()
            )));
        }
        let frame_id = ctx
            .inputs()
            .first()
            .and_then(kairos_sdk::InputPort::source)
            .unwrap_or("");
        if let Err(why) = encode(&sample.payload, sample.timestamp, frame_id, &mut self.scratch) {
            self.refused += 1;
            tracing::warn!("a sample is not published: {why}");
            return Ok(());
        }
        // `rmw_zenoh` numbers a publisher's samples from 1.
        self.sequence += 1;
        let attachment = Attachment {
            sequence: self.sequence,
            source_time_ns: sample.time_of_issue.as_nanos(),
            gid: declared.gid,
        };
        let (payload, attachment) = (
            ZBytes::from(self.scratch.clone()),
            ZBytes::from(attachment.to_bytes()),
        );
        // A kept message is stamped on the session's clock, as zenoh-ext's publishers stamp theirs: a
        // subscription that receives it twice (asked as it starts, and again when it sees this publisher)
        // keeps one. A volatile topic's messages need no stamp.
        let mut timestamp = None;
        if let Some(kept) = &declared.kept {
            let stamp = node.session.new_timestamp();
            kept.keep((payload.clone(), attachment.clone(), stamp));
            timestamp = Some(stamp);
        }
        declared
            .publisher
            .put(payload)
            .attachment(attachment)
            .timestamp(timestamp)
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot publish on {}: {e}", self.key)))?;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "ros2",
            "topic": self.topic,
            "key": self.key,
            "published": self.sequence,
            "refused": self.refused,
        }))
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        // The publisher leaves ROS 2's graph before its node does (with the last of its components).
        self.declared = None;
        self.node = None;
        Ok(())
    }
}

impl std::fmt::Debug for Publisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("topic", &self.topic)
            .field("key", &self.key)
            .field("published", &self.sequence)
            .finish_non_exhaustive()
    }
}

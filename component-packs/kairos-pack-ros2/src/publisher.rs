//! `ros2.publisher`: each sample of its input published as a ROS 2 topic, as a ROS 2 node on `rmw_zenoh`
//! publishes.

use kairos_pack_recording::ros2::write::{encode, ros_type_of, type_hash};
use kairos_sdk::DeviceKind;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{Component, ComponentError, ComponentInfo, ComponentResult, Context, TypeFilter};
use zenoh::Wait as _;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher as ZenohPublisher;
use zenoh::qos::CongestionControl;

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
    .property(
        Property::i64("depth", 10)
            .range(1.0, 10_000.0)
            .doc("The history depth it advertises (keep last)"),
    );
    for property in names::common_properties() {
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
}

/// `ros2.publisher`. See [`descriptor`].
#[derive(Default)]
pub struct Publisher {
    node: Option<std::sync::Arc<SharedNode>>,
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
        let hash = type_hash(ros_type).ok_or_else(|| {
            ComponentError::failed(format_args!("no ROS 2 type hash is known for {ros_type}"))
        })?;
        let reliable = ctx.text_property("reliability")? == "reliable";
        let qos = names::qos_words(reliable, ctx.i64_property("depth")?);
        let token_key = node
            .name
            .entity_token(node.entity_id(), "MP", &self.topic, ros_type, &hash, &qos);
        let token = session
            .liveliness()
            .declare_token(token_key.clone())
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot declare {token_key}: {e}")))?;
        self.key = names::topic_key(node.name.domain, &self.topic, ros_type, &hash);
        // As `rmw_zenoh` for keep-last history: a full queue drops. Over TCP every sample travels reliably;
        // best effort is what ROS 2's graph is told (Zenoh's reliability switch is not in its stable API).
        let publisher = session
            .declare_publisher(self.key.clone())
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot publish on {}: {e}", self.key)))?;
        tracing::info!("publishing {} as {ros_type} on {}", self.topic, self.key);
        self.declared = Some(Declared {
            publisher,
            ros_type,
            gid: names::gid_of(&token_key),
            _token: token,
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
        let Some(declared) = &self.declared else {
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
        declared
            .publisher
            .put(self.scratch.clone())
            .attachment(attachment.to_bytes())
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

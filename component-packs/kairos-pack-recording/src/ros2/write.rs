//! Kairos samples as ROS 2 messages: the `rosbag2` profile of the recorder writes each type as the
//! ROS message that carries it, in CDR, with the `ros2msg` definition ROS tools (`ros2 bag`, Foxglove,
//! the `rosbags` and `mcap_ros2` readers) decode it by.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use kairos_sdk::{DataType, FixStatus, Payload, Timestamp};

/// Each message type this side writes or reads without a definition of the bag's (an older `SQLite` bag, a
/// live topic), with its own fields as `ros2msg` text (no comments, constants left out), and the types
/// their definitions need.
const FIELDS: &[(&str, &str)] = &[
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    // The services the ROS 2 pack calls and offers: a service's own description names its request,
    // response and event messages (REP 2011), the event those and `service_msgs/ServiceEventInfo`. A
    // message with no field has the one `rosidl` gives it, so its CDR is one byte.
    (
        "service_msgs/ServiceEventInfo",
        "uint8 event_type\nbuiltin_interfaces/Time stamp\nuint8[16] client_gid\nint64 sequence_number\n",
    ),
    (
        "std_srvs/srv/Trigger",
        "std_srvs/srv/Trigger_Request request_message\nstd_srvs/srv/Trigger_Response response_message\n\
         std_srvs/srv/Trigger_Event event_message\n",
    ),
    (
        "std_srvs/srv/Trigger_Request",
        "uint8 structure_needs_at_least_one_member\n",
    ),
    ("std_srvs/srv/Trigger_Response", "bool success\nstring message\n"),
    (
        "std_srvs/srv/Trigger_Event",
        "service_msgs/ServiceEventInfo info\nstd_srvs/srv/Trigger_Request[<=1] request\n\
         std_srvs/srv/Trigger_Response[<=1] response\n",
    ),
    (
        "std_srvs/srv/SetBool",
        "std_srvs/srv/SetBool_Request request_message\nstd_srvs/srv/SetBool_Response response_message\n\
         std_srvs/srv/SetBool_Event event_message\n",
    ),
    ("std_srvs/srv/SetBool_Request", "bool data\n"),
    ("std_srvs/srv/SetBool_Response", "bool success\nstring message\n"),
    (
        "std_srvs/srv/SetBool_Event",
        "service_msgs/ServiceEventInfo info\nstd_srvs/srv/SetBool_Request[<=1] request\n\
         std_srvs/srv/SetBool_Response[<=1] response\n",
    ),
    (
        "std_srvs/srv/Empty",
        "std_srvs/srv/Empty_Request request_message\nstd_srvs/srv/Empty_Response response_message\n\
         std_srvs/srv/Empty_Event event_message\n",
    ),
    (
        "std_srvs/srv/Empty_Request",
        "uint8 structure_needs_at_least_one_member\n",
    ),
    (
        "std_srvs/srv/Empty_Response",
        "uint8 structure_needs_at_least_one_member\n",
    ),
    (
        "std_srvs/srv/Empty_Event",
        "service_msgs/ServiceEventInfo info\nstd_srvs/srv/Empty_Request[<=1] request\n\
         std_srvs/srv/Empty_Response[<=1] response\n",
    ),
    (
        "std_msgs/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    ("std_msgs/Float64", "float64 data\n"),
    ("std_msgs/Int64", "int64 data\n"),
    ("std_msgs/Bool", "bool data\n"),
    ("std_msgs/String", "string data\n"),
    (
        "std_msgs/MultiArrayDimension",
        "string label\nuint32 size\nuint32 stride\n",
    ),
    (
        "std_msgs/MultiArrayLayout",
        "std_msgs/MultiArrayDimension[] dim\nuint32 data_offset\n",
    ),
    (
        "std_msgs/Float64MultiArray",
        "std_msgs/MultiArrayLayout layout\nfloat64[] data\n",
    ),
    (
        "std_msgs/UInt8MultiArray",
        "std_msgs/MultiArrayLayout layout\nuint8[] data\n",
    ),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    (
        "geometry_msgs/Quaternion",
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    ),
    (
        "geometry_msgs/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    ),
    (
        "geometry_msgs/PoseStamped",
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    ),
    (
        "sensor_msgs/Imu",
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\
         geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\
         geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
    ),
    ("sensor_msgs/NavSatStatus", "int8 status\nuint16 service\n"),
    (
        "sensor_msgs/NavSatFix",
        "std_msgs/Header header\nsensor_msgs/NavSatStatus status\nfloat64 latitude\nfloat64 longitude\n\
         float64 altitude\nfloat64[9] position_covariance\nuint8 position_covariance_type\n",
    ),
    (
        "sensor_msgs/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n\
         uint32 step\nuint8[] data\n",
    ),
    // Read, never written: Kairos writes raw images; bags and cameras often carry these.
    (
        "sensor_msgs/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    (
        "sensor_msgs/PointField",
        "string name\nuint32 offset\nuint8 datatype\nuint32 count\n",
    ),
    (
        "sensor_msgs/PointCloud2",
        "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\n\
         bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
    ),
    (
        "can_msgs/Frame",
        "std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\nuint8 dlc\n\
         uint8[8] data\n",
    ),
];

fn fields_of(type_name: &str) -> &'static str {
    FIELDS
        .iter()
        .find(|(name, _)| *name == type_name)
        .map_or("", |(_, fields)| fields)
}

/// The ROS message type a payload is written as (`sensor_msgs/msg/Imu`).
pub fn ros_type_of(payload: &Payload) -> &'static str {
    ros_type_for(&payload.data_type())
}

/// The ROS message type samples of `data_type` are written as.
pub fn ros_type_for(data_type: &DataType) -> &'static str {
    match data_type {
        DataType::F64 => "std_msgs/msg/Float64",
        DataType::I64 => "std_msgs/msg/Int64",
        DataType::Bool => "std_msgs/msg/Bool",
        DataType::Text => "std_msgs/msg/String",
        DataType::Vector | DataType::Matrix => "std_msgs/msg/Float64MultiArray",
        DataType::Bytes | DataType::Custom(_) => "std_msgs/msg/UInt8MultiArray",
        DataType::Imu => "sensor_msgs/msg/Imu",
        DataType::GnssFix => "sensor_msgs/msg/NavSatFix",
        DataType::Image => "sensor_msgs/msg/Image",
        DataType::PointCloud => "sensor_msgs/msg/PointCloud2",
        DataType::Pose => "geometry_msgs/msg/PoseStamped",
        DataType::CanFrame => "can_msgs/msg/Frame",
    }
}

/// The `ros2msg` definition of `ros_type` as rosbag2 stores it: its fields, then each type they use
/// (depth first, each once) after a line of `=` and `MSG: package/Type`.
pub fn definition_of(ros_type: &str) -> String {
    let root = super::normalized(ros_type);
    let mut text = fields_of(&root).to_owned();
    let mut seen = BTreeSet::from([root.clone()]);
    let mut pending: Vec<String> = used_types(&root);
    pending.reverse();
    while let Some(next) = pending.pop() {
        if !seen.insert(next.clone()) {
            continue;
        }
        let _ = write!(text, "{}\nMSG: {next}\n{}", "=".repeat(80), fields_of(&next));
        let mut used = used_types(&next);
        used.reverse();
        pending.extend(used);
    }
    text
}

/// The type hash ROS 2 names `ros_type` by (`RIHS01_` and the SHA-256 of its type description, REP 2011),
/// as `rmw_zenoh` puts it in key expressions and liveliness tokens; `None` for a type Kairos does not write.
pub fn type_hash(ros_type: &str) -> Option<String> {
    use sha2::Digest as _;
    let root = super::normalized(ros_type);
    if fields_of(&root).is_empty() {
        return None;
    }
    let mut referenced = BTreeSet::new();
    let mut pending = used_types(&root);
    while let Some(next) = pending.pop() {
        if referenced.insert(next.clone()) {
            pending.extend(used_types(&next));
        }
    }
    // Python's `json.dumps` with its default separators, keys in the order REP 2011 gives them: what
    // `rosidl` hashes.
    let referenced: Vec<String> = referenced.iter().map(|t| description_json(t)).collect();
    let text = format!(
        "{{\"type_description\": {}, \"referenced_type_descriptions\": [{}]}}",
        description_json(&root),
        referenced.join(", ")
    );
    let digest = sha2::Sha256::digest(text.as_bytes());
    let mut hash = String::from("RIHS01_");
    for byte in digest {
        let _ = write!(hash, "{byte:02x}");
    }
    Some(hash)
}

/// One type's description: its name (`pkg/msg/Type`) and its fields with their REP 2011 type ids.
fn description_json(type_name: &str) -> String {
    let fields: Vec<String> = fields_of(type_name)
        .lines()
        .filter_map(|line| {
            let mut words = line.split_whitespace();
            Some((words.next()?, words.next()?))
        })
        .map(|(type_word, name)| {
            let (base, array) = match type_word.split_once('[') {
                Some((base, rest)) => (base, Some(rest.trim_end_matches(']'))),
                None => (type_word, None),
            };
            // type_description_interfaces/FieldType: the scalar's id, +48 for an array of fixed size,
            // +96 for a bounded sequence, +144 for an unbounded one.
            let (scalar, nested) = match base {
                "int8" => (2, String::new()),
                "uint8" => (3, String::new()),
                "int16" => (4, String::new()),
                "uint16" => (5, String::new()),
                "int32" => (6, String::new()),
                "uint32" => (7, String::new()),
                "int64" => (8, String::new()),
                "uint64" => (9, String::new()),
                "float32" => (10, String::new()),
                "float64" => (11, String::new()),
                "char" => (13, String::new()),
                "bool" => (15, String::new()),
                "byte" => (16, String::new()),
                "string" => (17, String::new()),
                message => (1, with_msg(message)),
            };
            let (type_id, capacity) = match array {
                None => (scalar, 0),
                Some("") => (scalar + 144, 0),
                Some(bound) if bound.starts_with("<=") => (scalar + 96, bound[2..].parse().unwrap_or(0)),
                Some(size) => (scalar + 48, size.parse().unwrap_or(0)),
            };
            format!(
                "{{\"name\": \"{name}\", \"type\": {{\"type_id\": {type_id}, \"capacity\": {capacity}, \
                 \"string_capacity\": 0, \"nested_type_name\": \"{nested}\"}}}}"
            )
        })
        .collect();
    format!(
        "{{\"type_name\": \"{}\", \"fields\": [{}]}}",
        with_msg(type_name),
        fields.join(", ")
    )
}

/// `pkg/Type` as REP 2011 names it: `pkg/msg/Type`.
fn with_msg(type_name: &str) -> String {
    match type_name.split_once('/') {
        Some((package, name)) if !name.contains('/') => format!("{package}/msg/{name}"),
        _ => type_name.to_owned(),
    }
}

/// The message types `type_name`'s own fields name, in order.
fn used_types(type_name: &str) -> Vec<String> {
    fields_of(type_name)
        .lines()
        .filter_map(|line| line.split_whitespace().next())
        .map(|word| word.split('[').next().unwrap_or(word))
        .filter(|word| word.contains('/'))
        .map(str::to_owned)
        .collect()
}

/// The ROS topic a Kairos output is written under: `/` for every `.` and `/` of `camera.image`
/// (`/camera/image`), characters ROS names do not allow replaced by `_`.
pub fn ros_topic(topic: &str) -> String {
    let mut name = String::with_capacity(topic.len() + 1);
    for part in topic.split(['.', '/']).filter(|p| !p.is_empty()) {
        name.push('/');
        if part.starts_with(|c: char| c.is_ascii_digit()) {
            name.push('_');
        }
        name.extend(part.chars().map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        }));
    }
    if name.is_empty() {
        "/kairos".to_owned()
    } else {
        name
    }
}

/// A CDR message being written: little-endian, aligned as [`super::Definitions::decode`] reads it.
struct Cdr {
    out: Vec<u8>,
}

impl Cdr {
    fn new(out: Vec<u8>) -> Cdr {
        let mut out = out;
        out.clear();
        out.extend_from_slice(&[0, 1, 0, 0]);
        Cdr { out }
    }

    fn align(&mut self, size: usize) {
        let offset = self.out.len() - 4;
        let padding = (size - offset % size) % size;
        self.out.resize(self.out.len() + padding, 0);
    }

    fn u8(&mut self, value: u8) {
        self.out.push(value);
    }

    fn bool(&mut self, value: bool) {
        self.out.push(u8::from(value));
    }

    fn u16(&mut self, value: u16) {
        self.align(2);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn i32(&mut self, value: i32) {
        self.align(4);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn u32(&mut self, value: u32) {
        self.align(4);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn i64(&mut self, value: i64) {
        self.align(8);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn f64(&mut self, value: f64) {
        self.align(8);
        self.out.extend_from_slice(&value.to_le_bytes());
    }

    fn f64s(&mut self, values: &[f64]) {
        for value in values {
            self.f64(*value);
        }
    }

    fn length(&mut self, length: usize) -> Result<(), WriteError> {
        self.u32(u32::try_from(length).map_err(|_| WriteError::TooLong(length))?);
        Ok(())
    }

    fn string(&mut self, text: &str) -> Result<(), WriteError> {
        self.length(text.len() + 1)?;
        self.out.extend_from_slice(text.as_bytes());
        self.out.push(0);
        Ok(())
    }

    fn byte_sequence(&mut self, bytes: &[u8]) -> Result<(), WriteError> {
        self.length(bytes.len())?;
        self.out.extend_from_slice(bytes);
        Ok(())
    }

    fn header(&mut self, stamp: Timestamp, frame_id: &str) -> Result<(), WriteError> {
        let nanos = stamp.as_nanos();
        let seconds =
            i32::try_from(nanos.div_euclid(1_000_000_000)).map_err(|_| WriteError::TimeRange(nanos))?;
        self.i32(seconds);
        self.u32(u32::try_from(nanos.rem_euclid(1_000_000_000)).unwrap_or(0));
        self.string(frame_id)
    }

    fn vector3(&mut self, v: glam::DVec3) {
        self.f64s(&v.to_array());
    }

    fn quaternion(&mut self, q: glam::DQuat) {
        self.f64s(&[q.x, q.y, q.z, q.w]);
    }

    /// A `std_msgs/MultiArrayLayout` of these dimensions (label, size), strides row-major.
    fn layout(&mut self, dimensions: &[(&str, usize)]) -> Result<(), WriteError> {
        self.length(dimensions.len())?;
        let mut stride: usize = dimensions.iter().map(|(_, size)| size).product();
        for (label, size) in dimensions {
            self.string(label)?;
            self.u32(u32::try_from(*size).unwrap_or(u32::MAX));
            self.u32(u32::try_from(stride).unwrap_or(u32::MAX));
            stride /= (*size).max(1);
        }
        self.u32(0);
        Ok(())
    }
}

/// Why a sample cannot be written as its ROS 2 message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WriteError {
    /// A CDR sequence counts to `u32::MAX`.
    #[error("{0} values do not fit a CDR sequence")]
    TooLong(usize),
    /// A ROS time's seconds are an `i32`.
    #[error("a timestamp of {0} ns is out of a ROS time's range")]
    TimeRange(i64),
    /// `can_msgs/Frame` holds classic frames.
    #[error("a CAN FD frame (can_msgs/Frame holds 8 data bytes at most)")]
    CanFd,
    /// A type no ROS message is mapped to.
    #[error("a {0} sample (no ROS message carries it yet)")]
    NoMessage(DataType),
    /// A cloud's width is a `uint32`.
    #[error("too many points")]
    TooManyPoints,
}

/// A 3×3 covariance with `diagonal` on its diagonal.
fn diagonal(diagonal: [f64; 3]) -> [f64; 9] {
    let [a, b, c] = diagonal;
    [a, 0.0, 0.0, 0.0, b, 0.0, 0.0, 0.0, c]
}

/// `sensor_msgs/PointField` data type `FLOAT32`.
const POINT_FLOAT32: u8 = 7;

/// Encodes `payload` (of a sample stamped `timestamp`, from output `frame_id`) as the CDR message of
/// [`ros_type_of`] into `out`.
pub fn encode(
    payload: &Payload,
    timestamp: Timestamp,
    frame_id: &str,
    out: &mut Vec<u8>,
) -> Result<(), WriteError> {
    let mut cdr = Cdr::new(std::mem::take(out));
    let written = write_message(&mut cdr, payload, timestamp, frame_id);
    *out = cdr.out;
    written
}

fn write_message(
    cdr: &mut Cdr,
    payload: &Payload,
    timestamp: Timestamp,
    frame_id: &str,
) -> Result<(), WriteError> {
    match payload {
        Payload::F64(value) => cdr.f64(*value),
        Payload::I64(value) => cdr.i64(*value),
        Payload::Bool(flag) => cdr.bool(*flag),
        Payload::Text(text) => cdr.string(text)?,
        Payload::Vector(values) => {
            cdr.layout(&[("", values.len())])?;
            cdr.length(values.len())?;
            cdr.f64s(values);
        }
        Payload::Matrix(matrix) => {
            cdr.layout(&[("rows", matrix.rows), ("cols", matrix.cols)])?;
            cdr.length(matrix.values.len())?;
            cdr.f64s(&matrix.values);
        }
        Payload::Bytes(bytes) => {
            cdr.layout(&[("", bytes.len())])?;
            cdr.byte_sequence(bytes)?;
        }
        Payload::Custom(custom) => {
            // The pack's type name is the layout's label: the bytes alone would not say what they are.
            cdr.layout(&[(&custom.type_name, custom.data.len())])?;
            cdr.byte_sequence(&custom.data)?;
        }
        Payload::Imu(imu) => {
            cdr.header(timestamp, frame_id)?;
            cdr.quaternion(imu.orientation.unwrap_or(glam::DQuat::IDENTITY));
            // A first orientation covariance of -1 says there is no orientation (sensor_msgs/Imu).
            let no_orientation = if imu.orientation.is_some() { 0.0 } else { -1.0 };
            cdr.f64s(&diagonal([no_orientation, 0.0, 0.0]));
            cdr.vector3(imu.angular_velocity);
            cdr.f64s(&[0.0; 9]);
            cdr.vector3(imu.linear_acceleration);
            cdr.f64s(&[0.0; 9]);
        }
        Payload::GnssFix(fix) => {
            cdr.header(timestamp, frame_id)?;
            // sensor_msgs/NavSatStatus: -1 no fix, 0 fix, 2 ground-based augmentation (RTK); GPS service.
            let status: i8 = match fix.status {
                FixStatus::NoFix => -1,
                FixStatus::Fix => 0,
                FixStatus::Differential => 1,
                FixStatus::RtkFixed => 2,
            };
            cdr.u8(status.cast_unsigned());
            cdr.u16(1);
            cdr.f64s(&[fix.latitude_deg, fix.longitude_deg, fix.altitude_m]);
            let known = fix.horizontal_accuracy_m.is_finite() && fix.vertical_accuracy_m.is_finite();
            let (h, v) = (fix.horizontal_accuracy_m, fix.vertical_accuracy_m);
            cdr.f64s(&if known {
                diagonal([h * h, h * h, v * v])
            } else {
                [0.0; 9]
            });
            // COVARIANCE_TYPE_DIAGONAL_KNOWN, or UNKNOWN.
            cdr.u8(if known { 2 } else { 0 });
        }
        Payload::Image(image) => {
            cdr.header(timestamp, frame_id)?;
            cdr.u32(image.height);
            cdr.u32(image.width);
            cdr.string(crate::encode::image_encoding(image.format))?;
            cdr.u8(0);
            cdr.u32(image.stride);
            cdr.byte_sequence(&image.pixels)?;
        }
        Payload::PointCloud(cloud) => {
            cdr.header(timestamp, frame_id)?;
            let with_intensity = cloud.intensity.is_some();
            let step = crate::encode::packed_point_stride(cloud);
            let count = u32::try_from(cloud.points.len()).map_err(|_| WriteError::TooManyPoints)?;
            cdr.u32(1);
            cdr.u32(count);
            let names: &[&str] = if with_intensity {
                &["x", "y", "z", "intensity"]
            } else {
                &["x", "y", "z"]
            };
            cdr.length(names.len())?;
            for (index, name) in names.iter().enumerate() {
                cdr.string(name)?;
                cdr.u32(4 * u32::try_from(index).unwrap_or(0));
                cdr.u8(POINT_FLOAT32);
                cdr.u32(1);
            }
            cdr.bool(false);
            cdr.u32(step);
            cdr.u32(step.saturating_mul(count));
            cdr.length(cloud.points.len() * step as usize)?;
            crate::encode::append_packed_points(cloud, &mut cdr.out);
            cdr.bool(cloud.points.iter().all(|p| p.is_finite()));
        }
        Payload::Pose(pose) => {
            cdr.header(timestamp, frame_id)?;
            cdr.vector3(pose.position);
            cdr.quaternion(pose.orientation);
        }
        Payload::CanFrame(frame) => {
            if frame.fd {
                return Err(WriteError::CanFd);
            }
            cdr.header(timestamp, frame_id)?;
            cdr.u32(frame.id);
            cdr.bool(frame.remote);
            cdr.bool(frame.extended);
            cdr.bool(false);
            cdr.u8(frame.length());
            let mut data = [0u8; 8];
            for (to, from) in data.iter_mut().zip(frame.data()) {
                *to = *from;
            }
            cdr.out.extend_from_slice(&data);
        }
        other => {
            return Err(WriteError::NoMessage(other.data_type()));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use kairos_sdk::{CanFrame, CustomPayload, GnssFix, Image, Imu, Matrix, PixelFormat, PointCloud, Pose};

    use super::*;
    use crate::ros2::{Definitions, data_type_noted, header_stamp, to_payload};

    /// Written as its ROS message, read back through the definition written with it.
    fn round_trip(payload: &Payload, stamp: Timestamp) -> (Payload, Option<Timestamp>) {
        let ros_type = ros_type_of(payload);
        let definitions = Definitions::parse(ros_type, &definition_of(ros_type)).unwrap();
        let mut data = Vec::new();
        encode(payload, stamp, "sensor.out", &mut data).unwrap();
        let value = definitions.decode(&data).unwrap();
        let data_type = data_type_noted(ros_type, Some(&payload.data_type().to_string()));
        let read = to_payload(&definitions, &value, &data_type).unwrap();
        (read, header_stamp(&definitions, &value))
    }

    #[test]
    fn every_payload_type_comes_back_from_its_ros_message() {
        let stamp = Timestamp(1_795_000_000_123_456_789);
        let payloads = vec![
            Payload::F64(-1.25e-3),
            Payload::I64(-42),
            Payload::Bool(true),
            Payload::Text(Arc::from("héllo")),
            Payload::Vector(Arc::from(vec![1.0, 2.5, -3.0])),
            Payload::Matrix(Arc::new(Matrix {
                rows: 2,
                cols: 3,
                values: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
            })),
            Payload::Bytes(Arc::from(vec![0_u8, 1, 254, 255])),
            Payload::Custom(CustomPayload {
                type_name: Arc::from("lidar.Scan"),
                data: Arc::from(vec![9_u8, 8]),
            }),
            Payload::Image(Image::packed(3, 2, PixelFormat::Bgr8, (0..18).collect::<Vec<u8>>()).unwrap()),
            Payload::PointCloud(Arc::new(PointCloud {
                points: vec![glam::Vec3::new(1.0, -2.0, 3.5), glam::Vec3::ZERO],
                intensity: Some(vec![0.5, 1.0]),
            })),
            Payload::Imu(Imu {
                angular_velocity: glam::DVec3::new(0.1, 0.2, 0.3),
                linear_acceleration: glam::DVec3::new(0.0, 0.0, 9.81),
                orientation: Some(glam::DQuat::from_rotation_z(0.3)),
            }),
            Payload::Imu(Imu {
                angular_velocity: glam::DVec3::X,
                linear_acceleration: glam::DVec3::Y,
                orientation: None,
            }),
            Payload::GnssFix(GnssFix {
                latitude_deg: 48.8,
                longitude_deg: 2.3,
                altitude_m: 35.0,
                horizontal_accuracy_m: 1.5,
                vertical_accuracy_m: 3.0,
                status: FixStatus::RtkFixed,
            }),
            Payload::CanFrame(CanFrame::new(0x1AB, true, &[1, 2, 3]).unwrap()),
            Payload::CanFrame(CanFrame::remote_request(0x1AB, false, 8).unwrap()),
            Payload::Pose(Pose {
                position: glam::DVec3::new(1.0, 2.0, 3.0),
                orientation: glam::DQuat::from_rotation_z(0.5),
            }),
        ];
        for payload in &payloads {
            let (read, read_stamp) = round_trip(payload, stamp);
            assert_eq!(&read, payload, "{}", ros_type_of(payload));
            if definition_of(ros_type_of(payload)).starts_with("std_msgs/Header header") {
                assert_eq!(read_stamp, Some(stamp), "{}", ros_type_of(payload));
            }
        }
        let fd = Payload::CanFrame(CanFrame::new(1, false, &[0; 12]).unwrap());
        assert_eq!(encode(&fd, stamp, "", &mut Vec::new()), Err(WriteError::CanFd));
    }

    #[test]
    fn cut_or_corrupted_messages_are_errors_never_panics() {
        let stamp = Timestamp(1_795_000_000_000_000_000);
        let samples = [
            Payload::Image(Image::packed(4, 3, PixelFormat::Rgb8, vec![7; 36]).unwrap()),
            Payload::PointCloud(Arc::new(PointCloud {
                points: vec![glam::Vec3::ONE; 5],
                intensity: Some(vec![1.0; 5]),
            })),
            Payload::GnssFix(GnssFix {
                latitude_deg: 1.0,
                longitude_deg: 2.0,
                altitude_m: 3.0,
                horizontal_accuracy_m: 1.0,
                vertical_accuracy_m: 1.0,
                status: FixStatus::Fix,
            }),
            Payload::Matrix(Arc::new(Matrix {
                rows: 2,
                cols: 2,
                values: vec![1.0; 4],
            })),
            Payload::CanFrame(CanFrame::new(5, false, &[1, 2]).unwrap()),
        ];
        // A fixed sequence of pseudo-random bytes: the same corruptions every run.
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut refused = 0;
        for payload in &samples {
            let ros_type = ros_type_of(payload);
            let definitions = Definitions::parse(ros_type, &definition_of(ros_type)).unwrap();
            let data_type = data_type_noted(ros_type, Some(&payload.data_type().to_string()));
            let mut data = Vec::new();
            encode(payload, stamp, "x", &mut data).unwrap();
            let mut tries: Vec<Vec<u8>> = (0..data.len()).map(|cut| data[..cut].to_vec()).collect();
            for _ in 0..2000 {
                let mut corrupted = data.clone();
                for _ in 0..=(next() % 4) {
                    let at = (next() % corrupted.len() as u64) as usize;
                    corrupted[at] = next() as u8;
                }
                tries.push(corrupted);
            }
            for message in tries {
                match definitions.decode(&message) {
                    Ok(value) => {
                        let _ = to_payload(&definitions, &value, &data_type);
                        let _ = value.to_json();
                    }
                    Err(why) => {
                        assert!(!why.to_string().is_empty());
                        refused += 1;
                    }
                }
            }
        }
        assert!(refused > 0, "every cut message was accepted");
    }

    #[test]
    fn type_hashes_are_the_ones_ros_2_computes() {
        // rmw_zenoh's design document gives std_msgs/msg/String's.
        assert_eq!(
            type_hash("std_msgs/msg/String").as_deref(),
            Some("RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18")
        );
        // These as the `rosbags` package computes them for ROS 2 Jazzy (0.11.9).
        for (ros_type, hash) in [
            (
                "sensor_msgs/msg/Imu",
                "7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
            ),
            (
                "sensor_msgs/msg/NavSatFix",
                "62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
            ),
            (
                "sensor_msgs/msg/Image",
                "d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
            ),
            (
                "sensor_msgs/msg/PointCloud2",
                "9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
            ),
            (
                "geometry_msgs/msg/PoseStamped",
                "10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
            ),
            (
                "sensor_msgs/msg/CompressedImage",
                "15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
            ),
        ] {
            assert_eq!(type_hash(ros_type), Some(format!("RIHS01_{hash}")), "{ros_type}");
        }
        assert_eq!(type_hash("unknown_msgs/msg/Thing"), None);
    }

    #[test]
    fn a_definition_lists_each_type_it_uses_once_after_a_separator() {
        let text = definition_of("sensor_msgs/msg/Imu");
        assert!(text.starts_with("std_msgs/Header header\n"));
        let sections: Vec<&str> = text
            .lines()
            .filter_map(|line| line.strip_prefix("MSG: "))
            .collect();
        assert_eq!(
            sections,
            [
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/Quaternion",
                "geometry_msgs/Vector3"
            ]
        );
        assert_eq!(text.lines().filter(|l| *l == "=".repeat(80)).count(), 4);
        assert_eq!(ros_topic("camera.image"), "/camera/image");
        assert_eq!(ros_topic("front/edges.out"), "/front/edges/out");
        assert_eq!(ros_topic("gnss-2.fix"), "/gnss_2/fix");
        assert_eq!(ros_topic("3d.cloud"), "/_3d/cloud");
    }

    #[test]
    fn a_service_s_type_hash_is_the_one_ros_2_keys_it_by() {
        // The key a ROS 2 Jazzy device's std_srvs/srv/Trigger service answers on, as quoted in another
        // project's public test script that queries it through rmw_zenoh: the hash of the service's
        // description with its request, response and event (REP 2011).
        assert_eq!(
            type_hash("std_srvs/srv/Trigger").as_deref(),
            Some("RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f")
        );
        assert!(type_hash("std_srvs/srv/SetBool").is_some_and(|h| h.starts_with("RIHS01_")));
        assert!(type_hash("std_srvs/srv/Empty").is_some_and(|h| h.starts_with("RIHS01_")));
    }
}

//! How each payload type is written to MCAP: Foxglove well-known schemas (protobuf) where one exists,
//! otherwise a JSON schema of ours, so every channel decodes from the file alone.

use foxglove::Encode as _;
use foxglove::schemas::{
    LocationFix, PackedElementField, PointCloud as FoxglovePointCloud, Pose as FoxglovePose, PoseInFrame,
    Quaternion, RawImage, Timestamp as FoxgloveTimestamp, Vector3, location_fix, packed_element_field,
};
use kairos_sdk::{FixStatus, Payload, PixelFormat, Timestamp};
use serde_json::json;

/// A schema as MCAP stores it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaSpec {
    /// The schema's name (`foxglove.RawImage`, `kairos.F64`).
    pub name: String,
    /// `protobuf` or `jsonschema`.
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
    /// The message encoding of channels using it (`protobuf` or `json`).
    pub message_encoding: String,
}

fn foxglove_schema<T: foxglove::Encode>() -> SchemaSpec {
    let schema = T::get_schema();
    SchemaSpec {
        name: schema.as_ref().map_or_else(String::new, |s| s.name.clone()),
        encoding: schema.as_ref().map_or_else(String::new, |s| s.encoding.clone()),
        data: schema.map_or_else(Vec::new, |s| s.data.into_owned()),
        message_encoding: T::get_message_encoding(),
    }
}

fn json_schema(name: &str, properties: &serde_json::Value) -> SchemaSpec {
    let schema = json!({
        "title": name,
        "description": "Kairos sample payload; the message's publish time is the sample's timestamp and its log time the time of issue",
        "type": "object",
        "properties": properties,
    });
    SchemaSpec {
        name: name.to_owned(),
        encoding: "jsonschema".to_owned(),
        data: schema.to_string().into_bytes(),
        message_encoding: "json".to_owned(),
    }
}

/// The schema for a payload's type.
pub fn schema_for(payload: &Payload) -> SchemaSpec {
    let number = json!({"type": "number"});
    let numbers = json!({"type": "array", "items": {"type": "number"}});
    match payload {
        Payload::Image(_) => foxglove_schema::<RawImage>(),
        Payload::PointCloud(_) => foxglove_schema::<FoxglovePointCloud>(),
        Payload::GnssFix(_) => foxglove_schema::<LocationFix>(),
        Payload::Pose(_) => foxglove_schema::<PoseInFrame>(),
        Payload::F64(_) => json_schema("kairos.F64", &json!({"value": number})),
        Payload::I64(_) => json_schema("kairos.I64", &json!({"value": {"type": "integer"}})),
        Payload::Bool(_) => json_schema("kairos.Bool", &json!({"value": {"type": "boolean"}})),
        Payload::Vector(_) => json_schema("kairos.Vector", &json!({"values": numbers})),
        Payload::Matrix(_) => json_schema(
            "kairos.Matrix",
            &json!({"rows": {"type": "integer"}, "cols": {"type": "integer"}, "values": numbers}),
        ),
        Payload::Text(_) => json_schema("kairos.Text", &json!({"text": {"type": "string"}})),
        Payload::Bytes(_) => json_schema(
            "kairos.Bytes",
            &json!({"base64": {"type": "string", "contentEncoding": "base64"}}),
        ),
        Payload::Imu(_) => {
            let vector = json!({"type": "object", "properties": {"x": number, "y": number, "z": number}});
            json_schema(
                "kairos.Imu",
                &json!({
                    "angular_velocity": vector, "linear_acceleration": vector,
                    "orientation": {"type": ["object", "null"], "properties": {"x": number, "y": number, "z": number, "w": number}},
                }),
            )
        }
        Payload::CanFrame(_) => json_schema(
            "kairos.CanFrame",
            &json!({"id": {"type": "integer"}, "extended": {"type": "boolean"}, "fd": {"type": "boolean"}, "data": {"type": "array", "items": {"type": "integer"}}, "remote": {"type": "boolean"}, "length": {"type": "integer"}}),
        ),
        Payload::Custom(custom) => json_schema(
            &format!("kairos.Custom.{}", custom.type_name),
            &json!({"type_name": {"type": "string"}, "base64": {"type": "string", "contentEncoding": "base64"}}),
        ),
        // A payload type newer than this recorder: `encode` refuses its samples, naming the type.
        other => json_schema(&format!("kairos.{}", other.data_type()), &json!({})),
    }
}

fn foxglove_time(time: Timestamp) -> FoxgloveTimestamp {
    let nanos = time.as_nanos().max(0);
    FoxgloveTimestamp::new(
        u32::try_from(nanos / 1_000_000_000).unwrap_or(u32::MAX),
        u32::try_from(nanos % 1_000_000_000).unwrap_or(0),
    )
}

fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk.first().copied().unwrap_or(0),
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= chunk.len() {
                out.push(char::from(
                    TABLE.get(((n >> shift) & 63) as usize).copied().unwrap_or(b'='),
                ));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// An image's encoding as ROS and Foxglove name pixel formats (`rgb8`, `mono16`): the inverse of
/// [`crate::decode::pixel_format_of`].
pub fn image_encoding(format: PixelFormat) -> &'static str {
    match format {
        PixelFormat::Gray8 => "mono8",
        PixelFormat::Gray16 => "mono16",
        PixelFormat::Rgb8 => "rgb8",
        PixelFormat::Rgba8 => "rgba8",
        PixelFormat::Bgr8 => "bgr8",
        PixelFormat::Bgra8 => "bgra8",
    }
}

fn varint(mut value: u64, out: &mut Vec<u8>) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

fn length_delimited(tag: u8, bytes: &[u8], out: &mut Vec<u8>) {
    if !bytes.is_empty() {
        out.push((tag << 3) | 2);
        varint(bytes.len() as u64, out);
        out.extend_from_slice(bytes);
    }
}

fn fixed32(tag: u8, value: u32, out: &mut Vec<u8>) {
    if value != 0 {
        out.push((tag << 3) | 5);
        out.extend_from_slice(&value.to_le_bytes());
    }
}

/// `foxglove.RawImage` in protobuf, written straight from the shared pixels: the generic encoder would
/// first copy them into a message of its own, a second full copy of every frame. The bytes are the ones
/// that encoder writes (fields by tag; a unit test compares).
fn encode_raw_image(image: &kairos_sdk::Image, timestamp: Timestamp, frame_id: &str, out: &mut Vec<u8>) {
    out.reserve(image.pixels.len() + frame_id.len() + 64);
    let time = foxglove_time(timestamp);
    let mut stamp = Vec::with_capacity(12);
    if time.sec() != 0 {
        stamp.push(1 << 3);
        varint(u64::from(time.sec()), &mut stamp);
    }
    if time.nsec() != 0 {
        stamp.push(2 << 3);
        varint(u64::from(time.nsec()), &mut stamp);
    }
    out.push((1 << 3) | 2);
    varint(stamp.len() as u64, out);
    out.extend_from_slice(&stamp);
    fixed32(2, image.width, out);
    fixed32(3, image.height, out);
    length_delimited(4, image_encoding(image.format).as_bytes(), out);
    fixed32(5, image.stride, out);
    length_delimited(6, &image.pixels, out);
    length_delimited(7, frame_id.as_bytes(), out);
}

/// The bytes of one point as [`append_packed_points`] packs them: `x`, `y`, `z`, and `intensity` when
/// the cloud has it.
pub fn packed_point_stride(cloud: &kairos_sdk::PointCloud) -> u32 {
    if cloud.intensity.is_some() { 16 } else { 12 }
}

/// Appends a cloud's points to `out` as little-endian `f32` fields, one point after the other: the
/// layout both Foxglove's and ROS's point clouds describe with their field lists.
pub fn append_packed_points(cloud: &kairos_sdk::PointCloud, out: &mut Vec<u8>) {
    for (index, point) in cloud.points.iter().enumerate() {
        for value in point.to_array() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        if let Some(intensity) = &cloud.intensity {
            out.extend_from_slice(&intensity.get(index).copied().unwrap_or(0.0).to_le_bytes());
        }
    }
}

/// Why a sample could not be encoded for its channel: the recorder fails, naming its file.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// A payload type this recorder has no encoding for (a newer runtime's).
    #[error("this recorder has no encoding for {0} samples: update the recording pack")]
    NoEncoding(kairos_sdk::DataType),
    /// A Foxglove schema's message that could not be written.
    #[error("{0}")]
    Protobuf(Box<dyn std::error::Error + Send + Sync>),
    /// A JSON message that could not be written.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A sample no ROS 2 message carries, or out of its range.
    #[error(transparent)]
    Ros2(#[from] crate::ros2::write::WriteError),
}

/// Encodes `payload` (of a sample stamped `timestamp`) in its schema's message encoding into `out`.
pub fn encode(
    payload: &Payload,
    timestamp: Timestamp,
    frame_id: &str,
    out: &mut Vec<u8>,
) -> Result<(), EncodeError> {
    out.clear();
    let protobuf =
        |message: &dyn Fn(&mut Vec<u8>) -> Result<(), EncodeError>, out: &mut Vec<u8>| message(out);
    let json_value = match payload {
        Payload::Image(image) => {
            encode_raw_image(image, timestamp, frame_id, out);
            return Ok(());
        }
        Payload::PointCloud(cloud) => {
            let with_intensity = cloud.intensity.is_some();
            let stride = packed_point_stride(cloud);
            let mut data = Vec::with_capacity(cloud.points.len() * stride as usize);
            append_packed_points(cloud, &mut data);
            let field = |name: &str, offset: u32| PackedElementField {
                name: name.to_owned(),
                offset,
                r#type: packed_element_field::NumericType::Float32 as i32,
            };
            let mut fields = vec![field("x", 0), field("y", 4), field("z", 8)];
            if with_intensity {
                fields.push(field("intensity", 12));
            }
            let message = FoxglovePointCloud {
                timestamp: Some(foxglove_time(timestamp)),
                frame_id: frame_id.to_owned(),
                pose: None,
                point_stride: stride,
                fields,
                data: foxglove::bytes::Bytes::from(data),
            };
            return protobuf(
                &|buf| {
                    message
                        .encode(buf)
                        .map_err(|e| EncodeError::Protobuf(Box::new(e)))
                },
                out,
            );
        }
        Payload::GnssFix(fix) => {
            let h = fix.horizontal_accuracy_m * fix.horizontal_accuracy_m;
            let v = fix.vertical_accuracy_m * fix.vertical_accuracy_m;
            // Foxglove has no field for the fix's quality: a metadata pair keeps it for replay.
            let status = match fix.status {
                FixStatus::NoFix => "no_fix",
                FixStatus::Fix => "fix",
                FixStatus::Differential => "differential",
                FixStatus::RtkFixed => "rtk_fixed",
            };
            let metadata = vec![foxglove::schemas::KeyValuePair {
                key: "kairos.status".to_owned(),
                value: status.to_owned(),
            }];
            let message = LocationFix {
                timestamp: Some(foxglove_time(timestamp)),
                frame_id: frame_id.to_owned(),
                latitude: fix.latitude_deg,
                longitude: fix.longitude_deg,
                altitude: fix.altitude_m,
                position_covariance: vec![h, 0.0, 0.0, 0.0, h, 0.0, 0.0, 0.0, v],
                position_covariance_type: location_fix::PositionCovarianceType::DiagonalKnown as i32,
                heading: None,
                velocity: None,
                color: None,
                metadata,
            };
            return protobuf(
                &|buf| {
                    message
                        .encode(buf)
                        .map_err(|e| EncodeError::Protobuf(Box::new(e)))
                },
                out,
            );
        }
        Payload::Pose(pose) => {
            let message = PoseInFrame {
                timestamp: Some(foxglove_time(timestamp)),
                frame_id: frame_id.to_owned(),
                pose: Some(FoxglovePose {
                    position: Some(Vector3 {
                        x: pose.position.x,
                        y: pose.position.y,
                        z: pose.position.z,
                    }),
                    orientation: Some(Quaternion {
                        x: pose.orientation.x,
                        y: pose.orientation.y,
                        z: pose.orientation.z,
                        w: pose.orientation.w,
                    }),
                }),
            };
            return protobuf(
                &|buf| {
                    message
                        .encode(buf)
                        .map_err(|e| EncodeError::Protobuf(Box::new(e)))
                },
                out,
            );
        }
        Payload::F64(v) => json!({"value": v}),
        Payload::I64(v) => json!({"value": v}),
        Payload::Bool(v) => json!({"value": v}),
        Payload::Vector(v) => json!({"values": &v[..]}),
        Payload::Matrix(m) => json!({"rows": m.rows, "cols": m.cols, "values": m.values}),
        Payload::Text(t) => json!({"text": &t[..]}),
        Payload::Bytes(b) => json!({"base64": base64(b)}),
        Payload::Imu(imu) => json!({
            "angular_velocity": {"x": imu.angular_velocity.x, "y": imu.angular_velocity.y, "z": imu.angular_velocity.z},
            "linear_acceleration": {"x": imu.linear_acceleration.x, "y": imu.linear_acceleration.y, "z": imu.linear_acceleration.z},
            "orientation": imu.orientation.map(|q| json!({"x": q.x, "y": q.y, "z": q.z, "w": q.w})),
        }),
        Payload::CanFrame(frame) if frame.remote => json!({
            "id": frame.id, "extended": frame.extended, "fd": frame.fd, "data": frame.data(),
            "remote": true, "length": frame.length(),
        }),
        Payload::CanFrame(frame) => {
            json!({"id": frame.id, "extended": frame.extended, "fd": frame.fd, "data": frame.data()})
        }
        Payload::Custom(custom) => {
            json!({"type_name": &custom.type_name[..], "base64": base64(&custom.data)})
        }
        other => {
            return Err(EncodeError::NoEncoding(other.data_type()));
        }
    };
    Ok(serde_json::to_writer(out, &json_value)?)
}

#[cfg(test)]
mod tests {
    use foxglove::Encode as _;
    use kairos_sdk::{Image, Payload, PixelFormat, Timestamp};

    use super::{base64, encode, foxglove_time, image_encoding};

    #[test]
    fn raw_images_encode_to_the_bytes_the_foxglove_encoder_writes() {
        for (time, frame) in [(1_700_000_000_123_456_789, "camera.image"), (0, ""), (5, "x")] {
            let pixels: Vec<u8> = (0..300 * 7 * 3).map(|i| (i % 251) as u8).collect();
            let image = Image::with_stride(299, 7, PixelFormat::Rgb8, 300 * 3, pixels).unwrap();
            let mut ours = Vec::new();
            encode(&Payload::Image(image.clone()), Timestamp(time), frame, &mut ours).unwrap();
            let reference = foxglove::schemas::RawImage {
                timestamp: Some(foxglove_time(Timestamp(time))),
                frame_id: frame.to_owned(),
                width: image.width,
                height: image.height,
                encoding: image_encoding(image.format).to_owned(),
                step: image.stride,
                data: foxglove::bytes::Bytes::copy_from_slice(&image.pixels),
            };
            let mut theirs = Vec::new();
            reference.encode(&mut theirs).unwrap();
            assert!(
                ours == theirs,
                "time {time}, frame {frame:?}: {:?} vs {:?}",
                &ours[..40.min(ours.len())],
                &theirs[..40.min(theirs.len())]
            );
        }
    }

    #[test]
    fn base64_matches_the_standard_alphabet_and_padding() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }
}

//! Recorded messages back into payloads: the inverse of [`crate::encode`], and raw bytes for schemas that
//! are not ours.

use std::sync::Arc;

use foxglove::Decode as _;
use foxglove::schemas::{
    LocationFix, PointCloud as FoxglovePointCloud, PoseInFrame, RawImage, packed_element_field,
};
use glam::{DQuat, DVec3, Vec3};
use kairos_sdk::{
    CanFrame, CustomPayload, DataType, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat,
    PointCloud, Pose,
};
use serde_json::Value as Json;

/// The prefix of the schemas of pack-defined types (`kairos.Custom.<type>`).
const CUSTOM_PREFIX: &str = "kairos.Custom.";

/// The data type a channel with this schema replays as. A schema that is not one we write replays as
/// that schema's raw messages, typed by the schema's name.
pub fn data_type_of(schema: &str) -> DataType {
    match schema {
        "foxglove.RawImage" => DataType::Image,
        "foxglove.PointCloud" => DataType::PointCloud,
        "foxglove.LocationFix" => DataType::GnssFix,
        "foxglove.PoseInFrame" => DataType::Pose,
        "kairos.F64" => DataType::F64,
        "kairos.I64" => DataType::I64,
        "kairos.Bool" => DataType::Bool,
        "kairos.Vector" => DataType::Vector,
        "kairos.Matrix" => DataType::Matrix,
        "kairos.Text" => DataType::Text,
        "kairos.Bytes" => DataType::Bytes,
        "kairos.Imu" => DataType::Imu,
        "kairos.CanFrame" => DataType::CanFrame,
        other => match other.strip_prefix(CUSTOM_PREFIX) {
            Some(name) => DataType::Custom(name.to_owned()),
            None if other.is_empty() => DataType::Custom("raw".to_owned()),
            None => DataType::Custom(other.to_owned()),
        },
    }
}

/// How one channel's messages become payloads: by the schema's name for Kairos recordings (and raw
/// bytes for foreign schemas), through the definition the file carries for rosbag2 channels.
#[derive(Debug, Clone)]
pub enum ChannelDecoder {
    /// A schema of ours, or a foreign one replayed raw, by its name.
    Named(String),
    /// A rosbag2 channel: CDR messages of this definition, replayed as this type.
    Ros2(Arc<crate::ros2::Definitions>, DataType),
    /// A rosbag2 channel whose definition cannot be read: each message is refused with the reason.
    Unreadable {
        /// The message type's name.
        schema: String,
        /// What is wrong with its definition.
        why: UnreadableChannel,
    },
}

/// Why a channel's messages cannot be decoded at all: said once for the channel, not per message.
#[derive(Debug, Clone, thiserror::Error)]
pub enum UnreadableChannel {
    /// ROS 2 messages in another encoding than CDR.
    #[error("ROS 2 messages encoded as '{0}' (only cdr is read)")]
    Encoding(String),
    /// An older bag without definitions, of a type Kairos has none of either.
    #[error(
        "the recording carries no definition of {0} (a bag recorded before ROS 2 Iron, of a type Kairos has \
         no definition of)"
    )]
    NoDefinition(String),
    /// The definition the file carries does not read.
    #[error(transparent)]
    Definition(#[from] crate::ros2::DefinitionError),
}

/// An image encoding Kairos has no pixel format for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("image encoding '{0}' is not one Kairos images have")]
pub struct EncodingError(pub String);

/// Why base64 text does not decode.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Base64Error {
    /// A character outside the alphabet.
    #[error("'{0}' is not a base64 character")]
    NotBase64(char),
    /// Base64 comes in groups of four.
    #[error("base64 text whose length is not a multiple of 4")]
    Length,
    /// More than two `=` in a group.
    #[error("base64 text with too much padding")]
    Padding,
}

/// Why one recorded message is not a sample: the player counts it, warns once per output, and goes on.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// The channel cannot be read at all.
    #[error(transparent)]
    Unreadable(#[from] UnreadableChannel),
    /// A ROS 2 message that does not decode against its definition.
    #[error(transparent)]
    Cdr(#[from] crate::ros2::CdrError),
    /// A ROS 2 message that is not the Kairos type its channel replays as.
    #[error(transparent)]
    Ros2(#[from] crate::ros2::MessageError),
    /// A JSON schema's message that is not JSON.
    #[error("not the JSON this schema describes: {0}")]
    Json(#[source] serde_json::Error),
    /// A field missing from a JSON message.
    #[error("no field '{0}'")]
    NoField(String),
    /// A JSON field of another kind.
    #[error("field '{name}' is not {what}")]
    FieldNot {
        /// The field.
        name: String,
        /// What it should be.
        what: &'static str,
    },
    /// A list of numbers with something else in it.
    #[error("field '{0}' holds a non-number")]
    NonNumber(String),
    /// A negative matrix dimension.
    #[error("negative {0} count")]
    NegativeCount(&'static str),
    /// Rows × columns is not the number of values.
    #[error("a {rows}x{cols} matrix with {values} values")]
    MatrixShape {
        /// Rows.
        rows: usize,
        /// Columns.
        cols: usize,
        /// Values given.
        values: usize,
    },
    /// A CAN id beyond 32 bits.
    #[error("CAN id out of range")]
    CanIdRange,
    /// A data byte beyond 255.
    #[error("a data byte out of range")]
    DataByteRange,
    /// A remote request longer than a classic frame.
    #[error("a remote request for more than 8 bytes")]
    RemoteRequestTooLong,
    /// More data than a CAN FD frame holds.
    #[error("a CAN frame of {0} bytes")]
    CanLength(usize),
    /// A type recorded as JSON that this version does not read back.
    #[error("no JSON decoding for {0}")]
    NoJsonDecoding(DataType),
    /// A Foxglove schema's message that does not decode.
    #[error("not a foxglove.{schema}: {source}")]
    Protobuf {
        /// The schema.
        schema: &'static str,
        /// What the decoder said.
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The image's geometry does not fit its pixels.
    #[error(transparent)]
    ImageSize(#[from] kairos_sdk::payload::ImageSizeError),
    /// An encoding Kairos has no pixel format for.
    #[error(transparent)]
    Encoding(#[from] EncodingError),
    /// Coordinates of another type than floats.
    #[error("point field '{0}' is neither float32 nor float64")]
    PointFieldType(String),
    /// Points need coordinates.
    #[error("a point cloud without x, y and z fields")]
    NoCoordinates,
    /// Points of no bytes.
    #[error("a point cloud with a point stride of 0")]
    ZeroStride,
    /// A field's offset beyond the point.
    #[error("a point field lies outside the point stride")]
    FieldOutsideStride,
    /// A custom payload's base64 that does not decode.
    #[error(transparent)]
    Base64(#[from] Base64Error),
}

/// A Foxglove message decoding error, with its schema's name.
fn protobuf<E: std::error::Error + Send + Sync + 'static>(
    schema: &'static str,
) -> impl FnOnce(E) -> DecodeError {
    move |source| DecodeError::Protobuf {
        schema,
        source: Box::new(source),
    }
}

impl ChannelDecoder {
    /// The decoder of `channel`'s messages.
    pub fn of(channel: &mcap::Channel<'_>) -> ChannelDecoder {
        let Some(schema) = &channel.schema else {
            return ChannelDecoder::Named(String::new());
        };
        if schema.encoding != crate::ros2::SCHEMA_ENCODING {
            return ChannelDecoder::Named(schema.name.clone());
        }
        if channel.message_encoding != crate::ros2::MESSAGE_ENCODING {
            return ChannelDecoder::Unreadable {
                schema: schema.name.clone(),
                why: UnreadableChannel::Encoding(channel.message_encoding.clone()),
            };
        }
        // An older SQLite bag carries no definitions: the types Kairos writes are read with its own.
        let text = if schema.data.is_empty() {
            crate::ros2::write::definition_of(&schema.name)
        } else {
            String::from_utf8_lossy(&schema.data).into_owned()
        };
        if text.is_empty() && !schema.name.ends_with("/Empty") {
            return ChannelDecoder::Unreadable {
                schema: schema.name.clone(),
                why: UnreadableChannel::NoDefinition(schema.name.clone()),
            };
        }
        match crate::ros2::Definitions::parse(&schema.name, &text) {
            Ok(definitions) => {
                let noted = channel.metadata.get("kairos.type").map(String::as_str);
                let data_type = crate::ros2::data_type_noted(&schema.name, noted);
                ChannelDecoder::Ros2(Arc::new(definitions), data_type)
            }
            Err(why) => ChannelDecoder::Unreadable {
                schema: schema.name.clone(),
                why: why.into(),
            },
        }
    }

    /// The data type the channel replays as.
    pub fn data_type(&self) -> DataType {
        match self {
            ChannelDecoder::Named(schema) => data_type_of(schema),
            ChannelDecoder::Ros2(_, data_type) => data_type.clone(),
            ChannelDecoder::Unreadable { schema, .. } => crate::ros2::data_type_of(schema),
        }
    }

    /// Decodes one message; with it, the timestamp the message itself carries (a ROS header's stamp),
    /// when it has one.
    pub fn decode(&self, data: &[u8]) -> Result<(Payload, Option<kairos_sdk::Timestamp>), DecodeError> {
        match self {
            ChannelDecoder::Named(schema) => decode(schema, data).map(|payload| (payload, None)),
            ChannelDecoder::Ros2(definitions, data_type) => {
                let value = definitions.decode(data)?;
                let payload = crate::ros2::to_payload(definitions, &value, data_type)?;
                Ok((payload, crate::ros2::header_stamp(definitions, &value)))
            }
            ChannelDecoder::Unreadable { why, .. } => Err(why.clone().into()),
        }
    }
}

/// Decodes one message of a channel with schema `schema` into the payload [`data_type_of`] promises.
pub fn decode(schema: &str, data: &[u8]) -> Result<Payload, DecodeError> {
    match data_type_of(schema) {
        DataType::Image => decode_image(data),
        DataType::PointCloud => decode_point_cloud(data),
        DataType::GnssFix => decode_fix(data),
        DataType::Pose => decode_pose(data),
        DataType::Custom(name) => {
            if schema.starts_with(CUSTOM_PREFIX) {
                let json = parse_json(data)?;
                let bytes = unbase64(text_field(&json, "base64")?)?;
                Ok(Payload::Custom(CustomPayload {
                    type_name: Arc::from(name.as_str()),
                    data: Arc::from(bytes),
                }))
            } else {
                Ok(Payload::Custom(CustomPayload {
                    type_name: Arc::from(name.as_str()),
                    data: Arc::from(data),
                }))
            }
        }
        json_type => decode_json(&json_type, &parse_json(data)?),
    }
}

fn parse_json(data: &[u8]) -> Result<Json, DecodeError> {
    serde_json::from_slice(data).map_err(DecodeError::Json)
}

fn field<'a>(json: &'a Json, name: &str) -> Result<&'a Json, DecodeError> {
    json.get(name)
        .ok_or_else(|| DecodeError::NoField(name.to_owned()))
}

fn number(json: &Json, name: &str) -> Result<f64, DecodeError> {
    field(json, name)?.as_f64().ok_or_else(|| DecodeError::FieldNot {
        name: name.to_owned(),
        what: "a number",
    })
}

fn integer(json: &Json, name: &str) -> Result<i64, DecodeError> {
    field(json, name)?.as_i64().ok_or_else(|| DecodeError::FieldNot {
        name: name.to_owned(),
        what: "an integer",
    })
}

fn boolean(json: &Json, name: &str) -> Result<bool, DecodeError> {
    field(json, name)?.as_bool().ok_or_else(|| DecodeError::FieldNot {
        name: name.to_owned(),
        what: "a boolean",
    })
}

fn text_field<'a>(json: &'a Json, name: &str) -> Result<&'a str, DecodeError> {
    field(json, name)?.as_str().ok_or_else(|| DecodeError::FieldNot {
        name: name.to_owned(),
        what: "text",
    })
}

fn numbers(json: &Json, name: &str) -> Result<Vec<f64>, DecodeError> {
    field(json, name)?
        .as_array()
        .ok_or_else(|| DecodeError::FieldNot {
            name: name.to_owned(),
            what: "a list",
        })?
        .iter()
        .map(|v| v.as_f64().ok_or_else(|| DecodeError::NonNumber(name.to_owned())))
        .collect()
}

fn vector3(json: &Json, name: &str) -> Result<DVec3, DecodeError> {
    let v = field(json, name)?;
    Ok(DVec3::new(number(v, "x")?, number(v, "y")?, number(v, "z")?))
}

fn decode_json(data_type: &DataType, json: &Json) -> Result<Payload, DecodeError> {
    Ok(match data_type {
        DataType::F64 => Payload::F64(number(json, "value")?),
        DataType::I64 => Payload::I64(integer(json, "value")?),
        DataType::Bool => Payload::Bool(boolean(json, "value")?),
        DataType::Vector => Payload::Vector(Arc::from(numbers(json, "values")?)),
        DataType::Matrix => {
            let rows =
                usize::try_from(integer(json, "rows")?).map_err(|_| DecodeError::NegativeCount("row"))?;
            let cols =
                usize::try_from(integer(json, "cols")?).map_err(|_| DecodeError::NegativeCount("column"))?;
            let values = numbers(json, "values")?;
            if rows.checked_mul(cols) != Some(values.len()) {
                let values = values.len();
                return Err(DecodeError::MatrixShape { rows, cols, values });
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        }
        DataType::Text => Payload::Text(Arc::from(text_field(json, "text")?)),
        DataType::Bytes => Payload::Bytes(Arc::from(unbase64(text_field(json, "base64")?)?)),
        DataType::Imu => {
            let orientation = match field(json, "orientation")? {
                Json::Null => None,
                q => Some(DQuat::from_xyzw(
                    number(q, "x")?,
                    number(q, "y")?,
                    number(q, "z")?,
                    number(q, "w")?,
                )),
            };
            Payload::Imu(Imu {
                angular_velocity: vector3(json, "angular_velocity")?,
                linear_acceleration: vector3(json, "linear_acceleration")?,
                orientation,
            })
        }
        DataType::CanFrame => {
            let id = u32::try_from(integer(json, "id")?).map_err(|_| DecodeError::CanIdRange)?;
            let data: Vec<u8> = field(json, "data")?
                .as_array()
                .ok_or_else(|| DecodeError::FieldNot {
                    name: "data".to_owned(),
                    what: "a list",
                })?
                .iter()
                .map(|b| {
                    b.as_u64()
                        .and_then(|b| u8::try_from(b).ok())
                        .ok_or(DecodeError::DataByteRange)
                })
                .collect::<Result<_, _>>()?;
            let extended = boolean(json, "extended")?;
            let optional = |name: &str| {
                json.get(name)
                    .and_then(serde_json::Value::as_bool)
                    .unwrap_or(false)
            };
            let mut frame = if optional("remote") {
                let length = json
                    .get("length")
                    .and_then(serde_json::Value::as_u64)
                    .unwrap_or(0);
                u8::try_from(length)
                    .ok()
                    .and_then(|length| CanFrame::remote_request(id, extended, length))
                    .ok_or(DecodeError::RemoteRequestTooLong)?
            } else {
                CanFrame::new(id, extended, &data).ok_or(DecodeError::CanLength(data.len()))?
            };
            frame.fd |= optional("fd");
            Payload::CanFrame(frame)
        }
        other => return Err(DecodeError::NoJsonDecoding(other.clone())),
    })
}

fn decode_image(data: &[u8]) -> Result<Payload, DecodeError> {
    let message = RawImage::decode(data).map_err(protobuf("RawImage"))?;
    let format = pixel_format_of(&message.encoding)?;
    let image = Image::with_stride(
        message.width,
        message.height,
        format,
        message.step,
        Arc::<[u8]>::from(&message.data[..]),
    )?;
    Ok(Payload::Image(image))
}

/// The pixel format an image encoding names, as ROS and Foxglove name them (`rgb8`, `mono16`, `8UC3`).
pub fn pixel_format_of(encoding: &str) -> Result<PixelFormat, EncodingError> {
    Ok(match encoding {
        "mono8" | "8UC1" => PixelFormat::Gray8,
        "mono16" | "16UC1" => PixelFormat::Gray16,
        "rgb8" => PixelFormat::Rgb8,
        "rgba8" => PixelFormat::Rgba8,
        "bgr8" | "8UC3" => PixelFormat::Bgr8,
        "bgra8" => PixelFormat::Bgra8,
        other => return Err(EncodingError(other.to_owned())),
    })
}

/// Reads one numeric field of a packed point as `f32`.
type FieldReader = Box<dyn Fn(&[u8]) -> Option<f32>>;

fn decode_point_cloud(data: &[u8]) -> Result<Payload, DecodeError> {
    use packed_element_field::NumericType;
    let message = FoxglovePointCloud::decode(data).map_err(protobuf("PointCloud"))?;
    let stride = message.point_stride as usize;
    let reader = |name: &str| -> Result<Option<FieldReader>, DecodeError> {
        let Some(field) = message.fields.iter().find(|f| f.name == name) else {
            return Ok(None);
        };
        let offset = field.offset as usize;
        let read: FieldReader = match NumericType::try_from(field.r#type) {
            Ok(NumericType::Float32) => Box::new(move |point: &[u8]| {
                Some(f32::from_le_bytes(
                    point.get(offset..offset + 4)?.try_into().ok()?,
                ))
            }),
            #[allow(clippy::cast_possible_truncation, reason = "points are f32 in Kairos")]
            Ok(NumericType::Float64) => Box::new(move |point: &[u8]| {
                Some(f64::from_le_bytes(point.get(offset..offset + 8)?.try_into().ok()?) as f32)
            }),
            _ => return Err(DecodeError::PointFieldType(name.to_owned())),
        };
        Ok(Some(read))
    };
    let (Some(x), Some(y), Some(z)) = (reader("x")?, reader("y")?, reader("z")?) else {
        return Err(DecodeError::NoCoordinates);
    };
    let intensity_of = reader("intensity")?;
    if stride == 0 {
        return Err(DecodeError::ZeroStride);
    }
    let count = message.data.len() / stride;
    let mut points = Vec::with_capacity(count);
    let mut intensity = intensity_of.as_ref().map(|_| Vec::with_capacity(count));
    for point in message.data.chunks_exact(stride) {
        let (Some(px), Some(py), Some(pz)) = (x(point), y(point), z(point)) else {
            return Err(DecodeError::FieldOutsideStride);
        };
        points.push(Vec3::new(px, py, pz));
        if let (Some(read), Some(values)) = (&intensity_of, &mut intensity) {
            values.push(read(point).unwrap_or(0.0));
        }
    }
    Ok(Payload::PointCloud(Arc::new(PointCloud { points, intensity })))
}

fn decode_fix(data: &[u8]) -> Result<Payload, DecodeError> {
    let message = LocationFix::decode(data).map_err(protobuf("LocationFix"))?;
    let covariance = |i: usize| {
        message
            .position_covariance
            .get(i)
            .copied()
            .unwrap_or(0.0)
            .max(0.0)
            .sqrt()
    };
    let status_of = |key: &str| {
        message
            .metadata
            .iter()
            .find(|pair| pair.key == key)
            .map(|pair| pair.value.as_str())
    };
    let status = match status_of("kairos.status").or_else(|| status_of("status")) {
        Some("no_fix") => FixStatus::NoFix,
        Some("differential") => FixStatus::Differential,
        Some("rtk_fixed") => FixStatus::RtkFixed,
        _ => FixStatus::Fix,
    };
    Ok(Payload::GnssFix(GnssFix {
        latitude_deg: message.latitude,
        longitude_deg: message.longitude,
        altitude_m: message.altitude,
        horizontal_accuracy_m: covariance(0),
        vertical_accuracy_m: covariance(8),
        status,
    }))
}

fn decode_pose(data: &[u8]) -> Result<Payload, DecodeError> {
    let message = PoseInFrame::decode(data).map_err(protobuf("PoseInFrame"))?;
    let pose = message.pose.unwrap_or_default();
    let position = pose.position.unwrap_or_default();
    let orientation = pose.orientation.unwrap_or_default();
    Ok(Payload::Pose(Pose {
        position: DVec3::new(position.x, position.y, position.z),
        orientation: DQuat::from_xyzw(orientation.x, orientation.y, orientation.z, orientation.w),
    }))
}

/// Standard base64 with padding, as [`crate::encode`] writes it.
fn unbase64(text: &str) -> Result<Vec<u8>, Base64Error> {
    let value = |c: u8| -> Result<u32, Base64Error> {
        Ok(match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return Err(Base64Error::NotBase64(char::from(c))),
        }
        .into())
    };
    let bytes = text.as_bytes();
    if !bytes.len().is_multiple_of(4) {
        return Err(Base64Error::Length);
    }
    let mut out = Vec::with_capacity(bytes.len() / 4 * 3);
    for group in bytes.chunks_exact(4) {
        let padding = group.iter().rev().take_while(|&&c| c == b'=').count();
        if padding > 2 {
            return Err(Base64Error::Padding);
        }
        let mut n = 0_u32;
        for (i, &c) in group.iter().enumerate() {
            n = (n << 6) | if i >= 4 - padding { 0 } else { value(c)? };
        }
        let [_, a, b, c] = n.to_be_bytes();
        out.extend_from_slice(&[a, b, c][..3 - padding]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use kairos_sdk::{
        CanFrame, FixStatus, GnssFix, Image, Payload, PixelFormat, PointCloud, Pose, Timestamp,
    };

    use std::sync::Arc;

    use super::{ChannelDecoder, DataType, decode, unbase64};
    use crate::encode::{encode, schema_for};

    fn round_trip(payload: &Payload) -> Payload {
        let mut bytes = Vec::new();
        encode(payload, Timestamp(1_700_000_000_123_456_789), "frame", &mut bytes).unwrap();
        decode(&schema_for(payload).name, &bytes).unwrap()
    }

    #[test]
    fn every_payload_type_survives_encoding_and_decoding() {
        use std::sync::Arc;
        let payloads = vec![
            Payload::F64(-1.25e-3),
            Payload::I64(-42),
            Payload::Bool(true),
            Payload::Vector(Arc::from(vec![1.0, 2.5, -3.0])),
            Payload::Matrix(Arc::new(kairos_sdk::Matrix {
                rows: 2,
                cols: 2,
                values: vec![1.0, 2.0, 3.0, 4.0],
            })),
            Payload::Text(Arc::from("héllo")),
            Payload::Bytes(Arc::from(vec![0_u8, 1, 2, 254, 255])),
            Payload::Image(Image::packed(3, 2, PixelFormat::Rgb8, vec![7_u8; 18]).unwrap()),
            Payload::PointCloud(Arc::new(PointCloud {
                points: vec![glam::Vec3::new(1.0, -2.0, 3.5), glam::Vec3::ZERO],
                intensity: Some(vec![0.5, 1.0]),
            })),
            Payload::Imu(kairos_sdk::Imu {
                angular_velocity: glam::DVec3::new(0.1, 0.2, 0.3),
                linear_acceleration: glam::DVec3::new(0.0, 0.0, 9.81),
                orientation: Some(glam::DQuat::IDENTITY),
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
            Payload::Custom(kairos_sdk::CustomPayload {
                type_name: Arc::from("lidar.Scan"),
                data: Arc::from(vec![9_u8, 8, 7]),
            }),
        ];
        for payload in &payloads {
            assert_eq!(&round_trip(payload), payload, "{:?}", payload.data_type());
        }
    }

    #[test]
    fn floats_come_back_bit_for_bit() {
        // Without exact float parsing one value in a few thousand comes back one unit in the last place off.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        for _ in 0..20_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let value = f64::from_bits(state >> 2) * 1e-300;
            assert_eq!(round_trip(&Payload::F64(value)), Payload::F64(value), "{value:e}");
        }
    }

    #[test]
    fn a_foreign_schema_replays_as_its_raw_bytes_named_by_the_schema() {
        let payload = decode("ros2msg/sensor_msgs/msg/Range", &[1, 2, 3]).unwrap();
        let Payload::Custom(custom) = payload else {
            panic!("expected raw bytes")
        };
        assert_eq!(&*custom.type_name, "ros2msg/sensor_msgs/msg/Range");
        assert_eq!(&*custom.data, &[1, 2, 3]);
    }

    /// A channel as MCAP gives it, with a `ros2msg` schema.
    fn ros_channel(type_name: &str, definition: &str, message_encoding: &str) -> mcap::Channel<'static> {
        mcap::Channel {
            id: 1,
            topic: "/topic".to_owned(),
            schema: Some(Arc::new(mcap::Schema {
                id: 1,
                name: type_name.to_owned(),
                encoding: "ros2msg".to_owned(),
                data: std::borrow::Cow::Owned(definition.as_bytes().to_vec()),
            })),
            message_encoding: message_encoding.to_owned(),
            metadata: std::collections::BTreeMap::new(),
        }
    }

    #[test]
    fn a_rosbag2_channel_whose_definition_is_broken_refuses_each_message_saying_why() {
        let incomplete = ros_channel("sensor_msgs/msg/Imu", "std_msgs/Header header\n", "cdr");
        let decoder = ChannelDecoder::of(&incomplete);
        assert_eq!(
            decoder.data_type(),
            DataType::Imu,
            "typed from its name all the same"
        );
        let why = decoder.decode(&[0, 1, 0, 0]).unwrap_err().to_string();
        assert!(
            why.contains("sensor_msgs/Imu.header is a std_msgs/Header"),
            "{why}"
        );
        let json_encoded = ros_channel("std_msgs/msg/Float64", "float64 data\n", "json");
        let why = ChannelDecoder::of(&json_encoded)
            .decode(b"{}")
            .unwrap_err()
            .to_string();
        assert!(why.contains("only cdr is read"), "{why}");
        let fine = ChannelDecoder::of(&ros_channel("std_msgs/msg/Float64", "float64 data\n", "cdr"));
        let mut message = vec![0, 1, 0, 0];
        message.extend_from_slice(&2.5f64.to_le_bytes());
        assert_eq!(fine.decode(&message).unwrap(), (Payload::F64(2.5), None));
        assert!(
            fine.decode(&message[..7])
                .unwrap_err()
                .to_string()
                .contains("std_msgs/Float64.data")
        );
    }

    #[test]
    fn malformed_messages_are_errors_not_panics() {
        assert!(decode("kairos.F64", b"{\"value\": \"x\"}").is_err());
        assert!(decode("kairos.Matrix", b"{\"rows\": 3, \"cols\": 3, \"values\": [1]}").is_err());
        assert!(decode("foxglove.RawImage", &[0xff, 0xff, 0xff]).is_err());
        assert!(unbase64("Zm9v=").is_err());
        assert_eq!(unbase64("Zm9vYg==").unwrap(), b"foob");
    }
}

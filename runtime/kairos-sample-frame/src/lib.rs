//! Whole samples as bytes and back, so two runtimes exchange samples with both times and their sequence
//! number, and fusion by timestamp still works across them. Encoding then decoding gives back the same
//! payload, whatever its type.
//!
//! Two layouts, and [`decode`] reads both:
//! - the **binary frame** (`KSB1`, [`binary`]), which Kairos sends between runtimes (socket components in
//!   `kairos` mode, links between hosts): a fixed header and the payload in its own layout. Building,
//!   writing, parsing and reading back a JSON header cost about a microsecond each way, more than the rest
//!   of a small sample's trip;
//! - the **control protocol's frame** (`KSF1`, `kairos_protocol::frame`), a JSON header then the payload's
//!   bulk, which the protocol's sample subscriptions carry to clients ([`encode_json`]) and which a
//!   third-party program may send to a Kairos receiver.

use std::borrow::Cow;
use std::sync::Arc;

use glam::{DQuat, DVec3, Vec3};
use kairos_protocol::frame::{self, ImageLayout, SampleHeader};
use kairos_sdk::{
    CanFrame, CustomPayload, DataType, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat,
    PixelsMut, PointCloud, Pose, Sample, Timestamp,
};
use serde_json::{Value as Json, json};

/// Why bytes are not a sample frame: the sender's fault (or a newer sender's), named so that a receiver
/// can count and report it.
#[derive(Debug, thiserror::Error)]
pub enum FrameDecodeError {
    /// Not a control-protocol frame either.
    #[error(transparent)]
    Frame(#[from] frame::FrameError),
    /// A binary frame cut before a field.
    #[error("a binary frame that ends before its {0}")]
    EndsBefore(&'static str),
    /// A binary frame cut inside a field.
    #[error("a binary frame that ends inside its {0}")]
    EndsInside(&'static str),
    /// A count beyond what this machine addresses.
    #[error("a {0} too large")]
    TooLarge(&'static str),
    /// A name that is not UTF-8.
    #[error("a {0} that is not UTF-8")]
    NameNotUtf8(&'static str),
    /// Text that is not UTF-8.
    #[error("text that is not UTF-8")]
    TextNotUtf8,
    /// Bytes of numbers that are not a whole number of them.
    #[error("{bytes} bytes of {what} are not a whole number of f64s")]
    NotWholeF64s {
        /// The bytes given.
        bytes: usize,
        /// What they hold.
        what: &'static str,
    },
    /// A kind of payload this version does not know.
    #[error("a binary frame of kind {0}, which this version does not know (a newer sender?)")]
    UnknownKind(u8),
    /// A pixel format by number this version does not know.
    #[error("an unknown pixel format {0}")]
    UnknownPixelFormat(u8),
    /// A pixel format by name this version does not know.
    #[error("an unknown pixel format {0:?}")]
    UnknownPixelFormatName(String),
    /// An image frame's header without the image's layout.
    #[error("an image frame without its layout")]
    NoImageLayout,
    /// The image's geometry does not fit its pixels.
    #[error(transparent)]
    ImageSize(#[from] kairos_sdk::payload::ImageSizeError),
    /// A header whose value is missing.
    #[error("a {0} frame without its value")]
    NoValue(DataType),
    /// A header value of the wrong kind.
    #[error("the value is not {0}")]
    ValueNot(&'static str),
    /// A JSON number expected.
    #[error("{0} is not a number")]
    NotANumber(Json),
    /// A JSON array of numbers expected.
    #[error("expected an array of numbers")]
    NotNumbers,
    /// A JSON array of this many numbers expected.
    #[error("expected {0}")]
    Expected(&'static str),
    /// A field of the value missing.
    #[error("no field {0:?}")]
    NoField(&'static str),
    /// A dimension that is not a count.
    #[error("{0} is not a count")]
    NotACount(&'static str),
    /// Rows × columns is not the number of values.
    #[error("a {rows}×{cols} matrix with {values} values")]
    MatrixShape {
        /// Rows.
        rows: usize,
        /// Columns.
        cols: usize,
        /// Values given.
        values: usize,
    },
    /// A fix status by name this version does not know.
    #[error("an unknown fix status")]
    UnknownFixStatusName,
    /// A fix status by number this version does not know.
    #[error("an unknown fix status {0}")]
    UnknownFixStatus(u8),
    /// The CAN id is not a 32-bit number.
    #[error("the CAN id is not a 32-bit number")]
    CanId,
    /// The CAN data is not an array.
    #[error("the CAN data is not an array")]
    CanDataNotArray,
    /// The CAN data holds something other than bytes.
    #[error("the CAN data are not bytes")]
    CanDataNotBytes,
    /// A remote request longer than a classic frame.
    #[error("a remote request for more than 8 bytes")]
    RemoteRequestTooLong,
    /// More data than a CAN FD frame holds.
    #[error("more than 64 CAN data bytes")]
    CanFrameTooLong,
    /// Point bytes that are not a whole number of points.
    #[error("{bytes} bytes of points are not a whole number of {stride}-byte points")]
    PointsNotWhole {
        /// The bytes given.
        bytes: usize,
        /// The bytes of one point.
        stride: usize,
    },
}

/// The name of a pixel format in frames (`rgb8`).
pub fn format_name(format: PixelFormat) -> &'static str {
    match format {
        PixelFormat::Gray8 => "gray8",
        PixelFormat::Gray16 => "gray16",
        PixelFormat::Rgb8 => "rgb8",
        PixelFormat::Rgba8 => "rgba8",
        PixelFormat::Bgr8 => "bgr8",
        PixelFormat::Bgra8 => "bgra8",
    }
}

fn format_of(name: &str) -> Option<PixelFormat> {
    Some(match name {
        "gray8" => PixelFormat::Gray8,
        "gray16" => PixelFormat::Gray16,
        "rgb8" => PixelFormat::Rgb8,
        "rgba8" => PixelFormat::Rgba8,
        "bgr8" => PixelFormat::Bgr8,
        "bgra8" => PixelFormat::Bgra8,
        _ => return None,
    })
}

fn status_name(status: FixStatus) -> &'static str {
    match status {
        FixStatus::NoFix => "no_fix",
        FixStatus::Fix => "fix",
        FixStatus::Differential => "differential",
        FixStatus::RtkFixed => "rtk_fixed",
    }
}

/// Small payloads as the JSON `value` of a frame header; `None` for those that travel as bytes.
pub fn value_of(payload: &Payload) -> Option<Json> {
    macro_rules! xyz {
        ($v:expr) => {
            json!([$v.x, $v.y, $v.z])
        };
    }
    Some(match payload {
        Payload::F64(v) => json!(v),
        Payload::I64(v) => json!(v),
        Payload::Bool(v) => json!(v),
        Payload::Vector(v) => json!(&v[..]),
        Payload::Matrix(m) => json!({"rows": m.rows, "cols": m.cols, "values": m.values}),
        Payload::Text(t) => json!(&t[..]),
        Payload::Imu(imu) => json!({
            "angular_velocity": xyz!(imu.angular_velocity),
            "linear_acceleration": xyz!(imu.linear_acceleration),
            "orientation": imu.orientation.map(|q| json!([q.x, q.y, q.z, q.w])),
        }),
        Payload::GnssFix(fix) => json!({
            "latitude_deg": fix.latitude_deg, "longitude_deg": fix.longitude_deg, "altitude_m": fix.altitude_m,
            "horizontal_accuracy_m": fix.horizontal_accuracy_m, "vertical_accuracy_m": fix.vertical_accuracy_m,
            "status": status_name(fix.status),
        }),
        Payload::CanFrame(frame) if frame.remote => json!({
            "id": frame.id, "extended": frame.extended, "fd": frame.fd, "data": frame.data(),
            "remote": true, "length": frame.length(),
        }),
        Payload::CanFrame(frame) => {
            json!({"id": frame.id, "extended": frame.extended, "fd": frame.fd, "data": frame.data()})
        }
        Payload::Pose(pose) => {
            let q = pose.orientation;
            json!({"position": xyz!(pose.position), "orientation": [q.x, q.y, q.z, q.w]})
        }
        // Large payloads travel as bytes after the header.
        _ => return None,
    })
}

/// A point cloud's points as frame bytes: x, y, z and, with intensity, a fourth f32, little-endian.
pub fn point_bytes(cloud: &PointCloud) -> Vec<u8> {
    let stride = if cloud.intensity.is_some() { 16 } else { 12 };
    let mut bytes = Vec::with_capacity(cloud.points.len() * stride);
    for (index, point) in cloud.points.iter().enumerate() {
        for value in point.to_array() {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        if let Some(intensity) = &cloud.intensity {
            bytes.extend_from_slice(&intensity.get(index).copied().unwrap_or(0.0).to_le_bytes());
        }
    }
    bytes
}

/// The header of `sample` of `output`, without image layout (the caller knows how it sends pixels).
pub fn header_of(output: &str, sample: &Sample, skipped: u64) -> SampleHeader {
    SampleHeader {
        output: output.to_owned(),
        data_type: sample.payload.data_type().to_string(),
        timestamp_ns: sample.timestamp.as_nanos(),
        time_of_issue_ns: sample.time_of_issue.as_nanos(),
        sequence: sample.sequence,
        skipped,
        value: value_of(&sample.payload),
        image: None,
        intensity: matches!(&sample.payload, Payload::PointCloud(cloud) if cloud.intensity.is_some()),
    }
}

pub mod binary;

/// `sample` whole as a binary frame in two parts: its start and the payload's bulk, borrowed where the
/// payload holds it (pixels, bytes, text), so a transport copies it once, where it goes. A sample the
/// binary layout cannot hold (an output name over 64 KiB) goes as the protocol's frame.
pub fn encode<'s>(output: &str, sample: &'s Sample) -> (Vec<u8>, Cow<'s, [u8]>) {
    binary::encode(output, sample).unwrap_or_else(|| encode_json(output, sample))
}

/// `sample` whole as one binary frame.
pub fn encode_whole(output: &str, sample: &Sample) -> Vec<u8> {
    join(encode(output, sample))
}

/// `sample` whole in the control protocol's frame, in two parts: its start (magic, header length, JSON
/// header) and the payload's bytes, borrowed where they can be.
pub fn encode_json<'s>(output: &str, sample: &'s Sample) -> (Vec<u8>, Cow<'s, [u8]>) {
    let mut header = header_of(output, sample, 0);
    let body: Cow<'s, [u8]> = match &sample.payload {
        Payload::Image(image) => {
            header.image = Some(ImageLayout {
                width: image.width,
                height: image.height,
                format: format_name(image.format).to_owned(),
                stride: image.stride,
                original_width: None,
                shared: None,
            });
            Cow::Borrowed(&image.pixels[..])
        }
        Payload::PointCloud(cloud) => Cow::Owned(point_bytes(cloud)),
        Payload::Bytes(bytes) => Cow::Borrowed(&bytes[..]),
        Payload::Custom(custom) => Cow::Borrowed(&custom.data[..]),
        _ => Cow::Borrowed(&[]),
    };
    (frame::encode(&header, &[]), body)
}

/// `sample` whole as one frame of the control protocol.
pub fn encode_json_whole(output: &str, sample: &Sample) -> Vec<u8> {
    join(encode_json(output, sample))
}

fn join((head, body): (Vec<u8>, Cow<'_, [u8]>)) -> Vec<u8> {
    let mut bytes = head;
    bytes.extend_from_slice(&body);
    bytes
}

/// A sample received in a frame.
#[derive(Debug, Clone)]
pub struct Received {
    /// The sender's output (`camera.image`).
    pub output: String,
    /// Its sequence number on that output.
    pub sequence: u64,
    /// The sample, with both of its times as sent (its own sequence number is the receiver's to give).
    pub sample: Sample,
}

/// Decodes a frame of either layout back into its sample.
pub fn decode(bytes: &[u8]) -> Result<Received, FrameDecodeError> {
    if let Some(binary) = bytes.strip_prefix(binary::MAGIC) {
        return binary::decode(binary);
    }
    let (header, body) = frame::decode(bytes)?;
    let payload = payload_of(&header, body)?;
    let mut sample = Sample::new(payload, Timestamp(header.timestamp_ns));
    sample.time_of_issue = Timestamp(header.time_of_issue_ns);
    Ok(Received {
        output: header.output,
        sequence: header.sequence,
        sample,
    })
}

/// [`decode`] for a frame in pieces, in order. An image whose header lies whole in the first piece has its
/// pixels copied from the pieces straight into the shared pixel pool; any other frame is joined first.
pub fn decode_pieces(pieces: &[&[u8]]) -> Result<Received, FrameDecodeError> {
    match pieces {
        [] => decode(&[]),
        [whole] => decode(whole),
        [first, rest @ ..] => {
            if let Some(image) = binary::decode_image_pieces(first, rest) {
                return image;
            }
            if let Ok((header, head_of_body)) = frame::decode(first)
                && DataType::from_name(&header.data_type) == DataType::Image
            {
                let body = std::iter::once(head_of_body).chain(rest.iter().copied());
                let payload = image_of(&header, body)?;
                let mut sample = Sample::new(payload, Timestamp(header.timestamp_ns));
                sample.time_of_issue = Timestamp(header.time_of_issue_ns);
                return Ok(Received {
                    output: header.output,
                    sequence: header.sequence,
                    sample,
                });
            }
            decode(&pieces.concat())
        }
    }
}

/// An image frame's payload from its header and its pixels, which may come in several pieces.
fn image_of<'b>(
    header: &SampleHeader,
    body: impl Iterator<Item = &'b [u8]> + Clone,
) -> Result<Payload, FrameDecodeError> {
    let layout = header.image.as_ref().ok_or(FrameDecodeError::NoImageLayout)?;
    let format = format_of(&layout.format)
        .ok_or_else(|| FrameDecodeError::UnknownPixelFormatName(layout.format.clone()))?;
    image_of_pieces((layout.width, layout.height, layout.stride, format), body)
}

/// An image from its layout and its pixels, which may come in several pieces: copied into the shared pixel
/// pool, so the image goes on through the diagram without another copy.
fn image_of_pieces<'b>(
    (width, height, stride, format): binary::ImageLayout,
    body: impl Iterator<Item = &'b [u8]> + Clone,
) -> Result<Payload, FrameDecodeError> {
    let length = body.clone().map(<[u8]>::len).sum();
    let mut pixels = PixelsMut::new(length);
    let mut at = 0;
    for piece in body {
        pixels[at..at + piece.len()].copy_from_slice(piece);
        at += piece.len();
    }
    Ok(Payload::Image(Image::with_stride(
        width,
        height,
        format,
        stride,
        pixels.freeze(),
    )?))
}

fn number(value: &Json) -> Result<f64, FrameDecodeError> {
    match value {
        // JSON has no NaN: a NaN was sent as null.
        Json::Null => Ok(f64::NAN),
        other => other
            .as_f64()
            .ok_or_else(|| FrameDecodeError::NotANumber(other.clone())),
    }
}

fn numbers(value: Option<&Json>) -> Result<Vec<f64>, FrameDecodeError> {
    value
        .and_then(Json::as_array)
        .ok_or(FrameDecodeError::NotNumbers)?
        .iter()
        .map(number)
        .collect()
}

fn field<'v>(value: &'v Json, name: &'static str) -> Result<&'v Json, FrameDecodeError> {
    value.get(name).ok_or(FrameDecodeError::NoField(name))
}

fn vector3(value: Option<&Json>) -> Result<DVec3, FrameDecodeError> {
    match numbers(value)?[..] {
        [x, y, z] => Ok(DVec3::new(x, y, z)),
        _ => Err(FrameDecodeError::Expected("[x, y, z]")),
    }
}

fn quaternion(value: Option<&Json>) -> Result<DQuat, FrameDecodeError> {
    match numbers(value)?[..] {
        [x, y, z, w] => Ok(DQuat::from_xyzw(x, y, z, w)),
        _ => Err(FrameDecodeError::Expected("[x, y, z, w]")),
    }
}

fn payload_of(header: &SampleHeader, body: &[u8]) -> Result<Payload, FrameDecodeError> {
    let data_type = DataType::from_name(&header.data_type);
    let value = || {
        header
            .value
            .as_ref()
            .ok_or_else(|| FrameDecodeError::NoValue(data_type.clone()))
    };
    let payload = match data_type {
        // A NaN went as null, which the header reads back as no value.
        DataType::F64 => Payload::F64(header.value.as_ref().map_or(Ok(f64::NAN), number)?),
        DataType::I64 => Payload::I64(
            value()?
                .as_i64()
                .ok_or(FrameDecodeError::ValueNot("an integer"))?,
        ),
        DataType::Bool => Payload::Bool(
            value()?
                .as_bool()
                .ok_or(FrameDecodeError::ValueNot("a boolean"))?,
        ),
        DataType::Vector => Payload::Vector(Arc::from(numbers(Some(value()?))?)),
        DataType::Matrix => {
            let value = value()?;
            let dimension = |name| {
                field(value, name)?
                    .as_u64()
                    .and_then(|n| usize::try_from(n).ok())
                    .ok_or(FrameDecodeError::NotACount(name))
            };
            let (rows, cols) = (dimension("rows")?, dimension("cols")?);
            let values = numbers(value.get("values"))?;
            if rows.checked_mul(cols) != Some(values.len()) {
                let values = values.len();
                return Err(FrameDecodeError::MatrixShape { rows, cols, values });
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        }
        DataType::Text => Payload::Text(Arc::from(
            value()?.as_str().ok_or(FrameDecodeError::ValueNot("text"))?,
        )),
        DataType::Imu => {
            let value = value()?;
            let orientation = match value.get("orientation") {
                None | Some(Json::Null) => None,
                some => Some(quaternion(some)?),
            };
            Payload::Imu(Imu {
                angular_velocity: vector3(value.get("angular_velocity"))?,
                linear_acceleration: vector3(value.get("linear_acceleration"))?,
                orientation,
            })
        }
        DataType::GnssFix => {
            let value = value()?;
            let status = match field(value, "status")?.as_str() {
                Some("no_fix") => FixStatus::NoFix,
                Some("fix") => FixStatus::Fix,
                Some("differential") => FixStatus::Differential,
                Some("rtk_fixed") => FixStatus::RtkFixed,
                _ => return Err(FrameDecodeError::UnknownFixStatusName),
            };
            Payload::GnssFix(GnssFix {
                latitude_deg: number(field(value, "latitude_deg")?)?,
                longitude_deg: number(field(value, "longitude_deg")?)?,
                altitude_m: number(field(value, "altitude_m")?)?,
                horizontal_accuracy_m: number(field(value, "horizontal_accuracy_m")?)?,
                vertical_accuracy_m: number(field(value, "vertical_accuracy_m")?)?,
                status,
            })
        }
        DataType::CanFrame => {
            let value = value()?;
            let id = field(value, "id")?
                .as_u64()
                .and_then(|id| u32::try_from(id).ok())
                .ok_or(FrameDecodeError::CanId)?;
            let data: Vec<u8> = field(value, "data")?
                .as_array()
                .ok_or(FrameDecodeError::CanDataNotArray)?
                .iter()
                .map(|byte| byte.as_u64().and_then(|b| u8::try_from(b).ok()))
                .collect::<Option<_>>()
                .ok_or(FrameDecodeError::CanDataNotBytes)?;
            let flag = |name: &str| value.get(name).and_then(Json::as_bool).unwrap_or(false);
            let extended = flag("extended");
            let mut frame = if flag("remote") {
                let length = value.get("length").and_then(Json::as_u64).unwrap_or(0);
                u8::try_from(length)
                    .ok()
                    .and_then(|length| CanFrame::remote_request(id, extended, length))
                    .ok_or(FrameDecodeError::RemoteRequestTooLong)?
            } else {
                CanFrame::new(id, extended, &data).ok_or(FrameDecodeError::CanFrameTooLong)?
            };
            frame.fd |= flag("fd");
            Payload::CanFrame(frame)
        }
        DataType::Pose => {
            let value = value()?;
            Payload::Pose(Pose {
                position: vector3(value.get("position"))?,
                orientation: quaternion(value.get("orientation"))?,
            })
        }
        DataType::Bytes => Payload::Bytes(Arc::from(body)),
        DataType::Image => image_of(header, std::iter::once(body))?,
        DataType::PointCloud => Payload::PointCloud(Arc::new(points_of(body, header.intensity)?)),
        DataType::Custom(name) => Payload::Custom(CustomPayload {
            type_name: Arc::from(name.as_str()),
            data: Arc::from(body),
        }),
    };
    Ok(payload)
}

/// Points from their bytes: x, y, z and, with `intensity`, a fourth f32, little-endian.
fn points_of(body: &[u8], intensity: bool) -> Result<PointCloud, FrameDecodeError> {
    let stride = if intensity { 16 } else { 12 };
    if !body.len().is_multiple_of(stride) {
        return Err(FrameDecodeError::PointsNotWhole {
            bytes: body.len(),
            stride,
        });
    }
    let float = |bytes: &[u8], at: usize| {
        bytes
            .get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .map_or(0.0, f32::from_le_bytes)
    };
    let points = body
        .chunks_exact(stride)
        .map(|p| Vec3::new(float(p, 0), float(p, 4), float(p, 8)))
        .collect();
    let intensity = intensity.then(|| body.chunks_exact(stride).map(|p| float(p, 12)).collect());
    Ok(PointCloud { points, intensity })
}

/// Counts what a stream of sequence numbers from one sender says about the link: samples lost in transit
/// (gaps), samples that arrived after a later one (reordered) and samples that came twice. A sender that
/// starts again (its sequence back at 0, or far behind) starts a new count.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct SequenceTracker {
    newest: Option<u64>,
    /// Bit `i`: whether `newest - i` was received, for the last 64 sequence numbers.
    seen: u64,
    /// Samples never received: the gaps between sequence numbers, less those that came late.
    pub lost: u64,
    /// Samples received after a later one (not passed on: the output's readers expect time order).
    pub reordered: u64,
    /// Samples received a second time.
    pub duplicates: u64,
    /// Times the sender started again.
    pub restarts: u64,
}

/// How far behind the newest a sequence number must be to mean that the sender started again rather than
/// that a sample was late.
const RESTART_DISTANCE: u64 = 1024;

impl SequenceTracker {
    /// Takes in `sequence`; whether the sample is new and in order, and goes on.
    pub fn take(&mut self, sequence: u64) -> bool {
        match self.newest {
            Some(newest) if sequence > newest => {
                let ahead = sequence - newest;
                self.lost += ahead - 1;
                self.seen = self
                    .seen
                    .checked_shl(u32::try_from(ahead).unwrap_or(u32::MAX))
                    .unwrap_or(0);
            }
            Some(newest) if sequence == 0 || newest - sequence >= RESTART_DISTANCE => {
                self.restarts += 1;
                self.seen = 0;
            }
            Some(newest) => {
                let behind = newest - sequence;
                let bit = 1_u64
                    .checked_shl(u32::try_from(behind).unwrap_or(u32::MAX))
                    .unwrap_or(0);
                if self.seen & bit != 0 {
                    self.duplicates += 1;
                } else {
                    // A late sample: it fills a gap counted as lost.
                    self.seen |= bit;
                    self.reordered += 1;
                    self.lost = self.lost.saturating_sub(1);
                }
                return false;
            }
            None => {}
        }
        self.newest = Some(sequence);
        self.seen |= 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::{DQuat, DVec3, Vec3};
    use kairos_sdk::{
        CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud,
        Pose, Sample, Timestamp,
    };

    use super::{SequenceTracker, decode, encode_json_whole, encode_whole};

    fn every_payload() -> Vec<Payload> {
        let pixels: Vec<u8> = (0..4 * 3 * 3).map(|i| i as u8).collect();
        vec![
            Payload::F64(-1.5),
            Payload::I64(i64::MIN),
            Payload::Bool(true),
            Payload::Vector(Arc::from(vec![1.0, 2.5])),
            Payload::Matrix(Arc::new(Matrix {
                rows: 2,
                cols: 1,
                values: vec![3.0, 4.0],
            })),
            Payload::Text(Arc::from("héllo")),
            Payload::Bytes(Arc::from(&[0_u8, 255, 7][..])),
            Payload::Imu(Imu {
                angular_velocity: DVec3::new(0.1, 0.2, 0.3),
                linear_acceleration: DVec3::new(0.0, 0.0, 9.81),
                orientation: Some(DQuat::IDENTITY),
            }),
            Payload::GnssFix(GnssFix {
                latitude_deg: 48.8,
                longitude_deg: 2.3,
                altitude_m: 35.0,
                horizontal_accuracy_m: 1.5,
                vertical_accuracy_m: 3.0,
                status: FixStatus::RtkFixed,
            }),
            Payload::CanFrame(CanFrame::new(0x18FF_0001, true, &[1, 2, 3]).unwrap()),
            Payload::CanFrame(CanFrame::remote_request(0x123, false, 5).unwrap()),
            Payload::Pose(Pose {
                position: DVec3::new(1.0, 2.0, 3.0),
                orientation: DQuat::from_rotation_z(0.5),
            }),
            // Rows of 12 bytes with a stride of 12; the pixels keep their layout.
            Payload::Image(Image::packed(4, 3, PixelFormat::Bgr8, Arc::<[u8]>::from(pixels)).unwrap()),
            Payload::PointCloud(Arc::new(PointCloud {
                points: vec![Vec3::new(1.0, -2.0, 0.5), Vec3::ZERO],
                intensity: Some(vec![0.25, 1.0]),
            })),
            Payload::Custom(CustomPayload {
                type_name: Arc::from("radar_track"),
                data: Arc::from(&b"track"[..]),
            }),
        ]
    }

    /// One layout's whole frame of a sample.
    type Encoder = fn(&str, &Sample) -> Vec<u8>;

    /// Both layouts' whole frames.
    const ENCODERS: [(&str, Encoder); 2] = [("binary", encode_whole), ("protocol", encode_json_whole)];

    #[test]
    fn a_frame_in_pieces_decodes_as_the_whole_frame_does() {
        for (layout, encode) in ENCODERS {
            for payload in every_payload() {
                let mut sample = Sample::new(payload.clone(), Timestamp(1_700_000_000_123_456_789));
                sample.time_of_issue = Timestamp(1_700_000_000_223_456_789);
                let frame = encode("camera.image", &sample);
                let whole = decode(&frame).unwrap();
                // Cut everywhere: inside the header, and inside the payload.
                for cut in [5, frame.len() - 7, frame.len() - 1] {
                    let (a, b) = frame.split_at(cut);
                    let (b, c) = b.split_at(b.len() / 2);
                    let pieces = super::decode_pieces(&[a, b, c]).unwrap();
                    assert_eq!(pieces.output, whole.output);
                    assert_eq!(
                        pieces.sample.payload, whole.sample.payload,
                        "{layout}: {payload:?}, cut at {cut}"
                    );
                    assert_eq!(pieces.sample.timestamp, whole.sample.timestamp);
                    assert_eq!(pieces.sample.time_of_issue, whole.sample.time_of_issue);
                }
            }
        }
    }

    #[test]
    fn every_payload_type_comes_back_whole_with_both_times_and_its_sequence() {
        for (layout, encode) in ENCODERS {
            for payload in every_payload() {
                let mut sample = Sample::new(payload.clone(), Timestamp(1_700_000_000_123_456_789));
                sample.time_of_issue = Timestamp(1_700_000_000_200_000_000);
                sample.sequence = 41;
                let received = decode(&encode("sensor.out", &sample)).unwrap();
                assert_eq!(received.sample.payload, payload, "{layout}");
                assert_eq!(received.sample.timestamp, sample.timestamp);
                assert_eq!(received.sample.time_of_issue, sample.time_of_issue);
                assert_eq!((received.output.as_str(), received.sequence), ("sensor.out", 41));
            }
        }
    }

    #[test]
    fn a_binary_frame_cut_short_is_refused_never_read_past_its_end() {
        for payload in every_payload() {
            let sample = Sample::new(payload.clone(), Timestamp(1));
            let frame = encode_whole("imu.out", &sample);
            assert!(frame.starts_with(super::binary::MAGIC), "{payload:?}");
            // Short of the fixed start (kind, name, times, sequence), any payload is refused.
            for end in 4..4 + 1 + 2 + "imu.out".len() + 24 {
                assert!(decode(&frame[..end]).is_err(), "{payload:?} cut at {end}");
            }
            // A payload of fixed size is refused short of any of its bytes. (Those that end with the frame,
            // as bytes do, are whole frames in every transport: a datagram, a length-prefixed message.)
            let fixed = matches!(
                payload,
                Payload::F64(_)
                    | Payload::I64(_)
                    | Payload::Bool(_)
                    | Payload::Imu(_)
                    | Payload::GnssFix(_)
                    | Payload::Pose(_)
                    | Payload::Matrix(_)
                    | Payload::Image(_)
            );
            if fixed {
                for end in 4..frame.len() {
                    assert!(decode(&frame[..end]).is_err(), "{payload:?} cut at {end}");
                }
            }
        }
    }

    #[test]
    fn a_binary_frame_of_a_kind_this_version_does_not_know_is_refused_by_number() {
        let mut frame = encode_whole("a.b", &Sample::new(Payload::F64(1.0), Timestamp(1)));
        frame[4] = 200;
        let error = decode(&frame).unwrap_err();
        assert!(
            matches!(error, crate::FrameDecodeError::UnknownKind(200)),
            "{error:?}"
        );
        let said = error.to_string();
        assert!(said.contains("kind 200") && said.contains("newer"), "{said}");
    }

    #[test]
    fn a_small_sample_s_binary_frame_is_a_fraction_of_its_protocol_frame() {
        let imu = every_payload().swap_remove(7);
        let sample = Sample::new(imu, Timestamp(1_700_000_000_123_456_789));
        let (binary, json) = (
            encode_whole("imu.imu", &sample).len(),
            encode_json_whole("imu.imu", &sample).len(),
        );
        // 4 + 1 + 2 + 7 + 24, then 6 f64s, a flag and 4 f64s.
        assert_eq!(binary, 38 + 48 + 1 + 32);
        assert!(binary * 2 < json, "{binary} B binary, {json} B JSON");
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_decode_or_are_refused_never_a_panic(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..512)) {
            let _ = decode(&bytes);
            for magic in [b"KSF1", b"KSB1"] {
                let mut framed = magic.to_vec();
                framed.extend_from_slice(&bytes);
                let _ = decode(&framed);
                let _ = super::decode_pieces(&[&framed[..framed.len() / 2], &framed[framed.len() / 2..]]);
            }
        }

        #[test]
        fn numbers_text_and_bytes_come_back_exactly(
            values in proptest::collection::vec(-1e300_f64..1e300, 0..32),
            text in ".{0,64}",
            bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..256),
            timestamp in proptest::num::i64::ANY,
            sequence in proptest::num::u64::ANY,
        ) {
            for (_, encode) in ENCODERS {
                for payload in [
                    Payload::Vector(Arc::from(values.clone())),
                    Payload::Text(Arc::from(text.as_str())),
                    Payload::Bytes(Arc::from(bytes.clone())),
                ] {
                    let mut sample = Sample::new(payload.clone(), Timestamp(timestamp));
                    sample.sequence = sequence;
                    let received = decode(&encode("a.b", &sample)).unwrap();
                    proptest::prop_assert_eq!(received.sample.payload, payload);
                    proptest::prop_assert_eq!(received.sample.timestamp, Timestamp(timestamp));
                    proptest::prop_assert_eq!(received.sequence, sequence);
                }
            }
        }
    }

    #[test]
    fn a_nan_travels_as_a_nan() {
        for (_, encode) in ENCODERS {
            let sample = Sample::new(Payload::F64(f64::NAN), Timestamp(1));
            let received = decode(&encode("a.b", &sample)).unwrap();
            assert!(matches!(received.sample.payload, Payload::F64(v) if v.is_nan()));
        }
    }

    #[test]
    fn damaged_frames_are_refused_with_the_reason() {
        let sample = Sample::new(Payload::Vector(Arc::from(vec![1.0])), Timestamp(1));
        for (_, encode) in ENCODERS {
            let bytes = encode("a.b", &sample);
            assert!(decode(&bytes[..bytes.len() - 3]).is_err());
            let image = every_payload()
                .into_iter()
                .find(|p| matches!(p, Payload::Image(_)))
                .unwrap();
            let image = Sample::new(image, Timestamp(1));
            let bytes = encode("camera.image", &image);
            let error = decode(&bytes[..bytes.len() - 1]).unwrap_err().to_string();
            assert!(error.contains("buffer") || error.contains("bytes"), "{error}");
        }
        assert!(decode(b"garbage").unwrap_err().to_string().contains("KSF1"));
    }

    #[test]
    fn gaps_count_as_lost_and_late_samples_as_reordered() {
        let mut tracker = SequenceTracker::default();
        let taken: Vec<bool> = [0, 1, 4, 3, 5, 5].iter().map(|s| tracker.take(*s)).collect();
        assert_eq!(taken, [true, true, true, false, true, false]);
        // 2 and 3 went missing, then 3 came late; 5 came twice.
        assert_eq!((tracker.lost, tracker.reordered, tracker.duplicates), (1, 1, 1));
        assert!(tracker.take(0));
        assert_eq!(tracker.restarts, 1);
    }
}

//! The binary sample frame (`KSB1`) between Kairos runtimes: a fixed header then the payload in its own
//! layout, with no text to build or parse. Little-endian throughout:
//!
//! | bytes | field |
//! | --- | --- |
//! | 4 | `KSB1` (the layout's version is its last character) |
//! | 1 | the payload's kind ([`Kind`]) |
//! | 2 + n | the output's name: its length (u16), then UTF-8 |
//! | 8, 8, 8 | timestamp (i64 ns), time of issue (i64 ns), sequence number (u64) |
//! | rest | the payload, by kind (below) |
//!
//! Payloads: f64 and i64 as 8 bytes; a boolean as one byte; text and bytes as the rest of the frame; a
//! vector as f64s; a matrix as rows and columns (u32 each) then its f64s by rows; an IMU sample as angular
//! velocity and linear acceleration (3 f64 each), then one byte saying whether an orientation (x, y, z, w
//! as f64) follows; a GNSS fix as latitude, longitude, altitude and both accuracies (f64) then its status
//! (one byte: no fix, fix, differential, RTK fixed); a CAN frame as its id (u32), one byte of flags
//! (1: extended id, 2: CAN FD, 4: remote request) and its data (a remote request: the one byte of the
//! length it asks for); a pose as position (3 f64) and orientation (x, y, z, w); an
//! image as width, height and stride (u32 each), its pixel format (one byte: its place in `PixelFormat::ALL`)
//! and its pixels; a point cloud as one byte saying whether each point has an intensity, then x, y, z (and
//! intensity) as f32; a pack-defined payload as its type's name (u16 length, UTF-8) then its bytes.

use std::borrow::Cow;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use kairos_sdk::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Imu, Matrix, Payload, PixelFormat, Pose, Sample, Timestamp,
};

use crate::{FrameDecodeError, Received, image_of_pieces, point_bytes, points_of};

/// The first bytes of a binary frame.
pub const MAGIC: &[u8; 4] = b"KSB1";

/// The bulk a frame's start makes room for: a transport copies a payload this small after the start.
const JOINED_UP_TO: usize = 4096;

/// The payload's kind, the byte after the magic. New kinds are only ever added: a frame of a kind a peer
/// does not know is refused by it with the kind's number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    F64 = 0,
    I64 = 1,
    Bool = 2,
    Text = 3,
    Bytes = 4,
    Vector = 5,
    Matrix = 6,
    Imu = 7,
    GnssFix = 8,
    CanFrame = 9,
    Pose = 10,
    Image = 11,
    PointCloud = 12,
    Custom = 13,
}

impl Kind {
    const ALL: [Kind; 14] = [
        Kind::F64,
        Kind::I64,
        Kind::Bool,
        Kind::Text,
        Kind::Bytes,
        Kind::Vector,
        Kind::Matrix,
        Kind::Imu,
        Kind::GnssFix,
        Kind::CanFrame,
        Kind::Pose,
        Kind::Image,
        Kind::PointCloud,
        Kind::Custom,
    ];

    fn of(byte: u8) -> Option<Kind> {
        Kind::ALL.get(usize::from(byte)).copied()
    }
}

/// The bytes of a frame's start, written field by field.
struct Head(Vec<u8>);

impl Head {
    fn f64s(&mut self, values: &[f64]) {
        for value in values {
            self.0.extend_from_slice(&value.to_le_bytes());
        }
    }

    fn u32(&mut self, value: usize) -> Option<()> {
        self.0
            .extend_from_slice(&u32::try_from(value).ok()?.to_le_bytes());
        Some(())
    }

    fn name(&mut self, name: &str) -> Option<()> {
        self.0
            .extend_from_slice(&u16::try_from(name.len()).ok()?.to_le_bytes());
        self.0.extend_from_slice(name.as_bytes());
        Some(())
    }
}

fn xyz(v: DVec3) -> [f64; 3] {
    v.to_array()
}

fn xyzw(q: DQuat) -> [f64; 4] {
    [q.x, q.y, q.z, q.w]
}

/// `sample` as a binary frame in two parts: its start (everything up to the payload's bulk) and the bulk,
/// borrowed where the payload holds it (pixels, bytes, text), so a transport copies it once, where it goes.
/// `None` only for what the layout cannot hold (a name over 64 KiB, a matrix side over 4 G).
pub fn encode<'s>(output: &str, sample: &'s Sample) -> Option<(Vec<u8>, Cow<'s, [u8]>)> {
    let payload = &sample.payload;
    // Room for a small payload's bulk too: a transport joins it to the start rather than send two slices.
    let mut head = Head(Vec::with_capacity(
        80 + output.len() + payload.heavy_size_bytes().min(JOINED_UP_TO),
    ));
    head.0.extend_from_slice(MAGIC);
    head.0.push(kind_of(payload)? as u8);
    head.name(output)?;
    head.0
        .extend_from_slice(&sample.timestamp.as_nanos().to_le_bytes());
    head.0
        .extend_from_slice(&sample.time_of_issue.as_nanos().to_le_bytes());
    head.0.extend_from_slice(&sample.sequence.to_le_bytes());
    let body: Cow<'s, [u8]> = match payload {
        Payload::F64(value) => {
            head.f64s(&[*value]);
            Cow::Borrowed(&[])
        }
        Payload::I64(value) => {
            head.0.extend_from_slice(&value.to_le_bytes());
            Cow::Borrowed(&[])
        }
        Payload::Bool(value) => {
            head.0.push(u8::from(*value));
            Cow::Borrowed(&[])
        }
        Payload::Text(text) => Cow::Borrowed(text.as_bytes()),
        Payload::Bytes(bytes) => Cow::Borrowed(bytes),
        Payload::Vector(values) => {
            head.f64s(values);
            Cow::Borrowed(&[])
        }
        Payload::Matrix(matrix) => {
            head.u32(matrix.rows)?;
            head.u32(matrix.cols)?;
            head.f64s(&matrix.values);
            Cow::Borrowed(&[])
        }
        Payload::Imu(imu) => {
            head.f64s(&xyz(imu.angular_velocity));
            head.f64s(&xyz(imu.linear_acceleration));
            head.0.push(u8::from(imu.orientation.is_some()));
            if let Some(orientation) = imu.orientation {
                head.f64s(&xyzw(orientation));
            }
            Cow::Borrowed(&[])
        }
        Payload::GnssFix(fix) => {
            head.f64s(&[
                fix.latitude_deg,
                fix.longitude_deg,
                fix.altitude_m,
                fix.horizontal_accuracy_m,
                fix.vertical_accuracy_m,
            ]);
            let status = FixStatus::ALL.iter().position(|s| *s == fix.status).unwrap_or(0);
            head.0.push(u8::try_from(status).unwrap_or(0));
            Cow::Borrowed(&[])
        }
        Payload::CanFrame(frame) => {
            head.0.extend_from_slice(&frame.id.to_le_bytes());
            head.0
                .push(u8::from(frame.extended) | (u8::from(frame.fd) << 1) | (u8::from(frame.remote) << 2));
            if frame.remote {
                head.0.push(frame.length());
            }
            head.0.extend_from_slice(frame.data());
            Cow::Borrowed(&[])
        }
        Payload::Pose(pose) => {
            head.f64s(&xyz(pose.position));
            head.f64s(&xyzw(pose.orientation));
            Cow::Borrowed(&[])
        }
        Payload::Image(image) => {
            for side in [image.width, image.height, image.stride] {
                head.0.extend_from_slice(&side.to_le_bytes());
            }
            let format = PixelFormat::ALL
                .iter()
                .position(|f| *f == image.format)
                .unwrap_or(0);
            head.0.push(u8::try_from(format).unwrap_or(0));
            Cow::Borrowed(&image.pixels)
        }
        Payload::PointCloud(cloud) => {
            head.0.push(u8::from(cloud.intensity.is_some()));
            Cow::Owned(point_bytes(cloud))
        }
        Payload::Custom(custom) => {
            head.name(&custom.type_name)?;
            Cow::Borrowed(&custom.data)
        }
        _ => return None,
    };
    Some((head.0, body))
}

/// The payload's kind; `None` for a payload added to the SDK after this layout (sent as the protocol's
/// frame until it has a kind).
fn kind_of(payload: &Payload) -> Option<Kind> {
    Some(match payload {
        Payload::F64(_) => Kind::F64,
        Payload::I64(_) => Kind::I64,
        Payload::Bool(_) => Kind::Bool,
        Payload::Text(_) => Kind::Text,
        Payload::Bytes(_) => Kind::Bytes,
        Payload::Vector(_) => Kind::Vector,
        Payload::Matrix(_) => Kind::Matrix,
        Payload::Imu(_) => Kind::Imu,
        Payload::GnssFix(_) => Kind::GnssFix,
        Payload::CanFrame(_) => Kind::CanFrame,
        Payload::Pose(_) => Kind::Pose,
        Payload::Image(_) => Kind::Image,
        Payload::PointCloud(_) => Kind::PointCloud,
        Payload::Custom(_) => Kind::Custom,
        _ => return None,
    })
}

/// A frame's bytes, read field by field; every read says what was short.
struct Fields<'b>(&'b [u8]);

impl<'b> Fields<'b> {
    fn take<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], FrameDecodeError> {
        let (field, rest) = self
            .0
            .split_first_chunk::<N>()
            .ok_or(FrameDecodeError::EndsBefore(what))?;
        self.0 = rest;
        Ok(*field)
    }

    fn u8(&mut self, what: &'static str) -> Result<u8, FrameDecodeError> {
        Ok(self.take::<1>(what)?[0])
    }

    fn u32(&mut self, what: &'static str) -> Result<usize, FrameDecodeError> {
        usize::try_from(u32::from_le_bytes(self.take(what)?)).map_err(|_| FrameDecodeError::TooLarge(what))
    }

    fn i64(&mut self, what: &'static str) -> Result<i64, FrameDecodeError> {
        Ok(i64::from_le_bytes(self.take(what)?))
    }

    fn f64(&mut self, what: &'static str) -> Result<f64, FrameDecodeError> {
        Ok(f64::from_le_bytes(self.take(what)?))
    }

    fn f64s<const N: usize>(&mut self, what: &'static str) -> Result<[f64; N], FrameDecodeError> {
        let mut values = [0.0; N];
        for value in &mut values {
            *value = self.f64(what)?;
        }
        Ok(values)
    }

    fn name(&mut self, what: &'static str) -> Result<&'b str, FrameDecodeError> {
        let length = usize::from(u16::from_le_bytes(self.take(what)?));
        let (name, rest) = self
            .0
            .split_at_checked(length)
            .ok_or(FrameDecodeError::EndsInside(what))?;
        self.0 = rest;
        std::str::from_utf8(name).map_err(|_| FrameDecodeError::NameNotUtf8(what))
    }

    /// What is left, all of it the payload's: f64s.
    fn rest_f64s(&self, what: &'static str) -> Result<Vec<f64>, FrameDecodeError> {
        if !self.0.len().is_multiple_of(8) {
            return Err(FrameDecodeError::NotWholeF64s {
                bytes: self.0.len(),
                what,
            });
        }
        Ok(self
            .0
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap_or_default()))
            .collect())
    }
}

/// A frame's start: everything before the payload, and the payload's kind.
struct Start<'b> {
    kind: Kind,
    output: &'b str,
    timestamp: i64,
    time_of_issue: i64,
    sequence: u64,
}

fn start<'b>(fields: &mut Fields<'b>) -> Result<Start<'b>, FrameDecodeError> {
    let kind = fields.u8("kind")?;
    let kind = Kind::of(kind).ok_or(FrameDecodeError::UnknownKind(kind))?;
    Ok(Start {
        kind,
        output: fields.name("output name")?,
        timestamp: fields.i64("timestamp")?,
        time_of_issue: fields.i64("time of issue")?,
        sequence: u64::from_le_bytes(fields.take("sequence number")?),
    })
}

fn received(start: &Start<'_>, payload: Payload) -> Received {
    let mut sample = Sample::new(payload, Timestamp(start.timestamp));
    sample.time_of_issue = Timestamp(start.time_of_issue);
    Received {
        output: start.output.to_owned(),
        sequence: start.sequence,
        sample,
    }
}

/// Reads a binary frame, its magic already taken off.
pub(crate) fn decode(bytes: &[u8]) -> Result<Received, FrameDecodeError> {
    let mut fields = Fields(bytes);
    let start = start(&mut fields)?;
    let payload = match start.kind {
        Kind::F64 => Payload::F64(fields.f64("value")?),
        Kind::I64 => Payload::I64(fields.i64("value")?),
        Kind::Bool => Payload::Bool(fields.u8("value")? != 0),
        Kind::Text => Payload::Text(Arc::from(
            std::str::from_utf8(fields.0).map_err(|_| FrameDecodeError::TextNotUtf8)?,
        )),
        Kind::Bytes => Payload::Bytes(Arc::from(fields.0)),
        Kind::Vector => Payload::Vector(Arc::from(fields.rest_f64s("vector")?)),
        Kind::Matrix => {
            let (rows, cols) = (fields.u32("row count")?, fields.u32("column count")?);
            let values = fields.rest_f64s("matrix")?;
            if rows.checked_mul(cols) != Some(values.len()) {
                let values = values.len();
                return Err(FrameDecodeError::MatrixShape { rows, cols, values });
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        }
        Kind::Imu => {
            let [wx, wy, wz] = fields.f64s("angular velocity")?;
            let [ax, ay, az] = fields.f64s("linear acceleration")?;
            let orientation = if fields.u8("orientation flag")? == 0 {
                None
            } else {
                let [x, y, z, w] = fields.f64s("orientation")?;
                Some(DQuat::from_xyzw(x, y, z, w))
            };
            Payload::Imu(Imu {
                angular_velocity: DVec3::new(wx, wy, wz),
                linear_acceleration: DVec3::new(ax, ay, az),
                orientation,
            })
        }
        Kind::GnssFix => {
            let [
                latitude_deg,
                longitude_deg,
                altitude_m,
                horizontal_accuracy_m,
                vertical_accuracy_m,
            ] = fields.f64s("fix")?;
            let status = fields.u8("fix status")?;
            let status = *FixStatus::ALL
                .get(usize::from(status))
                .ok_or(FrameDecodeError::UnknownFixStatus(status))?;
            Payload::GnssFix(GnssFix {
                latitude_deg,
                longitude_deg,
                altitude_m,
                horizontal_accuracy_m,
                vertical_accuracy_m,
                status,
            })
        }
        Kind::CanFrame => {
            let id = u32::from_le_bytes(fields.take("CAN id")?);
            let flags = fields.u8("CAN flags")?;
            let extended = flags & 1 != 0;
            let mut frame = if flags & 4 != 0 {
                let length = fields.u8("a remote request's length")?;
                CanFrame::remote_request(id, extended, length)
                    .ok_or(FrameDecodeError::RemoteRequestTooLong)?
            } else {
                CanFrame::new(id, extended, fields.0).ok_or(FrameDecodeError::CanFrameTooLong)?
            };
            frame.fd |= flags & 2 != 0;
            Payload::CanFrame(frame)
        }
        Kind::Pose => {
            let [x, y, z] = fields.f64s("position")?;
            let [qx, qy, qz, qw] = fields.f64s("orientation")?;
            Payload::Pose(Pose {
                position: DVec3::new(x, y, z),
                orientation: DQuat::from_xyzw(qx, qy, qz, qw),
            })
        }
        Kind::Image => {
            let layout = image_layout(&mut fields)?;
            image_of_pieces(layout, std::iter::once(fields.0))?
        }
        Kind::PointCloud => {
            let intensity = fields.u8("intensity flag")? != 0;
            Payload::PointCloud(Arc::new(points_of(fields.0, intensity)?))
        }
        Kind::Custom => Payload::Custom(CustomPayload {
            type_name: Arc::from(fields.name("type name")?),
            data: Arc::from(fields.0),
        }),
    };
    Ok(received(&start, payload))
}

/// An image's width, height, stride and format.
pub(crate) type ImageLayout = (u32, u32, u32, PixelFormat);

fn image_layout(fields: &mut Fields<'_>) -> Result<ImageLayout, FrameDecodeError> {
    let (width, height, stride) = (
        u32::from_le_bytes(fields.take("image width")?),
        u32::from_le_bytes(fields.take("image height")?),
        u32::from_le_bytes(fields.take("image stride")?),
    );
    let format = fields.u8("pixel format")?;
    let format = *PixelFormat::ALL
        .get(usize::from(format))
        .ok_or(FrameDecodeError::UnknownPixelFormat(format))?;
    Ok((width, height, stride, format))
}

/// An image frame in pieces whose start lies whole in the first: its pixels copied from the pieces straight
/// into the shared pixel pool. `None` for any other frame.
pub(crate) fn decode_image_pieces(
    first: &[u8],
    rest: &[&[u8]],
) -> Option<Result<Received, FrameDecodeError>> {
    let mut fields = Fields(first.strip_prefix(MAGIC)?);
    let start = start(&mut fields).ok()?;
    if start.kind != Kind::Image {
        return None;
    }
    let layout = image_layout(&mut fields).ok()?;
    let pixels = std::iter::once(fields.0).chain(rest.iter().copied());
    Some(image_of_pieces(layout, pixels).map(|payload| received(&start, payload)))
}

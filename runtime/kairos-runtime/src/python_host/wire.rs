//! The worker protocol's bytes on the runtime's side (docs/python.md; `kairos_sdk/wire.py` is the other
//! side): frames on a Unix socket, payloads as a tag and little-endian fields.

use std::io::{self, BufReader, Read as _, Write as _};
use std::os::fd::AsFd as _;
use std::os::unix::net::UnixStream;
use std::time::Duration;

use glam::{DQuat, DVec3, Vec3};
use kairos_sdk_core::{CanFrame, FixStatus, GnssFix, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose};

pub const PROTOCOL_VERSION: u32 = 1;

/// Frames larger than this are refused: a worker gone wrong must not make the runtime allocate without bound.
const MAX_FRAME: usize = 1 << 30;

/// How long the runtime's thread yields, rather than sleeps, for the worker's next frame: the worker
/// answers a sample in tens of microseconds, and sleeping adds a wake-up of this thread to the hop
/// (benchmark 19: the unpinned integer hop's p50 92 µs rather than 101, p99 161 rather than 196, for 2
/// more points of a core at 1 kHz). At most this much CPU per frame awaited when the worker takes longer.
const ANSWER_SPIN: Duration = Duration::from_micros(100);

/// Where an image's pixels travel.
pub const PIXELS_INLINE: u8 = 0;
pub const PIXELS_SHARED: u8 = 1;
pub const PIXELS_HELD: u8 = 2;

/// The runtime's end of a worker's socket.
#[derive(Debug)]
pub struct Connection {
    reader: BufReader<UnixStream>,
    writer: UnixStream,
    out: Vec<u8>,
    /// How long a wait for the worker yields before it sleeps: [`ANSWER_SPIN`], or nothing when the
    /// calling thread is pinned to one CPU, which the worker then shares (its process inherits the
    /// thread's affinity): yielding there only takes the CPU from the worker it waits for.
    answer_spin: Duration,
}

impl Connection {
    /// A connection over `stream`, made on the component's thread, after its affinity is set.
    pub fn new(stream: UnixStream) -> io::Result<Self> {
        let cpus = nix::sched::sched_getaffinity(nix::unistd::Pid::from_raw(0)).map_or(usize::MAX, |set| {
            (0..nix::sched::CpuSet::count())
                .filter(|&cpu| set.is_set(cpu).unwrap_or(false))
                .count()
        });
        Ok(Connection {
            reader: BufReader::with_capacity(1 << 16, stream.try_clone()?),
            writer: stream,
            out: Vec::with_capacity(1 << 12),
            answer_spin: if cpus > 1 { ANSWER_SPIN } else { Duration::ZERO },
        })
    }

    /// Starts a frame of `kind`; the body is appended to the returned buffer and the length patched by
    /// [`Connection::end_frame`].
    pub fn begin_frame(&mut self, kind: u8) -> usize {
        let start = self.out.len();
        self.out.extend_from_slice(&[0, 0, 0, 0, kind]);
        start
    }

    pub fn body(&mut self) -> &mut Vec<u8> {
        &mut self.out
    }

    pub fn end_frame(&mut self, start: usize) {
        let length = (self.out.len() - start - 4) as u32;
        if let Some(field) = self.out.get_mut(start..start + 4) {
            field.copy_from_slice(&length.to_le_bytes());
        }
    }

    /// A whole frame at once.
    pub fn send(&mut self, kind: u8, body: &[u8]) {
        let start = self.begin_frame(kind);
        self.out.extend_from_slice(body);
        self.end_frame(start);
    }

    pub fn flush(&mut self) -> io::Result<()> {
        if !self.out.is_empty() {
            self.writer.write_all(&self.out)?;
            self.out.clear();
        }
        Ok(())
    }

    /// Whether a frame can be read now, waiting at most `timeout` for one to start arriving. The first
    /// [`ANSWER_SPIN`] of the wait yields instead of sleeping, unless the thread is pinned to one CPU.
    pub fn readable(&mut self, timeout: Duration) -> io::Result<bool> {
        if !self.reader.buffer().is_empty() {
            return Ok(true);
        }
        let mut fds = [nix::poll::PollFd::new(
            self.reader.get_ref().as_fd(),
            nix::poll::PollFlags::POLLIN,
        )];
        let spinning = std::time::Instant::now();
        while spinning.elapsed() < self.answer_spin {
            match nix::poll::poll(&mut fds, nix::poll::PollTimeout::ZERO) {
                Ok(0) | Err(nix::errno::Errno::EINTR) => std::thread::yield_now(),
                Ok(_) => return Ok(true),
                Err(error) => return Err(io::Error::from(error)),
            }
        }
        let millis = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
        match nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(millis)) {
            Ok(ready) => Ok(ready > 0),
            Err(nix::errno::Errno::EINTR) => Ok(false),
            Err(error) => Err(io::Error::from(error)),
        }
    }

    /// Reads one frame into `body`; its kind. `UnexpectedEof` when the worker closed the socket (it ended).
    pub fn read_frame(&mut self, body: &mut Vec<u8>) -> io::Result<u8> {
        let mut head = [0_u8; 5];
        self.reader.read_exact(&mut head)?;
        let [a, b, c, d, kind] = head;
        let length = u32::from_le_bytes([a, b, c, d]) as usize;
        if length == 0 || length > MAX_FRAME {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!("a frame of {length} bytes"),
            ));
        }
        body.clear();
        body.resize(length - 1, 0);
        self.reader.read_exact(body)?;
        Ok(kind)
    }
}

/// Why a worker's frame is not one the worker protocol allows: the worker broke the protocol, and its
/// component fails naming what was malformed.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    /// The frame ended before the field being read.
    #[error("the worker's frame ends inside {0}")]
    EndsInside(&'static str),
    /// A count of values whose bytes overflow the address space.
    #[error("too many values")]
    TooManyValues,
    /// A matrix whose rows × columns overflow.
    #[error("a matrix too large")]
    MatrixTooLarge,
    /// Text fields must be UTF-8.
    #[error("{0} that is not UTF-8")]
    NotUtf8(&'static str),
    /// A payload tag this runtime does not know.
    #[error("an unknown payload tag {0}")]
    UnknownPayloadTag(u8),
    /// A fix status beyond [`FixStatus::ALL`].
    #[error("an unknown fix status")]
    UnknownFixStatus,
    /// A pixel format beyond [`PixelFormat::ALL`].
    #[error("an unknown pixel format")]
    UnknownPixelFormat,
    /// An image's pixels in none of the places [`PIXELS_INLINE`], [`PIXELS_SHARED`], [`PIXELS_HELD`].
    #[error("pixels in an unknown place {0}")]
    UnknownPixelPlace(u8),
    /// A remote request cannot ask for more than a classic frame holds.
    #[error("a remote request for more than 8 bytes")]
    RemoteRequestTooLong,
    /// A CAN FD frame holds 64 bytes at most.
    #[error("a CAN frame of more than 64 bytes")]
    CanFrameTooLong,
    /// A request kind this runtime does not know.
    #[error("an unknown request '{}'", char::from(*.0))]
    UnknownRequest(u8),
    /// A status the worker published that is not JSON.
    #[error("a status that is not JSON: {0}")]
    StatusNotJson(#[source] serde_json::Error),
}

/// Reads fields off a frame's body in order; a frame that ends early is an error naming what was read.
#[derive(Debug)]
pub struct Fields<'a> {
    data: &'a [u8],
}

impl<'a> Fields<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Fields { data }
    }

    pub fn bytes(&mut self, count: usize, what: &'static str) -> Result<&'a [u8], WireError> {
        if self.data.len() < count {
            return Err(WireError::EndsInside(what));
        }
        let (head, rest) = self.data.split_at(count);
        self.data = rest;
        Ok(head)
    }

    fn array<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], WireError> {
        let bytes = self.bytes(N, what)?;
        let mut array = [0_u8; N];
        array.copy_from_slice(bytes);
        Ok(array)
    }

    pub fn u8(&mut self, what: &'static str) -> Result<u8, WireError> {
        Ok(self.array::<1>(what)?[0])
    }

    pub fn u16(&mut self, what: &'static str) -> Result<u16, WireError> {
        Ok(u16::from_le_bytes(self.array(what)?))
    }

    pub fn u32(&mut self, what: &'static str) -> Result<u32, WireError> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    pub fn u64(&mut self, what: &'static str) -> Result<u64, WireError> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    pub fn i64(&mut self, what: &'static str) -> Result<i64, WireError> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }

    pub fn f64(&mut self, what: &'static str) -> Result<f64, WireError> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    fn f32(&mut self, what: &'static str) -> Result<f32, WireError> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    fn sized(&mut self, what: &'static str) -> Result<&'a [u8], WireError> {
        let length = self.u32(what)? as usize;
        self.bytes(length, what)
    }

    fn dvec3(&mut self, what: &'static str) -> Result<DVec3, WireError> {
        Ok(DVec3::new(self.f64(what)?, self.f64(what)?, self.f64(what)?))
    }

    fn floats(&mut self, count: usize, what: &'static str) -> Result<Vec<f64>, WireError> {
        let bytes = self.bytes(count.checked_mul(8).ok_or(WireError::TooManyValues)?, what)?;
        Ok(bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or_default()))
            .collect())
    }
}

/// An image as a write names it: its geometry, and where its pixels are.
#[derive(Debug)]
pub struct ImageFields<'a> {
    pub width: u32,
    pub height: u32,
    pub stride: u32,
    pub format: PixelFormat,
    pub pixels: ImagePixels<'a>,
}

#[derive(Debug)]
pub enum ImagePixels<'a> {
    /// Copied in the frame.
    Inline(&'a [u8]),
    /// A buffer the runtime allocated for the worker (`copied`: the worker copied them there).
    Allocated { handle: u64, copied: bool },
    /// An input's pixels the runtime holds for the worker.
    Held(u64),
}

/// A payload a worker wrote: everything but images decoded whole; an image's pixels to be found by the caller.
#[derive(Debug)]
pub enum Written<'a> {
    Payload(Payload),
    Image(ImageFields<'a>),
}

/// Decodes a payload of a write.
pub fn decode_payload<'a>(fields: &mut Fields<'a>) -> Result<Written<'a>, WireError> {
    let tag = fields.u8("the payload's tag")?;
    let payload = match tag {
        0 => Payload::F64(fields.f64("a float")?),
        1 => Payload::I64(fields.i64("an integer")?),
        2 => Payload::Bool(fields.u8("a boolean")? != 0),
        3 => {
            let text = std::str::from_utf8(fields.sized("text")?).map_err(|_| WireError::NotUtf8("text"))?;
            Payload::Text(text.into())
        }
        4 => Payload::Bytes(fields.sized("bytes")?.into()),
        5 => {
            let count = fields.u32("a vector's length")? as usize;
            Payload::Vector(fields.floats(count, "a vector")?.into())
        }
        6 => {
            let rows = fields.u32("a matrix's rows")? as usize;
            let cols = fields.u32("a matrix's columns")? as usize;
            let values = fields.floats(
                rows.checked_mul(cols).ok_or(WireError::MatrixTooLarge)?,
                "a matrix",
            )?;
            Payload::Matrix(std::sync::Arc::new(Matrix { rows, cols, values }))
        }
        7 => return decode_image(fields).map(Written::Image),
        8..=12 => decode_record(tag, fields)?,
        13 => {
            let length = usize::from(fields.u16("a type name")?);
            let name = std::str::from_utf8(fields.bytes(length, "a type name")?)
                .map_err(|_| WireError::NotUtf8("a type name"))?;
            Payload::Custom(kairos_sdk_core::CustomPayload {
                type_name: name.into(),
                data: fields.sized("custom data")?.into(),
            })
        }
        other => return Err(WireError::UnknownPayloadTag(other)),
    };
    Ok(Written::Payload(payload))
}

/// The fixed records: point clouds, IMU readings, fixes, CAN frames, poses.
fn decode_record(tag: u8, fields: &mut Fields<'_>) -> Result<Payload, WireError> {
    Ok(match tag {
        8 => {
            let count = fields.u32("a point count")? as usize;
            let has_intensity = fields.u8("the intensity flag")? != 0;
            let mut points = Vec::with_capacity(count.min(1 << 24));
            for _ in 0..count {
                points.push(Vec3::new(
                    fields.f32("a point")?,
                    fields.f32("a point")?,
                    fields.f32("a point")?,
                ));
            }
            let intensity = if has_intensity {
                let mut values = Vec::with_capacity(count.min(1 << 24));
                for _ in 0..count {
                    values.push(fields.f32("an intensity")?);
                }
                Some(values)
            } else {
                None
            };
            Payload::PointCloud(std::sync::Arc::new(PointCloud { points, intensity }))
        }
        9 => {
            let angular_velocity = fields.dvec3("an IMU reading")?;
            let linear_acceleration = fields.dvec3("an IMU reading")?;
            let has_orientation = fields.u8("an IMU reading")? != 0;
            let q = [
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("an IMU reading")?,
            ];
            Payload::Imu(Imu {
                angular_velocity,
                linear_acceleration,
                orientation: has_orientation.then(|| DQuat::from_xyzw(q[0], q[1], q[2], q[3])),
            })
        }
        10 => {
            let values = [
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("a fix")?,
            ];
            let status = *FixStatus::ALL
                .get(usize::from(fields.u8("a fix status")?))
                .ok_or(WireError::UnknownFixStatus)?;
            Payload::GnssFix(GnssFix {
                latitude_deg: values[0],
                longitude_deg: values[1],
                altitude_m: values[2],
                horizontal_accuracy_m: values[3],
                vertical_accuracy_m: values[4],
                status,
            })
        }
        11 => {
            let id = fields.u32("a CAN id")?;
            // Flags: 1 extended, 2 FD, 4 remote request (its length, and no data).
            let flags = fields.u8("a CAN frame")?;
            let length = fields.u8("a CAN frame")?;
            let mut frame = if flags & 4 != 0 {
                CanFrame::remote_request(id, flags & 1 != 0, length).ok_or(WireError::RemoteRequestTooLong)?
            } else {
                let data = fields.bytes(usize::from(length), "a CAN frame's data")?;
                CanFrame::new(id, flags & 1 != 0, data).ok_or(WireError::CanFrameTooLong)?
            };
            frame.fd |= flags & 2 != 0;
            Payload::CanFrame(frame)
        }
        12 => {
            let position = fields.dvec3("a pose")?;
            let q = [
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("")?,
                fields.f64("a pose")?,
            ];
            Payload::Pose(Pose {
                position,
                orientation: DQuat::from_xyzw(q[0], q[1], q[2], q[3]),
            })
        }
        _ => return Err(WireError::UnknownPayloadTag(tag)),
    })
}

fn decode_image<'a>(fields: &mut Fields<'a>) -> Result<ImageFields<'a>, WireError> {
    let width = fields.u32("an image")?;
    let height = fields.u32("an image")?;
    let stride = fields.u32("an image")?;
    let format = *PixelFormat::ALL
        .get(usize::from(fields.u8("an image's format")?))
        .ok_or(WireError::UnknownPixelFormat)?;
    let pixels = match fields.u8("where an image's pixels are")? {
        PIXELS_INLINE => ImagePixels::Inline(fields.sized("an image's pixels")?),
        PIXELS_SHARED => ImagePixels::Allocated {
            handle: fields.u64("a buffer handle")?,
            copied: fields.u8("a buffer handle")? != 0,
        },
        PIXELS_HELD => ImagePixels::Held(fields.u64("a held sample's handle")?),
        other => return Err(WireError::UnknownPixelPlace(other)),
    };
    Ok(ImageFields {
        width,
        height,
        stride,
        format,
        pixels,
    })
}

/// Where an image's pixels go in a sample sent to the worker.
#[derive(Debug)]
pub enum SentPixels {
    Inline,
    /// In the runtime's shared memory: descriptor, buffer id and length.
    Shared {
        fd: i32,
        id: u64,
        len: u64,
    },
}

/// Appends `payload` to `out`; images as `pixels` says.
pub fn encode_payload(out: &mut Vec<u8>, payload: &Payload, pixels: &SentPixels) {
    match payload {
        Payload::F64(v) => {
            out.push(0);
            out.extend_from_slice(&v.to_le_bytes());
        }
        Payload::I64(v) => {
            out.push(1);
            out.extend_from_slice(&v.to_le_bytes());
        }
        Payload::Bool(v) => out.extend_from_slice(&[2, u8::from(*v)]),
        Payload::Text(text) => {
            out.push(3);
            sized(out, text.as_bytes());
        }
        Payload::Bytes(bytes) => {
            out.push(4);
            sized(out, bytes);
        }
        Payload::Vector(values) => {
            out.push(5);
            out.extend_from_slice(&(values.len() as u32).to_le_bytes());
            values
                .iter()
                .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        }
        Payload::Matrix(matrix) => {
            out.push(6);
            out.extend_from_slice(&(matrix.rows as u32).to_le_bytes());
            out.extend_from_slice(&(matrix.cols as u32).to_le_bytes());
            matrix
                .values
                .iter()
                .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        }
        Payload::Image(image) => {
            out.push(7);
            for field in [image.width, image.height, image.stride] {
                out.extend_from_slice(&field.to_le_bytes());
            }
            let format = PixelFormat::ALL
                .iter()
                .position(|f| *f == image.format)
                .unwrap_or_default() as u8;
            out.push(format);
            match pixels {
                SentPixels::Inline => {
                    out.push(PIXELS_INLINE);
                    sized(out, &image.pixels);
                }
                SentPixels::Shared { fd, id, len } => {
                    out.push(PIXELS_SHARED);
                    out.extend_from_slice(&fd.to_le_bytes());
                    out.extend_from_slice(&id.to_le_bytes());
                    out.extend_from_slice(&len.to_le_bytes());
                }
            }
        }
        Payload::PointCloud(_)
        | Payload::Imu(_)
        | Payload::GnssFix(_)
        | Payload::CanFrame(_)
        | Payload::Pose(_) => encode_record(out, payload),
        Payload::Custom(custom) => {
            out.push(13);
            out.extend_from_slice(&(custom.type_name.len() as u16).to_le_bytes());
            out.extend_from_slice(custom.type_name.as_bytes());
            sized(out, &custom.data);
        }
        _ => {
            // A payload type newer than this protocol: sent as empty bytes rather than not at all.
            out.push(4);
            sized(out, &[]);
        }
    }
}

/// The fixed records, as [`decode_record`] reads them.
fn encode_record(out: &mut Vec<u8>, payload: &Payload) {
    match payload {
        Payload::PointCloud(cloud) => {
            out.push(8);
            out.extend_from_slice(&(cloud.points.len() as u32).to_le_bytes());
            out.push(u8::from(cloud.intensity.is_some()));
            for point in &cloud.points {
                for v in point.to_array() {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
            for v in cloud.intensity.iter().flatten() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        Payload::Imu(imu) => {
            out.push(9);
            f64s(out, &imu.angular_velocity.to_array());
            f64s(out, &imu.linear_acceleration.to_array());
            out.push(u8::from(imu.orientation.is_some()));
            f64s(out, &imu.orientation.unwrap_or(DQuat::IDENTITY).to_array());
        }
        Payload::GnssFix(fix) => {
            out.push(10);
            f64s(
                out,
                &[
                    fix.latitude_deg,
                    fix.longitude_deg,
                    fix.altitude_m,
                    fix.horizontal_accuracy_m,
                    fix.vertical_accuracy_m,
                ],
            );
            out.push(
                FixStatus::ALL
                    .iter()
                    .position(|s| *s == fix.status)
                    .unwrap_or_default() as u8,
            );
        }
        Payload::CanFrame(frame) => {
            out.push(11);
            out.extend_from_slice(&frame.id.to_le_bytes());
            out.push(u8::from(frame.extended) | (u8::from(frame.fd) << 1) | (u8::from(frame.remote) << 2));
            out.push(frame.length());
            out.extend_from_slice(frame.data());
        }
        Payload::Pose(pose) => {
            out.push(12);
            f64s(out, &pose.position.to_array());
            f64s(out, &pose.orientation.to_array());
        }
        _ => {}
    }
}

fn sized(out: &mut Vec<u8>, bytes: &[u8]) {
    out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(bytes);
}

fn f64s(out: &mut Vec<u8>, values: &[f64]) {
    for value in values {
        out.extend_from_slice(&value.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn can_frames_go_and_come_back_with_their_flags_remote_requests_with_their_length() {
        let mut fd = CanFrame::new(0x123, false, &[1, 2]).unwrap();
        fd.fd = true;
        for frame in [
            CanFrame::new(0x1ABC_DEF0, true, &[9; 12]).unwrap(),
            fd,
            CanFrame::remote_request(0x7FF, false, 6).unwrap(),
        ] {
            let mut out = Vec::new();
            encode_payload(&mut out, &Payload::CanFrame(frame), &SentPixels::Inline);
            let Ok(Written::Payload(back)) = decode_payload(&mut Fields::new(&out)) else {
                panic!("{frame:?} does not decode");
            };
            assert_eq!(back, Payload::CanFrame(frame));
        }
    }
}

//! Payload types: what a sample carries.
//!
//! Large payloads (vectors, matrices, text, bytes, images, point clouds, pack-defined data) sit behind an
//! `Arc`, so cloning a sample to hand it to another input never copies them.

use std::fmt;
use std::sync::Arc;

use glam::{DQuat, DVec3, Vec3};
use kairos_diagram::DataType;

use crate::pixels::Pixels;

/// The data of one sample.
///
/// The plain variants, `Copy` data, come first and the shared ones after: telling them apart is then one
/// comparison, which output buffers make for every sample.
#[derive(Clone, PartialEq)]
#[non_exhaustive]
pub enum Payload {
    /// One float.
    F64(f64),
    /// One integer.
    I64(i64),
    /// One boolean.
    Bool(bool),
    /// An inertial measurement.
    Imu(Imu),
    /// A satellite navigation fix.
    GnssFix(GnssFix),
    /// A CAN bus frame.
    CanFrame(CanFrame),
    /// A position and orientation.
    Pose(Pose),
    /// A vector of floats.
    Vector(Arc<[f64]>),
    /// A row-major matrix of floats.
    Matrix(Arc<Matrix>),
    /// UTF-8 text.
    Text(Arc<str>),
    /// Raw bytes.
    Bytes(Arc<[u8]>),
    /// An image; the pixel buffer is shared.
    Image(Image),
    /// 3D points, shared.
    PointCloud(Arc<PointCloud>),
    /// A pack-defined type, carried as bytes in the pack's own encoding.
    Custom(CustomPayload),
}

impl Payload {
    /// Whether the payload holds shared data (an `Arc`). Every other variant is plain `Copy` data, so a
    /// copy of its bytes is a clone of it, and writing over it loses nothing: output buffers rely on both.
    #[inline]
    pub fn owns_shared_data(&self) -> bool {
        const fn plain<T: Copy>() {}
        const {
            plain::<Imu>();
            plain::<GnssFix>();
            plain::<CanFrame>();
            plain::<Pose>();
        }
        !matches!(
            self,
            Payload::F64(_)
                | Payload::I64(_)
                | Payload::Bool(_)
                | Payload::Imu(_)
                | Payload::GnssFix(_)
                | Payload::CanFrame(_)
                | Payload::Pose(_)
        )
    }

    /// The payload's data type, as output ports and input filters name it.
    pub fn data_type(&self) -> DataType {
        match self {
            Payload::F64(_) => DataType::F64,
            Payload::I64(_) => DataType::I64,
            Payload::Bool(_) => DataType::Bool,
            Payload::Vector(_) => DataType::Vector,
            Payload::Matrix(_) => DataType::Matrix,
            Payload::Text(_) => DataType::Text,
            Payload::Bytes(_) => DataType::Bytes,
            Payload::Image(_) => DataType::Image,
            Payload::PointCloud(_) => DataType::PointCloud,
            Payload::Imu(_) => DataType::Imu,
            Payload::GnssFix(_) => DataType::GnssFix,
            Payload::CanFrame(_) => DataType::CanFrame,
            Payload::Pose(_) => DataType::Pose,
            Payload::Custom(custom) => DataType::Custom(custom.type_name.to_string()),
        }
    }

    /// Whether the payload is of `data_type`, without allocating.
    pub fn is_of(&self, data_type: &DataType) -> bool {
        match (self, data_type) {
            (Payload::Custom(custom), DataType::Custom(name)) => *custom.type_name == **name,
            (Payload::Custom(_), _) | (_, DataType::Custom(_)) => false,
            _ => std::mem::discriminant(&self.data_type()) == std::mem::discriminant(data_type),
        }
    }

    /// The payload as one float, converting integers and booleans; `None` for other types.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Payload::F64(v) => Some(*v),
            Payload::I64(v) => Some(*v as f64),
            Payload::Bool(v) => Some(if *v { 1.0 } else { 0.0 }),
            _ => None,
        }
    }

    /// The number of payload bytes behind shared pointers (what a copy would cost); for statistics.
    pub fn heavy_size_bytes(&self) -> usize {
        match self {
            Payload::Vector(v) => v.len() * 8,
            Payload::Matrix(m) => m.values.len() * 8,
            Payload::Text(t) => t.len(),
            Payload::Bytes(b) => b.len(),
            Payload::Image(image) => image.pixels.len(),
            Payload::PointCloud(cloud) => {
                cloud.points.len() * 12 + cloud.intensity.as_ref().map_or(0, |i| i.len() * 4)
            }
            Payload::Custom(custom) => custom.data.len(),
            _ => 0,
        }
    }
}

impl fmt::Debug for Payload {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Payload::F64(v) => write!(f, "F64({v})"),
            Payload::I64(v) => write!(f, "I64({v})"),
            Payload::Bool(v) => write!(f, "Bool({v})"),
            Payload::Vector(v) => write!(f, "Vector({v:?})"),
            Payload::Matrix(m) => write!(f, "Matrix({}x{})", m.rows, m.cols),
            Payload::Text(t) => write!(f, "Text({t:?})"),
            Payload::Bytes(b) => write!(f, "Bytes({} bytes)", b.len()),
            Payload::Image(i) => write!(f, "Image({}x{} {:?})", i.width, i.height, i.format),
            Payload::PointCloud(c) => write!(f, "PointCloud({} points)", c.points.len()),
            Payload::Imu(i) => write!(f, "{i:?}"),
            Payload::GnssFix(g) => write!(f, "{g:?}"),
            Payload::CanFrame(c) => write!(f, "{c:?}"),
            Payload::Pose(p) => write!(f, "{p:?}"),
            Payload::Custom(c) => write!(f, "Custom({}, {} bytes)", c.type_name, c.data.len()),
        }
    }
}

impl fmt::Display for Payload {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Payload::F64(v) => write!(f, "{v}"),
            Payload::I64(v) => write!(f, "{v}"),
            Payload::Bool(v) => write!(f, "{v}"),
            Payload::Text(t) => f.write_str(t),
            Payload::Imu(i) => write!(
                f,
                "gyro [{:.4} {:.4} {:.4}] acc [{:.3} {:.3} {:.3}]",
                i.angular_velocity.x,
                i.angular_velocity.y,
                i.angular_velocity.z,
                i.linear_acceleration.x,
                i.linear_acceleration.y,
                i.linear_acceleration.z
            ),
            Payload::GnssFix(g) => write!(
                f,
                "lat {:.7} lon {:.7} alt {:.2} m ({:?})",
                g.latitude_deg, g.longitude_deg, g.altitude_m, g.status
            ),
            Payload::Pose(p) => write!(
                f,
                "pos [{:.3} {:.3} {:.3}] rot [{:.4} {:.4} {:.4} {:.4}]",
                p.position.x,
                p.position.y,
                p.position.z,
                p.orientation.x,
                p.orientation.y,
                p.orientation.z,
                p.orientation.w
            ),
            other => write!(f, "{other:?}"),
        }
    }
}

/// A row-major matrix of floats.
#[derive(Debug, Clone, PartialEq)]
pub struct Matrix {
    /// Number of rows.
    pub rows: usize,
    /// Number of columns.
    pub cols: usize,
    /// `rows * cols` values, row after row.
    pub values: Vec<f64>,
}

/// How an image's pixels are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum PixelFormat {
    /// One byte of grey.
    Gray8,
    /// Two bytes of grey, little-endian.
    Gray16,
    /// Red, green, blue: one byte each.
    Rgb8,
    /// Red, green, blue, alpha: one byte each.
    Rgba8,
    /// Blue, green, red: one byte each.
    Bgr8,
    /// Blue, green, red, alpha: one byte each.
    Bgra8,
}

impl PixelFormat {
    /// Every format, in the order binary encodings number them (the Python wire, the sample frame): a
    /// format's number is its place here, so new formats only ever go at the end.
    pub const ALL: [PixelFormat; 6] = [
        PixelFormat::Gray8,
        PixelFormat::Gray16,
        PixelFormat::Rgb8,
        PixelFormat::Rgba8,
        PixelFormat::Bgr8,
        PixelFormat::Bgra8,
    ];

    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> u32 {
        match self {
            PixelFormat::Gray8 => 1,
            PixelFormat::Gray16 => 2,
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => 3,
            PixelFormat::Rgba8 | PixelFormat::Bgra8 => 4,
        }
    }
}

/// An image whose pixel buffer is shared: cloning it never copies pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel layout.
    pub format: PixelFormat,
    /// Bytes from the start of one row to the start of the next.
    pub stride: u32,
    /// `stride * height` bytes.
    pub pixels: Pixels,
}

/// Why an image's fields do not fit together.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("image of {width}x{height} {format:?} with stride {stride} needs {needed} bytes, got {got}")]
pub struct ImageSizeError {
    width: u32,
    height: u32,
    format: PixelFormat,
    stride: u32,
    needed: u64,
    got: usize,
}

impl Image {
    /// An image with rows packed tightly (`stride = width * bytes per pixel`).
    pub fn packed(
        width: u32,
        height: u32,
        format: PixelFormat,
        pixels: impl Into<Pixels>,
    ) -> Result<Self, ImageSizeError> {
        Self::with_stride(
            width,
            height,
            format,
            width.saturating_mul(format.bytes_per_pixel()),
            pixels,
        )
    }

    /// An image with an explicit stride; checks that the buffer is large enough.
    pub fn with_stride(
        width: u32,
        height: u32,
        format: PixelFormat,
        stride: u32,
        pixels: impl Into<Pixels>,
    ) -> Result<Self, ImageSizeError> {
        let pixels = pixels.into();
        let needed = u64::from(stride) * u64::from(height);
        let row_fits = u64::from(stride) >= u64::from(width) * u64::from(format.bytes_per_pixel());
        if !row_fits || (pixels.len() as u64) < needed {
            return Err(ImageSizeError {
                width,
                height,
                format,
                stride,
                needed,
                got: pixels.len(),
            });
        }
        Ok(Image {
            width,
            height,
            format,
            stride,
            pixels,
        })
    }
}

/// 3D points with optional per-point intensity.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// The points, in metres, in the sensor's frame.
    pub points: Vec<Vec3>,
    /// One intensity per point, when the sensor gives it.
    pub intensity: Option<Vec<f32>>,
}

/// An inertial measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Imu {
    /// Angular velocity in rad/s, body frame.
    pub angular_velocity: DVec3,
    /// Linear acceleration in m/s², body frame, gravity included.
    pub linear_acceleration: DVec3,
    /// Orientation estimate, when the unit provides one.
    pub orientation: Option<DQuat>,
}

/// The quality of a satellite fix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FixStatus {
    /// No position.
    NoFix,
    /// Autonomous fix.
    Fix,
    /// Differential (SBAS/DGPS) fix.
    Differential,
    /// RTK fixed-ambiguity fix.
    RtkFixed,
}

impl FixStatus {
    /// Every status, in the order binary encodings number them: a status's number is its place here.
    pub const ALL: [FixStatus; 4] = [
        FixStatus::NoFix,
        FixStatus::Fix,
        FixStatus::Differential,
        FixStatus::RtkFixed,
    ];
}

/// A satellite navigation fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssFix {
    /// Latitude, degrees north, WGS84.
    pub latitude_deg: f64,
    /// Longitude, degrees east, WGS84.
    pub longitude_deg: f64,
    /// Altitude above the WGS84 ellipsoid, metres.
    pub altitude_m: f64,
    /// Horizontal accuracy (one sigma), metres.
    pub horizontal_accuracy_m: f64,
    /// Vertical accuracy (one sigma), metres.
    pub vertical_accuracy_m: f64,
    /// Fix quality.
    pub status: FixStatus,
}

/// A CAN or CAN FD frame.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    /// The identifier (11 or 29 bits).
    pub id: u32,
    /// Whether the identifier is extended (29 bits).
    pub extended: bool,
    /// Whether this is a CAN FD frame (up to 64 data bytes).
    pub fd: bool,
    /// Whether this is a remote request (RTR, classic CAN): it asks for the frame with this identifier
    /// and carries no data, only the length it asks for.
    pub remote: bool,
    /// The data's length; a remote request's, the length it asks for.
    len: u8,
    data: [u8; 64],
}

impl CanFrame {
    /// A frame with `data` (at most 8 bytes for classic CAN, 64 for CAN FD); `None` if too long.
    pub fn new(id: u32, extended: bool, data: &[u8]) -> Option<Self> {
        let fd = data.len() > 8;
        if data.len() > 64 {
            return None;
        }
        let mut buffer = [0_u8; 64];
        buffer.get_mut(..data.len())?.copy_from_slice(data);
        Some(CanFrame {
            id,
            extended,
            fd,
            remote: false,
            len: data.len() as u8,
            data: buffer,
        })
    }

    /// A remote request for the frame `id`, asking for `length` bytes (at most 8); `None` if longer.
    pub fn remote_request(id: u32, extended: bool, length: u8) -> Option<Self> {
        (length <= 8).then_some(CanFrame {
            id,
            extended,
            fd: false,
            remote: true,
            len: length,
            data: [0; 64],
        })
    }

    /// The data bytes (none for a remote request).
    pub fn data(&self) -> &[u8] {
        if self.remote {
            return &[];
        }
        self.data.get(..usize::from(self.len)).unwrap_or(&[])
    }

    /// The length code: the data's length, or the length a remote request asks for.
    pub fn length(&self) -> u8 {
        self.len
    }
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let extended = if self.extended { " ext" } else { "" };
        if self.remote {
            // No data: what it asks for is the length.
            return write!(
                f,
                "CanFrame(id {:#x}{extended} remote, asks {} bytes)",
                self.id, self.len
            );
        }
        write!(f, "CanFrame(id {:#x}{extended}, {:02x?})", self.id, self.data())
    }
}

/// A position and orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Position in metres.
    pub position: DVec3,
    /// Orientation.
    pub orientation: DQuat,
}

/// Data of a pack-defined type: the type's registered name and the pack's own encoding of it.
#[derive(Debug, Clone, PartialEq)]
pub struct CustomPayload {
    /// The registered type name.
    pub type_name: Arc<str>,
    /// The encoded data.
    pub data: Arc<[u8]>,
}

#[cfg(test)]
mod tests {
    use super::CanFrame;

    #[test]
    fn a_can_frame_shows_its_data_or_the_length_a_remote_request_asks_for() {
        let data = CanFrame::new(0x123, false, &[1, 0xab]).unwrap();
        assert_eq!(format!("{data:?}"), "CanFrame(id 0x123, [01, ab])");
        let remote = CanFrame::remote_request(0x1234_5678, true, 4).unwrap();
        assert_eq!(
            format!("{remote:?}"),
            "CanFrame(id 0x12345678 ext remote, asks 4 bytes)"
        );
    }
}

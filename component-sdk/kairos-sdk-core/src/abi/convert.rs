//! Samples, property values and status codes to and from their C form, for both sides of the ABI.

#![allow(unsafe_code, reason = "C samples borrow their bytes through raw pointers")]

use std::sync::Arc;

use glam::{DQuat, DVec3, Vec3};
use kairos_diagram::Value;

use super::types::{KError, KSample, KStr, KValue};
use super::{kind, status};
use crate::component::{ComponentError, ComponentResult};
use crate::payload::{
    CanFrame, CustomPayload, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat, PointCloud, Pose,
};
use crate::sample::Sample;
use crate::time::Timestamp;

/// Copies `message` into a pack's or host's error buffer (cut at a character boundary to fit).
///
/// # Safety
/// `error` is null or a valid, exclusive [`KError`] whose buffer is null or has `capacity` writable bytes.
pub unsafe fn write_error(error: *mut KError, message: &str) {
    // SAFETY: guaranteed by the caller.
    let Some(error) = (unsafe { error.as_mut() }) else {
        return;
    };
    if error.buffer.is_null() {
        return;
    }
    let mut len = message.len().min(error.capacity);
    while !message.is_char_boundary(len) {
        len -= 1;
    }
    // SAFETY: `len <= capacity` bytes fit in the buffer; source and destination do not overlap.
    unsafe { std::ptr::copy_nonoverlapping(message.as_ptr(), error.buffer, len) };
    error.len = len;
}

// ----------------------------------------------------------------------------------------------------
// Payload conversions.

fn pixel_format_code(format: PixelFormat) -> u32 {
    match format {
        PixelFormat::Gray8 => 1,
        PixelFormat::Gray16 => 2,
        PixelFormat::Rgb8 => 3,
        PixelFormat::Rgba8 => 4,
        PixelFormat::Bgr8 => 5,
        PixelFormat::Bgra8 => 6,
    }
}

fn pixel_format_from(code: u32) -> Option<PixelFormat> {
    Some(match code {
        1 => PixelFormat::Gray8,
        2 => PixelFormat::Gray16,
        3 => PixelFormat::Rgb8,
        4 => PixelFormat::Rgba8,
        5 => PixelFormat::Bgr8,
        6 => PixelFormat::Bgra8,
        _ => return None,
    })
}

fn f64_bytes(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_ne_bytes()).collect()
}

fn f64s_from(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|c| f64::from_ne_bytes(c.try_into().unwrap_or([0; 8])))
        .collect()
}

fn f32s_from(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_ne_bytes(c.try_into().unwrap_or([0; 4])))
        .collect()
}

/// Describes `sample` in C terms. Pointers borrow from `sample` and from `scratch` (for payloads that need
/// re-encoding), so both must outlive the `KSample`.
pub fn sample_to_c(sample: &Sample, scratch: &mut Vec<u8>) -> KSample {
    let mut k = KSample {
        timestamp_ns: sample.timestamp.as_nanos(),
        time_of_issue_ns: sample.time_of_issue.as_nanos(),
        sequence: sample.sequence,
        ..KSample::default()
    };
    let borrow = |bytes: &[u8], k: &mut KSample| {
        k.data = bytes.as_ptr();
        k.data_len = bytes.len();
    };
    match &sample.payload {
        Payload::F64(v) => {
            k.kind = kind::F64;
            k.scalar_f64 = *v;
        }
        Payload::I64(v) => {
            k.kind = kind::I64;
            k.scalar_i64 = *v;
        }
        Payload::Bool(v) => {
            k.kind = kind::BOOL;
            k.scalar_i64 = i64::from(*v);
        }
        Payload::Vector(v) => {
            k.kind = kind::VECTOR;
            *scratch = f64_bytes(v);
            borrow(scratch, &mut k);
        }
        Payload::Matrix(m) => {
            k.kind = kind::MATRIX;
            k.width = u32::try_from(m.cols).unwrap_or(0);
            k.height = u32::try_from(m.rows).unwrap_or(0);
            *scratch = f64_bytes(&m.values);
            borrow(scratch, &mut k);
        }
        Payload::Text(t) => {
            k.kind = kind::TEXT;
            borrow(t.as_bytes(), &mut k);
        }
        Payload::Bytes(b) => {
            k.kind = kind::BYTES;
            borrow(b, &mut k);
        }
        Payload::Image(image) => {
            k.kind = kind::IMAGE;
            k.width = image.width;
            k.height = image.height;
            k.stride = image.stride;
            k.pixel_format = pixel_format_code(image.format);
            borrow(&image.pixels, &mut k);
        }
        Payload::PointCloud(cloud) => {
            k.kind = kind::POINT_CLOUD;
            k.width = u32::try_from(cloud.points.len()).unwrap_or(0);
            scratch.clear();
            for p in &cloud.points {
                scratch.extend(p.to_array().iter().flat_map(|v| v.to_ne_bytes()));
            }
            if let Some(intensity) = &cloud.intensity {
                k.flags = 1;
                scratch.extend(intensity.iter().flat_map(|v| v.to_ne_bytes()));
            }
            borrow(scratch, &mut k);
        }
        Payload::Imu(imu) => {
            k.kind = kind::IMU;
            let [gx, gy, gz] = imu.angular_velocity.to_array();
            let [ax, ay, az] = imu.linear_acceleration.to_array();
            let [qx, qy, qz, qw] = imu.orientation.map_or([0.0; 4], |q| q.to_array());
            k.flags = u32::from(imu.orientation.is_some());
            k.values[..10].copy_from_slice(&[gx, gy, gz, ax, ay, az, qx, qy, qz, qw]);
        }
        Payload::GnssFix(fix) => {
            k.kind = kind::GNSS_FIX;
            k.values[..5].copy_from_slice(&[
                fix.latitude_deg,
                fix.longitude_deg,
                fix.altitude_m,
                fix.horizontal_accuracy_m,
                fix.vertical_accuracy_m,
            ]);
            k.scalar_i64 = match fix.status {
                FixStatus::NoFix => 0,
                FixStatus::Fix => 1,
                FixStatus::Differential => 2,
                FixStatus::RtkFixed => 3,
            };
        }
        Payload::CanFrame(frame) => {
            k.kind = kind::CAN_FRAME;
            k.scalar_i64 = i64::from(frame.id);
            k.flags = u32::from(frame.extended) | (u32::from(frame.fd) << 1) | (u32::from(frame.remote) << 2);
            k.width = u32::from(frame.length());
            borrow(frame.data(), &mut k);
        }
        Payload::Pose(pose) => {
            k.kind = kind::POSE;
            let [x, y, z] = pose.position.to_array();
            let [qx, qy, qz, qw] = pose.orientation.to_array();
            k.values[..7].copy_from_slice(&[x, y, z, qx, qy, qz, qw]);
        }
        Payload::Custom(custom) => {
            k.kind = kind::CUSTOM;
            k.type_name = KStr::new(&custom.type_name);
            borrow(&custom.data, &mut k);
        }
    }
    k
}

/// Why a sample's C description is not a sample: the write (or read) across the pack boundary fails.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ForeignSampleError {
    /// `rows × cols` is not the number of values given.
    #[error("matrix of {rows}x{cols} with {values} values")]
    MatrixShape { rows: usize, cols: usize, values: usize },
    /// Text must be UTF-8 on both sides.
    #[error("text is not UTF-8: {0}")]
    TextNotUtf8(std::str::Utf8Error),
    /// A pixel format code this side does not know.
    #[error("unknown pixel format {0}")]
    UnknownPixelFormat(u32),
    /// The image's geometry does not fit its pixels.
    #[error(transparent)]
    ImageSize(#[from] crate::payload::ImageSizeError),
    /// Fewer floats than the points (and intensities) need.
    #[error("point cloud of {points} points with {floats} floats")]
    PointCloudShort { points: usize, floats: usize },
    /// A remote request longer than a classic frame.
    #[error("a remote request for {0} bytes")]
    RemoteRequestLength(u32),
    /// More data than a CAN FD frame holds.
    #[error("CAN frame of {0} bytes")]
    CanFrameLength(usize),
    /// A custom type's name must be UTF-8: it is matched against descriptors.
    #[error("custom type name is not UTF-8")]
    CustomNameNotUtf8,
    /// A payload kind code this side does not know (a newer pack).
    #[error("unknown payload kind {0}")]
    UnknownKind(u32),
}

/// Builds a sample from its C description, copying any borrowed bytes into memory of this side.
///
/// # Safety
/// `k.data` must point to `k.data_len` readable bytes and `k.type_name` must be valid, for the call.
pub unsafe fn sample_from_c(k: &KSample) -> Result<Sample, ForeignSampleError> {
    let data: &[u8] = if k.data_len == 0 || k.data.is_null() {
        &[]
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { std::slice::from_raw_parts(k.data, k.data_len) }
    };
    let v = &k.values;
    let payload = match k.kind {
        kind::F64 => Payload::F64(k.scalar_f64),
        kind::I64 => Payload::I64(k.scalar_i64),
        kind::BOOL => Payload::Bool(k.scalar_i64 != 0),
        kind::VECTOR => Payload::Vector(Arc::from(f64s_from(data))),
        kind::MATRIX => {
            let values = f64s_from(data);
            let (rows, cols) = (k.height as usize, k.width as usize);
            if rows * cols != values.len() {
                let values = values.len();
                return Err(ForeignSampleError::MatrixShape { rows, cols, values });
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        }
        kind::TEXT => Payload::Text(Arc::from(
            std::str::from_utf8(data).map_err(ForeignSampleError::TextNotUtf8)?,
        )),
        kind::BYTES => Payload::Bytes(Arc::from(data)),
        kind::IMAGE => {
            let format = pixel_format_from(k.pixel_format)
                .ok_or(ForeignSampleError::UnknownPixelFormat(k.pixel_format))?;
            // The one copy across the boundary goes into a buffer that local viewers can map as it is.
            let mut pixels = crate::pixels::PixelsMut::new(data.len());
            pixels.copy_from_slice(data);
            Payload::Image(Image::with_stride(
                k.width,
                k.height,
                format,
                k.stride,
                pixels.freeze(),
            )?)
        }
        kind::POINT_CLOUD => {
            let count = k.width as usize;
            let floats = f32s_from(data);
            let needed = count * if k.flags & 1 == 1 { 4 } else { 3 };
            if floats.len() < needed {
                return Err(ForeignSampleError::PointCloudShort {
                    points: count,
                    floats: floats.len(),
                });
            }
            let points = floats
                .chunks_exact(3)
                .take(count)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect();
            let intensity =
                (k.flags & 1 == 1).then(|| floats.iter().skip(3 * count).take(count).copied().collect());
            Payload::PointCloud(Arc::new(PointCloud { points, intensity }))
        }
        kind::IMU => Payload::Imu(Imu {
            angular_velocity: DVec3::new(v[0], v[1], v[2]),
            linear_acceleration: DVec3::new(v[3], v[4], v[5]),
            orientation: (k.flags & 1 == 1).then(|| DQuat::from_xyzw(v[6], v[7], v[8], v[9])),
        }),
        kind::GNSS_FIX => Payload::GnssFix(GnssFix {
            latitude_deg: v[0],
            longitude_deg: v[1],
            altitude_m: v[2],
            horizontal_accuracy_m: v[3],
            vertical_accuracy_m: v[4],
            status: match k.scalar_i64 {
                1 => FixStatus::Fix,
                2 => FixStatus::Differential,
                3 => FixStatus::RtkFixed,
                _ => FixStatus::NoFix,
            },
        }),
        kind::CAN_FRAME => {
            let (id, extended) = (u32::try_from(k.scalar_i64).unwrap_or(0), k.flags & 1 == 1);
            let mut frame = if k.flags & 4 != 0 {
                u8::try_from(k.width)
                    .ok()
                    .and_then(|length| CanFrame::remote_request(id, extended, length))
                    .ok_or(ForeignSampleError::RemoteRequestLength(k.width))?
            } else {
                CanFrame::new(id, extended, data).ok_or(ForeignSampleError::CanFrameLength(data.len()))?
            };
            frame.fd |= k.flags & 2 != 0;
            Payload::CanFrame(frame)
        }
        kind::POSE => Payload::Pose(Pose {
            position: DVec3::new(v[0], v[1], v[2]),
            orientation: DQuat::from_xyzw(v[3], v[4], v[5], v[6]),
        }),
        kind::CUSTOM => {
            // SAFETY: guaranteed by the caller.
            let name = unsafe { k.type_name.as_str() }.ok_or(ForeignSampleError::CustomNameNotUtf8)?;
            Payload::Custom(CustomPayload {
                type_name: Arc::from(name),
                data: Arc::from(data),
            })
        }
        other => return Err(ForeignSampleError::UnknownKind(other)),
    };
    Ok(Sample {
        payload,
        timestamp: Timestamp::from_nanos(k.timestamp_ns),
        time_of_issue: Timestamp::from_nanos(k.time_of_issue_ns),
        sequence: k.sequence,
    })
}

/// The status code that carries `error` across the boundary.
pub fn error_status(error: &ComponentError) -> i32 {
    match error {
        ComponentError::Stopped => status::STOPPED,
        ComponentError::Interrupted => status::INTERRUPTED,
        ComponentError::EndOfStream => status::END_OF_STREAM,
        ComponentError::NoData => status::NO_DATA,
        ComponentError::Failed(_) => status::FAILED,
    }
}

/// The result a status code stands for; `message` gives a failure's text.
pub fn status_error(code: i32, message: impl FnOnce() -> String) -> ComponentResult {
    match code {
        status::OK => Ok(()),
        status::STOPPED => Err(ComponentError::Stopped),
        status::INTERRUPTED => Err(ComponentError::Interrupted),
        status::END_OF_STREAM => Err(ComponentError::EndOfStream),
        status::NO_DATA => Err(ComponentError::NoData),
        _ => Err(ComponentError::Failed(message())),
    }
}

/// Describes a property value in C terms; text borrows from `value`.
pub fn value_to_c(value: &Value) -> KValue {
    let mut described = KValue {
        kind: 0,
        integer: 0,
        float: 0.0,
        text: KStr::new(""),
    };
    match value {
        Value::Bool(b) => {
            described.kind = 1;
            described.integer = i64::from(*b);
        }
        Value::I64(i) => {
            described.kind = 2;
            described.integer = *i;
        }
        Value::F64(f) => {
            described.kind = 3;
            described.float = *f;
        }
        Value::Text(t) => {
            described.kind = 4;
            described.text = KStr::new(t);
        }
    }
    described
}

/// The property value a [`KValue`] describes.
///
/// # Safety
/// A text value's bytes must be readable for the call.
pub unsafe fn value_from_c(described: &KValue) -> Value {
    match described.kind {
        1 => Value::Bool(described.integer != 0),
        2 => Value::I64(described.integer),
        3 => Value::F64(described.float),
        // SAFETY: guaranteed by the caller.
        _ => Value::Text(unsafe { described.text.as_str() }.unwrap_or_default().to_owned()),
    }
}

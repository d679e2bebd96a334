//! `video.v4l2_camera`: a camera through Video4Linux2 (USB/UVC cameras, capture cards), YUYV or MJPEG
//! converted to RGB straight into the shared pixel pool, on the `linuxvideo` crate.

use std::os::fd::AsFd as _;

use kairos_sdk::Throttle;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DeviceKind, Payload, Value,
};
use linuxvideo::format::{PixFormat, PixelFormat};
use linuxvideo::stream::ReadStream;
use linuxvideo::{CapabilityFlags, Device, Fract};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};

use crate::convert::{mjpeg_to_rgb, yuyv_to_rgb};

/// How long one wait for a frame lasts, so stop and control requests get through.
const FRAME_WAIT_MS: u16 = 50;

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

/// The descriptor of `video.v4l2_camera`.
pub fn descriptor() -> ComponentInfo {
    Descriptor::new(
        "video.v4l2_camera",
        "video",
        "Captures a camera through Video4Linux2 (USB/UVC cameras, capture cards): YUYV or MJPEG frames \
         converted to RGB images, stamped when the frame is taken from the driver",
    )
    .label("Camera (V4L2)")
    .output("image", DataType::Image, "Each frame, RGB")
    .property(
        Property::path("device", "/dev/video0")
            .doc("The camera's device; `kairos devices` lists them")
            .device(DeviceKind::Camera),
    )
    .property(Property::i64("width", 640).int_range(2, 8192).unit("px").doc("Width asked of the camera"))
    .property(Property::i64("height", 480).int_range(1, 8192).unit("px").doc("Height asked of the camera"))
    .property(Property::choice("pixel_format", &["yuyv", "mjpeg"], "yuyv").doc(
        "What the camera sends: yuyv (uncompressed, light on the CPU, limited in rate at large sizes over USB \
         2) or mjpeg (compressed, decoded here)",
    ))
    .property(
        Property::f64("rate", 30.0)
            .range(0.0, 1000.0)
            .unit("Hz")
            .doc("Frames per second asked of the camera (0: its default)"),
    )
    .build()
}

/// What the camera and the driver agreed on.
#[derive(Debug, Clone, Copy)]
struct Negotiated {
    width: u32,
    height: u32,
    bytes_per_line: u32,
    mjpeg: bool,
}

/// `video.v4l2_camera`. See [`descriptor`].
#[derive(Default)]
pub struct V4l2Camera {
    stream: Option<ReadStream>,
    format: Option<Negotiated>,
    device: String,
    frames: u64,
    bad_frames: u64,
    warnings: Throttle,
}

impl std::fmt::Debug for V4l2Camera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Camera")
            .field("device", &self.device)
            .field("frames", &self.frames)
            .finish_non_exhaustive()
    }
}

/// Why a camera cannot be opened, in words that say what to do.
fn open_error(path: &str, error: &std::io::Error) -> String {
    match error.kind() {
        std::io::ErrorKind::NotFound => {
            format!("no camera at {path} ({error}); `kairos devices` lists the cameras present")
        }
        std::io::ErrorKind::PermissionDenied => format!(
            "cannot open the camera {path}: {error}; add the user to the `video` group (sudo usermod -aG video \
             $USER, then log in again)"
        ),
        _ => format!("cannot open the camera {path}: {error}"),
    }
}

impl Component for V4l2Camera {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.device = ctx.text_property("device")?;
        let path = self.device.clone();
        let device = Device::open(&path).map_err(|e| failed(open_error(&path, &e)))?;
        if !device
            .capabilities()
            .map_err(failed)?
            .device_capabilities()
            .contains(CapabilityFlags::VIDEO_CAPTURE)
        {
            return Err(failed(format_args!(
                "{path} is a video device that does not capture (an output or metadata node?)"
            )));
        }
        let (width, height) = (
            u32::try_from(ctx.i64_property("width")?).unwrap_or(640),
            u32::try_from(ctx.i64_property("height")?).unwrap_or(480),
        );
        let wanted = if ctx.text_property("pixel_format")? == "mjpeg" {
            PixelFormat::MJPG
        } else {
            PixelFormat::YUYV
        };
        let capture = device
            .video_capture(PixFormat::new(width, height, wanted))
            .map_err(|e| failed(format_args!("{path}: cannot set {width}×{height} {wanted}: {e}")))?;
        let got = capture.format();
        if got.pixel_format() != wanted {
            return Err(failed(format_args!(
                "{path} does not send {wanted} (it offers {}); choose the other pixel_format",
                got.pixel_format()
            )));
        }
        if (got.width(), got.height()) != (width, height) {
            tracing::warn!(
                "{path} gives {}×{} rather than the {width}×{height} asked for",
                got.width(),
                got.height()
            );
        }
        let rate = ctx.f64_property("rate")?;
        if rate > 0.0 {
            #[allow(
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                reason = "a rate in Hz, at most 1000"
            )]
            let per_second = (rate * 1000.0).round() as u32;
            match capture.set_frame_interval(Fract::new(1000, per_second.max(1))) {
                Ok(interval) => tracing::info!(
                    "{path}: {}×{} {wanted}, one frame every {interval} s",
                    got.width(),
                    got.height()
                ),
                Err(e) => tracing::warn!(
                    "{path}: cannot set {rate} frames per second ({e}); the camera's own rate it is"
                ),
            }
        }
        let negotiated = Negotiated {
            width: got.width(),
            height: got.height(),
            bytes_per_line: got.bytes_per_line(),
            mjpeg: wanted == PixelFormat::MJPG,
        };
        self.stream = Some(
            capture
                .into_stream()
                .map_err(|e| failed(format_args!("{path}: cannot start streaming: {e}")))?,
        );
        self.format = Some(negotiated);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let (Some(stream), Some(format)) = (&mut self.stream, self.format) else {
            return Err(ComponentError::Stopped);
        };
        let mut fds = [PollFd::new(stream.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(FRAME_WAIT_MS)) {
            Ok(0) | Err(nix::errno::Errno::EINTR) => return Ok(()),
            Ok(_) => {}
            Err(e) => return Err(failed(format_args!("{}: {e}", self.device))),
        }
        let converted = stream
            .dequeue(|buffer| {
                let bytes: &[u8] = &buffer;
                Ok(if format.mjpeg {
                    mjpeg_to_rgb(bytes)
                } else {
                    yuyv_to_rgb(bytes, format.width, format.height, format.bytes_per_line)
                })
            })
            .map_err(|e| failed(format_args!("{}: the camera stopped sending: {e}", self.device)))?;
        let now = ctx.now();
        match converted {
            Ok(image) => {
                self.frames += 1;
                ctx.write_at("image", Payload::Image(image), now)?;
            }
            Err(why) => {
                // A torn MJPEG frame (USB trouble) is dropped; the next one usually decodes.
                self.bad_frames += 1;
                let (device, count) = (&self.device, self.bad_frames);
                self.warnings
                    .warn(|| format!("{device}: a frame dropped: {why} ({count} in all)"));
            }
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "camera", "device": self.device, "frames": self.frames, "bad_frames": self.bad_frames,
            "width": self.format.map(|f| f.width), "height": self.format.map(|f| f.height),
        }))
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        // Dropping the stream stops streaming and frees the driver's buffers.
        self.stream = None;
        Ok(())
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

//! Encoded frames: images to JPEG bytes (to record or send compressed) and back, and raw YUV frames
//! (YUYV, NV12: what cameras and video codecs exchange) to images and back.

use std::sync::Arc;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, TypeFilter,
};

use crate::image_io::{format_of, image_of, made, view_of};
use crate::kernels::color;
use crate::kernels::color::Layout;
use crate::kernels::yuv::{self, Yuv};
use crate::kernels::{jpeg, turbojpeg};

/// `vision.jpeg_encode`.
#[derive(Debug, Default)]
pub struct JpegEncode {
    buffer: Vec<u8>,
    /// libjpeg-turbo's compressor, when the encoder chosen is it.
    turbo: Option<turbojpeg::Compressor>,
}

impl JpegEncode {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.jpeg_encode",
            "images",
            "Compresses images to JPEG (baseline, 4:2:0 chroma)",
        )
        .label("JPEG encode")
        .input("in", TypeFilter::only(DataType::Image), "An 8-bit image")
        .output("out", DataType::Bytes, "The JPEG file's bytes, same timestamp")
        .property(
            Property::i64("quality", 90)
                .int_range(1, 100)
                .live()
                .doc("1: smallest; 100: best"),
        )
        .property(
            Property::choice("encoder", &["auto", "libjpeg-turbo", "rust"], "auto").doc(
                "auto: libjpeg-turbo where the system has it (package libturbojpeg0), about 3× faster, \
                 else the built-in pure-Rust encoder",
            ),
        )
        .build()
    }
}

impl Component for JpegEncode {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let chosen = ctx.text_property("encoder")?;
        self.turbo = match chosen.as_str() {
            "rust" => None,
            "libjpeg-turbo" => Some(turbojpeg::Compressor::new().ok_or_else(|| {
                ComponentError::failed(
                    "encoder is libjpeg-turbo, but libturbojpeg.so.0 cannot be loaded: install it \
                     (Debian, Ubuntu: apt install libturbojpeg0) or set encoder to auto",
                )
            })?),
            _ => turbojpeg::Compressor::new(),
        };
        tracing::info!(
            "JPEG encoder: {}",
            if self.turbo.is_some() {
                "libjpeg-turbo (the system's)"
            } else if chosen == "rust" {
                "jpeg-encoder (pure Rust)"
            } else {
                "jpeg-encoder (pure Rust; install libturbojpeg0 for one about 3× faster)"
            }
        );
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let quality = ctx.i64_property("quality")?.clamp(1, 100) as u8;
        let sample = ctx.read("in")?;
        let (view, layout) = view_of(image_of(&sample, "in")?, "vision.jpeg_encode")?;
        self.buffer.clear();
        match &mut self.turbo {
            Some(turbo) => turbo.encode(&view, layout, quality, &mut self.buffer),
            None => jpeg::encode(&view, layout, quality, &mut self.buffer),
        }
        .map_err(ComponentError::failed)?;
        ctx.write_processed("out", &sample, Payload::Bytes(Arc::from(self.buffer.as_slice())))
    }

    fn status(&self) -> Option<serde_json::Value> {
        let encoder = if self.turbo.is_some() {
            "libjpeg-turbo"
        } else {
            "jpeg-encoder"
        };
        Some(serde_json::json!({ "kind": "jpeg", "encoder": encoder }))
    }
}

/// `vision.jpeg_decode`.
#[derive(Debug, Default)]
pub struct JpegDecode;

impl JpegDecode {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new("vision.jpeg_decode", "images", "Decodes JPEG bytes into images")
            .label("JPEG decode")
            .input("in", TypeFilter::only(DataType::Bytes), "A JPEG file's bytes")
            .output("out", DataType::Image, "The image, same timestamp")
            .property(
                Property::choice("to", &["rgb", "gray"], "rgb")
                    .live()
                    .doc("Colour or grey output"),
            )
            .build()
    }
}

impl Component for JpegDecode {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let layout = if ctx.text_property("to")? == "gray" {
            Layout::Gray
        } else {
            Layout::Rgb
        };
        let sample = ctx.read("in")?;
        let Payload::Bytes(bytes) = &sample.payload else {
            return Err(ComponentError::failed(format_args!(
                "input in expects JPEG bytes, got {}",
                sample.payload.data_type()
            )));
        };
        let (width, height, _) = jpeg::header(bytes).map_err(ComponentError::failed)?;
        let out = made(width, height, format_of(layout), |dst| {
            jpeg::decode(bytes, layout, dst).map_err(ComponentError::failed)
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

fn yuv_named(name: &str) -> Yuv {
    if name == "nv12" { Yuv::Nv12 } else { Yuv::Yuyv }
}

/// `vision.from_yuv`.
#[derive(Debug, Default)]
pub struct FromYuv;

impl FromYuv {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.from_yuv",
            "images",
            "Raw YUYV or NV12 frames (bytes) as RGB images (BT.601 limited range, as cameras send)",
        )
        .label("YUV frame to image")
        .input(
            "in",
            TypeFilter::only(DataType::Bytes),
            "One raw frame per sample",
        )
        .output("out", DataType::Image, "The RGB image, same timestamp")
        .property(Property::choice("format", &["yuyv", "nv12"], "yuyv").doc(
            "yuyv: 4:2:2 packed (Y0 U Y1 V); nv12: a Y plane then an interleaved U V plane at half height",
        ))
        .property(
            Property::i64("width", 640)
                .int_range(2, 16384)
                .unit("px")
                .doc("Frame width (even)"),
        )
        .property(
            Property::i64("height", 480)
                .int_range(1, 16384)
                .unit("px")
                .doc("Frame height (even for NV12)"),
        )
        .property(
            Property::i64("stride", 0)
                .int_range(0, 65536)
                .unit("bytes")
                .doc("Bytes per row (of the Y plane for NV12); 0: packed"),
        )
        .build()
    }
}

impl Component for FromYuv {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let layout = yuv_named(&ctx.text_property("format")?);
        let size = |name: &str| -> Result<usize, ComponentError> {
            Ok(usize::try_from(ctx.i64_property(name)?).unwrap_or(0))
        };
        let (width, height, stride) = (size("width")?, size("height")?, size("stride")?);
        if width % 2 == 1 || (layout == Yuv::Nv12 && height % 2 == 1) {
            return Err(ComponentError::failed(format_args!(
                "a {width}×{height} frame cannot be {}: chroma is shared by pairs of pixels, so the width{} must be even",
                if layout == Yuv::Nv12 { "NV12" } else { "YUYV" },
                if layout == Yuv::Nv12 { " and height" } else { "" }
            )));
        }
        let sample = ctx.read("in")?;
        let Payload::Bytes(bytes) = &sample.payload else {
            return Err(ComponentError::failed(format_args!(
                "input in expects a raw frame (bytes), got {}",
                sample.payload.data_type()
            )));
        };
        let needed = layout.frame_len(width, height, stride);
        if bytes.len() < needed {
            return Err(ComponentError::failed(format_args!(
                "a {width}×{height} {} frame needs {needed} bytes, this one has {}: check the width, height, stride and format",
                if layout == Yuv::Nv12 { "NV12" } else { "YUYV" },
                bytes.len()
            )));
        }
        let out = made(width, height, kairos_sdk::PixelFormat::Rgb8, |dst| {
            yuv::to_rgb(bytes, layout, (width, height, stride), dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.to_yuv`.
#[derive(Debug, Default)]
pub struct ToYuv {
    rgb: Vec<u8>,
}

impl ToYuv {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.to_yuv",
            "images",
            "Images as raw YUYV or NV12 frames (bytes), for encoders and displays that take them",
        )
        .label("Image to YUV frame")
        .input(
            "in",
            TypeFilter::only(DataType::Image),
            "An 8-bit image of even width (and height for NV12)",
        )
        .output("out", DataType::Bytes, "The packed frame, same timestamp")
        .property(
            Property::choice("format", &["yuyv", "nv12"], "nv12")
                .live()
                .doc("yuyv: 4:2:2 packed; nv12: 4:2:0 semi-planar"),
        )
        .build()
    }
}

impl Component for ToYuv {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let layout = yuv_named(&ctx.text_property("format")?);
        let sample = ctx.read("in")?;
        let (view, from) = view_of(image_of(&sample, "in")?, "vision.to_yuv")?;
        if view.width % 2 == 1 || (layout == Yuv::Nv12 && view.height % 2 == 1) {
            return Err(ComponentError::failed(format_args!(
                "a {}×{} image cannot become {}: chroma is shared by pairs of pixels; crop or resize it to even sides",
                view.width,
                view.height,
                if layout == Yuv::Nv12 { "NV12" } else { "YUYV" }
            )));
        }
        self.rgb.resize(view.width * view.height * 3, 0);
        color::convert(&view, from, Layout::Rgb, &mut self.rgb);
        let mut frame = vec![0_u8; layout.frame_len(view.width, view.height, 0)];
        yuv::from_rgb(&self.rgb, layout, (view.width, view.height), &mut frame);
        ctx.write_processed("out", &sample, Payload::Bytes(Arc::from(frame)))
    }
}

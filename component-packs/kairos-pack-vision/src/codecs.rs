//! JPEG components: images to JPEG bytes (to record or send compressed) and back.

use std::sync::Arc;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, TypeFilter,
};

use crate::image_io::{format_of, image_of, made, view_of};
use crate::kernels::color::Layout;
use crate::kernels::jpeg;

/// `vision.jpeg_encode`.
#[derive(Debug, Default)]
pub struct JpegEncode {
    buffer: Vec<u8>,
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
        .build()
    }
}

impl Component for JpegEncode {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let quality = ctx.i64_property("quality")?.clamp(1, 100) as u8;
        let sample = ctx.read("in")?;
        let (view, layout) = view_of(image_of(&sample, "in")?, "vision.jpeg_encode")?;
        self.buffer.clear();
        jpeg::encode(&view, layout, quality, &mut self.buffer).map_err(ComponentError::failed)?;
        ctx.write_processed("out", &sample, Payload::Bytes(Arc::from(self.buffer.as_slice())))
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

//! Between samples and kernels: an image input taken apart into a [`View`], checked against the
//! formats a component accepts (failing with the reason and the fix), and results made in the shared
//! pixel pool, or in place when the component alone holds the input's pixels.

use kairos_sdk::{ComponentError, Image, Payload, PixelFormat, PixelsMut, Sample};

use crate::kernels::View;
use crate::kernels::color::Layout;

/// The image in `sample`, or why it is not one.
pub fn image_of<'a>(sample: &'a Sample, input: &str) -> Result<&'a Image, ComponentError> {
    match &sample.payload {
        Payload::Image(image) => Ok(image),
        other => Err(ComponentError::failed(format_args!(
            "input {input} expects an image, got {}",
            other.data_type()
        ))),
    }
}

/// The byte layout of an 8-bit format (16-bit grey has none).
pub fn layout_of(format: PixelFormat) -> Option<Layout> {
    match format {
        PixelFormat::Gray8 => Some(Layout::Gray),
        PixelFormat::Rgb8 => Some(Layout::Rgb),
        PixelFormat::Bgr8 => Some(Layout::Bgr),
        PixelFormat::Rgba8 => Some(Layout::Rgba),
        PixelFormat::Bgra8 => Some(Layout::Bgra),
        PixelFormat::Gray16 => None,
    }
}

/// The pixel format of a layout.
pub fn format_of(layout: Layout) -> PixelFormat {
    match layout {
        Layout::Gray => PixelFormat::Gray8,
        Layout::Rgb => PixelFormat::Rgb8,
        Layout::Bgr => PixelFormat::Bgr8,
        Layout::Rgba => PixelFormat::Rgba8,
        Layout::Bgra => PixelFormat::Bgra8,
    }
}

/// A view of an 8-bit image's pixels, or a failure naming its format when it is 16-bit.
pub fn view_of<'a>(image: &'a Image, what: &str) -> Result<(View<'a>, Layout), ComponentError> {
    let layout = layout_of(image.format).ok_or_else(|| {
        ComponentError::failed(format_args!(
            "{what} works on 8-bit images, this one is {:?}: convert it first (vision.convert)",
            image.format
        ))
    })?;
    let view = View {
        width: image.width as usize,
        height: image.height as usize,
        channels: layout.channels(),
        stride: image.stride as usize,
        data: &image.pixels,
    };
    if !view.fits() {
        return Err(ComponentError::failed(format_args!(
            "the {}×{} image's buffer is shorter than its rows",
            image.width, image.height
        )));
    }
    Ok((view, layout))
}

/// A view of a grey 8-bit image, or a failure that says to convert it.
pub fn grey_view<'a>(image: &'a Image, what: &str) -> Result<View<'a>, ComponentError> {
    let (view, layout) = view_of(image, what)?;
    if layout != Layout::Gray {
        return Err(ComponentError::failed(format_args!(
            "{what} works on grey images, this one is {:?}: put a vision.convert with to = \"gray\" before it",
            image.format
        )));
    }
    Ok(view)
}

/// A new packed `width × height` image in `format`, its pixels written by `fill` into a buffer from
/// the shared pool.
pub fn made(
    width: usize,
    height: usize,
    format: PixelFormat,
    fill: impl FnOnce(&mut [u8]) -> Result<(), ComponentError>,
) -> Result<Image, ComponentError> {
    let len = width * height * format.bytes_per_pixel() as usize;
    let mut pixels = PixelsMut::new(len);
    fill(&mut pixels)?;
    Image::packed(
        u32::try_from(width).unwrap_or(u32::MAX),
        u32::try_from(height).unwrap_or(u32::MAX),
        format,
        pixels.freeze(),
    )
    .map_err(ComponentError::failed)
}

/// `image` transformed byte for byte by `apply`: in place when nothing else holds its pixels and its
/// rows are packed, else into a new buffer that starts as a copy.
pub fn transformed(image: Image, apply: impl FnOnce(&mut [u8])) -> Result<Image, ComponentError> {
    let packed_len = image.width as usize * image.height as usize * image.format.bytes_per_pixel() as usize;
    let Image {
        width,
        height,
        format,
        stride,
        pixels,
    } = image;
    let in_place = stride as usize * height as usize == packed_len;
    let mut writable = match pixels.try_into_mut() {
        Ok(writable) if in_place => writable,
        Ok(writable) => copy_packed(&writable, width, height, format, stride),
        Err(shared) => copy_packed(&shared, width, height, format, stride),
    };
    apply(&mut writable[..packed_len]);
    Image::packed(width, height, format, writable.freeze()).map_err(ComponentError::failed)
}

fn copy_packed(bytes: &[u8], width: u32, height: u32, format: PixelFormat, stride: u32) -> PixelsMut {
    let row = width as usize * format.bytes_per_pixel() as usize;
    let mut copy = PixelsMut::new(row * height as usize);
    if row > 0 {
        for (y, out) in copy.chunks_exact_mut(row).enumerate() {
            let start = y * stride as usize;
            out.copy_from_slice(&bytes[start..start + row]);
        }
    }
    copy
}

//! Camera pixel formats to RGB, as pure functions: YUYV (YUV 4:2:2, the format most USB cameras send
//! uncompressed; converted by the vision pack's kernel) and MJPEG (a JPEG per frame). Both write into a
//! buffer from the shared pixel pool, so a frame is converted once and then only shared.

use kairos_pack_vision::kernels::yuv::{self, Yuv};
use kairos_sdk::{Image, PixelFormat, PixelsMut};

/// Why a frame does not convert.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConvertError {
    /// The buffer is shorter than the size says.
    #[error("a {width}×{height} YUYV frame needs {needed} bytes, got {got}")]
    TooShort {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        got: usize,
    },
    /// YUYV needs an even width (two pixels share their chroma).
    #[error("YUYV needs an even width, got {0}")]
    OddWidth(u32),
    /// The JPEG does not decode.
    #[error("the JPEG frame does not decode: {0}")]
    Jpeg(String),
}

/// A YUYV frame (`Y0 U Y1 V` for each pair of pixels; `stride` bytes per row, at least `2 × width`) as
/// an RGB image.
///
/// # Errors
///
/// An odd width, or a buffer shorter than the size says.
pub fn yuyv_to_rgb(yuyv: &[u8], width: u32, height: u32, stride: u32) -> Result<Image, ConvertError> {
    if !width.is_multiple_of(2) {
        return Err(ConvertError::OddWidth(width));
    }
    let (w, h, stride) = (
        width as usize,
        height as usize,
        (stride as usize).max(2 * width as usize),
    );
    let needed = if h == 0 { 0 } else { stride * (h - 1) + 2 * w };
    if yuyv.len() < needed {
        return Err(ConvertError::TooShort {
            width,
            height,
            needed,
            got: yuyv.len(),
        });
    }
    let mut rgb = PixelsMut::new(w * h * 3);
    if w > 0 {
        yuv::to_rgb(yuyv, Yuv::Yuyv, (w, h, stride), &mut rgb);
    }
    Image::packed(width, height, PixelFormat::Rgb8, rgb.freeze())
        .map_err(|e| ConvertError::Jpeg(e.to_string()))
}

/// An MJPEG frame (one JPEG) as an RGB image.
///
/// # Errors
///
/// The frame does not decode.
pub fn mjpeg_to_rgb(jpeg: &[u8]) -> Result<Image, ConvertError> {
    /// 7680 × 4320 RGB.
    const LARGEST_FRAME_BYTES: usize = 7680 * 4320 * 3;
    use image::ImageDecoder as _;
    let decoder = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(jpeg))
        .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
    if decoder.color_type() == image::ColorType::Rgb8 {
        // Colour frames decode straight into the shared pixel pool: no copy after the decoder's.
        let (width, height) = decoder.dimensions();
        // A damaged header can claim any size: nothing larger than an 8K frame is a camera's.
        let bytes = usize::try_from(decoder.total_bytes())
            .ok()
            .filter(|bytes| *bytes <= LARGEST_FRAME_BYTES)
            .ok_or_else(|| {
                ConvertError::Jpeg(format!("a {width}×{height} frame is larger than cameras send"))
            })?;
        let mut rgb = PixelsMut::new(bytes);
        decoder
            .read_image(&mut rgb)
            .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
        return Image::packed(width, height, PixelFormat::Rgb8, rgb.freeze())
            .map_err(|e| ConvertError::Jpeg(e.to_string()));
    }
    // Grey frames (rare from cameras) go through the image crate's conversion.
    let grey = image::load_from_memory_with_format(jpeg, image::ImageFormat::Jpeg)
        .map_err(|e| ConvertError::Jpeg(e.to_string()))?
        .into_rgb8();
    let (width, height) = grey.dimensions();
    let mut rgb = PixelsMut::new(grey.as_raw().len());
    rgb.copy_from_slice(grey.as_raw());
    Image::packed(width, height, PixelFormat::Rgb8, rgb.freeze())
        .map_err(|e| ConvertError::Jpeg(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_black_white_and_primaries_convert_as_bt601_says() {
        // Four pixel pairs: black, white, and the limited-range codes of pure red and blue.
        let frame = [
            16, 128, 16, 128, // black
            235, 128, 235, 128, // white
            81, 90, 81, 240, // red (Y 81, U 90, V 240)
            41, 240, 41, 110, // blue (Y 41, U 240, V 110)
        ];
        let image = yuyv_to_rgb(&frame, 8, 1, 16).unwrap();
        let rgb = &image.pixels[..];
        let near = |got: &[u8], want: [u8; 3]| got.iter().zip(want).all(|(g, w)| g.abs_diff(w) <= 3);
        assert!(near(&rgb[0..3], [0, 0, 0]), "{rgb:?}");
        assert!(near(&rgb[6..9], [255, 255, 255]), "{rgb:?}");
        assert!(near(&rgb[12..15], [255, 0, 0]), "{rgb:?}");
        assert!(near(&rgb[18..21], [0, 0, 255]), "{rgb:?}");
    }

    #[test]
    fn yuyv_with_row_padding_skips_it_and_short_or_odd_frames_are_refused() {
        let mut frame = vec![128_u8; 2 * 16];
        frame[..8].copy_from_slice(&[235, 128, 235, 128, 235, 128, 235, 128]);
        let image = yuyv_to_rgb(&frame, 4, 2, 16).unwrap();
        assert_eq!(image.pixels.len(), 4 * 2 * 3);
        assert!(image.pixels[..12].iter().all(|&v| v >= 253));
        assert!(matches!(
            yuyv_to_rgb(&frame[..10], 4, 2, 16),
            Err(ConvertError::TooShort { .. })
        ));
        assert_eq!(
            yuyv_to_rgb(&frame, 3, 2, 16).unwrap_err(),
            ConvertError::OddWidth(3)
        );
    }

    #[test]
    fn an_mjpeg_frame_decodes_close_to_what_was_encoded_and_garbage_is_refused() {
        let source = image::RgbImage::from_fn(32, 16, |x, _| image::Rgb([(x * 8) as u8, 100, 200]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&source)
            .unwrap();
        let decoded = mjpeg_to_rgb(&jpeg).unwrap();
        assert_eq!((decoded.width, decoded.height), (32, 16));
        let error: u32 = decoded
            .pixels
            .iter()
            .zip(source.as_raw())
            .map(|(a, b)| u32::from(a.abs_diff(*b)))
            .max()
            .unwrap();
        assert!(error <= 12, "max error {error}");
        assert!(matches!(mjpeg_to_rgb(b"not a jpeg"), Err(ConvertError::Jpeg(_))));
    }
}

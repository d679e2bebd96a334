//! JPEG both ways: `jpeg-encoder` (baseline, 4:2:0 like OpenCV's default, AVX2 where the CPU has it)
//! and `zune-jpeg`.

use zune_core::bytestream::ZCursor;
use zune_core::colorspace::ColorSpace;
use zune_core::options::DecoderOptions;
use zune_jpeg::JpegDecoder;

use super::View;
use super::color::Layout;

/// Why a JPEG was not made or read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JpegError {
    /// JPEG sides are 16 bits.
    #[error("JPEG images are at most 65 535 pixels a side, this one is {0}×{1}")]
    TooLarge(usize, usize),
    /// The encoder refused.
    #[error("JPEG encoding failed: {0}")]
    Encode(String),
    /// The bytes are not a JPEG it can read.
    #[error("not a readable JPEG: {0}")]
    Decode(String),
}

/// `src` (in `layout`) as a JPEG of `quality` (1–100), appended to `out`.
pub fn encode(src: &View<'_>, layout: Layout, quality: u8, out: &mut Vec<u8>) -> Result<(), JpegError> {
    let too_large = || JpegError::TooLarge(src.width, src.height);
    let width = u16::try_from(src.width).map_err(|_| too_large())?;
    let height = u16::try_from(src.height).map_err(|_| too_large())?;
    let packed;
    let pixels = if let Some(pixels) = src.pixels() {
        pixels
    } else {
        packed = (0..src.height)
            .flat_map(|y| src.row(y).iter().copied())
            .collect::<Vec<u8>>();
        &packed
    };
    let color = match layout {
        Layout::Gray => jpeg_encoder::ColorType::Luma,
        Layout::Rgb => jpeg_encoder::ColorType::Rgb,
        Layout::Bgr => jpeg_encoder::ColorType::Bgr,
        Layout::Rgba => jpeg_encoder::ColorType::Rgba,
        Layout::Bgra => jpeg_encoder::ColorType::Bgra,
    };
    let mut encoder = jpeg_encoder::Encoder::new(out, quality.clamp(1, 100));
    // Chroma at half resolution both ways (4:2:0) at every quality, as OpenCV and most cameras do: the
    // encoder's own default keeps full chroma from quality 90, twice the data for little visible gain.
    encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::F_2_2);
    encoder
        .encode(pixels, width, height, color)
        .map_err(|e| JpegError::Encode(e.to_string()))
}

/// The size and layout a JPEG decodes to: (width, height, grey or RGB).
pub fn header(jpeg: &[u8]) -> Result<(usize, usize, Layout), JpegError> {
    let mut decoder = JpegDecoder::new(ZCursor::new(jpeg));
    decoder
        .decode_headers()
        .map_err(|e| JpegError::Decode(e.to_string()))?;
    let info = decoder
        .info()
        .ok_or_else(|| JpegError::Decode("no size".to_owned()))?;
    let (width, height) = (usize::from(info.width), usize::from(info.height));
    let layout = match decoder.input_colorspace() {
        Some(ColorSpace::Luma) => Layout::Gray,
        _ => Layout::Rgb,
    };
    Ok((width, height, layout))
}

/// Decodes `jpeg` into `out` as `layout` (grey or RGB), of the size [`header`] gives.
pub fn decode(jpeg: &[u8], layout: Layout, out: &mut [u8]) -> Result<(), JpegError> {
    let colorspace = if layout == Layout::Gray {
        ColorSpace::Luma
    } else {
        ColorSpace::RGB
    };
    let options = DecoderOptions::default()
        .jpeg_set_out_colorspace(colorspace)
        .set_max_width(1 << 16)
        .set_max_height(1 << 16);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(jpeg), options);
    decoder
        .decode_into(out)
        .map_err(|e| JpegError::Decode(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::{Layout, View, decode, encode, header};

    #[test]
    fn an_image_survives_encoding_and_decoding_within_the_quality_s_error() {
        let pixels: Vec<u8> = (0..64 * 48)
            .flat_map(|i| [(i % 64 * 4) as u8, (i / 64 * 5) as u8, 90])
            .collect();
        let view = View::packed(64, 48, 3, &pixels).unwrap();
        let mut jpeg = Vec::new();
        encode(&view, Layout::Rgb, 90, &mut jpeg).unwrap();
        assert_eq!(header(&jpeg).unwrap(), (64, 48, Layout::Rgb));
        let mut back = vec![0; pixels.len()];
        decode(&jpeg, Layout::Rgb, &mut back).unwrap();
        let worst = pixels
            .iter()
            .zip(&back)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(worst < 24, "{worst}");
        assert!(header(b"not a jpeg").is_err());
    }
}

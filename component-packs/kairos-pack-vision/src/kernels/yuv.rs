//! YUV frames as cameras and video codecs carry them, both ways: YUYV (4:2:2, packed `Y0 U Y1 V`) and
//! NV12 (4:2:0: a plane of Y, then a plane of interleaved U V at half the height). BT.601 limited range
//! (Y 16–235), the convention of USB cameras and of OpenCV's `COLOR_YUV2RGB_YUYV` and `_NV12`.

/// A YUV layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Yuv {
    /// 4:2:2 packed, two bytes per pixel.
    Yuyv,
    /// 4:2:0 semi-planar, a byte and a half per pixel.
    Nv12,
}

impl Yuv {
    /// Bytes of a `width × height` frame with rows of `stride` bytes (the luma rows' for NV12).
    pub fn frame_len(self, width: usize, height: usize, stride: usize) -> usize {
        match self {
            Yuv::Yuyv => stride.max(2 * width) * height,
            Yuv::Nv12 => stride.max(width) * (height + height.div_ceil(2)),
        }
    }
}

/// R, G, B of one pixel: 298 (Y − 16) + coefficients × (U − 128, V − 128), all scaled by 256.
#[inline]
fn rgb_of(luma: u8, u: i32, v: i32) -> [u8; 3] {
    let y = 298 * (i32::from(luma) - 16) + 128;
    let clamp = |value: i32| (value >> 8).clamp(0, 255) as u8;
    [
        clamp(y + 409 * v),
        clamp(y - 100 * u - 208 * v),
        clamp(y + 516 * u),
    ]
}

/// Y, U, V of one RGB pixel (BT.601 limited range, rounded).
#[inline]
fn yuv_of(red: u8, green: u8, blue: u8) -> (i32, i32, i32) {
    let (r, g, b) = (i32::from(red), i32::from(green), i32::from(blue));
    (
        ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16,
        ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128,
        ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128,
    )
}

/// A YUV frame (`width` even for YUYV, `width` and `height` even for NV12) into packed RGB.
pub fn to_rgb(frame: &[u8], layout: Yuv, (width, height, stride): (usize, usize, usize), rgb: &mut [u8]) {
    match layout {
        Yuv::Yuyv => {
            let stride = stride.max(2 * width);
            for (y, out) in rgb.chunks_exact_mut(3 * width).take(height).enumerate() {
                let line = &frame[y * stride..y * stride + 2 * width];
                for (pair, pixels) in line.chunks_exact(4).zip(out.chunks_exact_mut(6)) {
                    let (u, v) = (i32::from(pair[1]) - 128, i32::from(pair[3]) - 128);
                    pixels[..3].copy_from_slice(&rgb_of(pair[0], u, v));
                    pixels[3..].copy_from_slice(&rgb_of(pair[2], u, v));
                }
            }
        }
        Yuv::Nv12 => {
            let stride = stride.max(width);
            let chroma = &frame[stride * height..];
            for (y, out) in rgb.chunks_exact_mut(3 * width).take(height).enumerate() {
                let luma = &frame[y * stride..y * stride + width];
                let uv = &chroma[(y / 2) * stride..(y / 2) * stride + width];
                for ((pair, lumas), pixels) in uv
                    .chunks_exact(2)
                    .zip(luma.chunks_exact(2))
                    .zip(out.chunks_exact_mut(6))
                {
                    let (u, v) = (i32::from(pair[0]) - 128, i32::from(pair[1]) - 128);
                    pixels[..3].copy_from_slice(&rgb_of(lumas[0], u, v));
                    pixels[3..].copy_from_slice(&rgb_of(lumas[1], u, v));
                }
            }
        }
    }
}

/// Packed RGB (`width` even; `height` even for NV12) into a packed YUV frame; chroma is the mean of the
/// pixels that share it.
pub fn from_rgb(rgb: &[u8], layout: Yuv, (width, height): (usize, usize), frame: &mut [u8]) {
    let row = 3 * width;
    match layout {
        Yuv::Yuyv => {
            for (line, out) in rgb
                .chunks_exact(row)
                .zip(frame.chunks_exact_mut(2 * width))
                .take(height)
            {
                for (pixels, pair) in line.chunks_exact(6).zip(out.chunks_exact_mut(4)) {
                    let (y0, u0, v0) = yuv_of(pixels[0], pixels[1], pixels[2]);
                    let (y1, u1, v1) = yuv_of(pixels[3], pixels[4], pixels[5]);
                    pair.copy_from_slice(&[
                        y0 as u8,
                        ((u0 + u1 + 1) / 2) as u8,
                        y1 as u8,
                        ((v0 + v1 + 1) / 2) as u8,
                    ]);
                }
            }
        }
        Yuv::Nv12 => {
            let (luma, chroma) = frame.split_at_mut(width * height);
            for (y, line) in rgb.chunks_exact(row).take(height).enumerate() {
                for (x, pixel) in line.chunks_exact(3).enumerate() {
                    luma[y * width + x] = yuv_of(pixel[0], pixel[1], pixel[2]).0 as u8;
                }
            }
            for cy in 0..height / 2 {
                for cx in 0..width / 2 {
                    let (mut u, mut v) = (0, 0);
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let at = (2 * cy + dy) * row + (2 * cx + dx) * 3;
                        let (_, pu, pv) = yuv_of(rgb[at], rgb[at + 1], rgb[at + 2]);
                        u += pu;
                        v += pv;
                    }
                    chroma[cy * width + 2 * cx] = ((u + 2) / 4) as u8;
                    chroma[cy * width + 2 * cx + 1] = ((v + 2) / 4) as u8;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Yuv, from_rgb, to_rgb};

    #[test]
    fn colours_survive_a_round_trip_through_both_layouts() {
        // 4 × 2 pixels: pairs of one colour each, so shared chroma loses nothing.
        let colours: [[u8; 3]; 4] = [[255, 0, 0], [0, 200, 0], [20, 40, 220], [128, 128, 128]];
        let mut rgb = Vec::new();
        for _ in 0..2 {
            for c in [colours[0], colours[0], colours[1], colours[1]] {
                rgb.extend_from_slice(&c);
            }
        }
        let mut nv12_rgb = Vec::new();
        for _ in 0..2 {
            for c in [colours[2], colours[2], colours[3], colours[3]] {
                nv12_rgb.extend_from_slice(&c);
            }
        }
        for (layout, source) in [(Yuv::Yuyv, &rgb), (Yuv::Nv12, &nv12_rgb)] {
            let mut frame = vec![0; layout.frame_len(4, 2, 0)];
            from_rgb(source, layout, (4, 2), &mut frame);
            let mut back = vec![0; 4 * 2 * 3];
            to_rgb(&frame, layout, (4, 2, 0), &mut back);
            let worst = source
                .iter()
                .zip(&back)
                .map(|(a, b)| a.abs_diff(*b))
                .max()
                .unwrap();
            assert!(worst <= 3, "{layout:?}: {source:?} came back as {back:?}");
        }
        // Y of white and black in limited range.
        let mut frame = vec![0; 4];
        from_rgb(&[255, 255, 255, 0, 0, 0], Yuv::Yuyv, (2, 1), &mut frame);
        assert_eq!((frame[0], frame[2]), (235, 16));
    }
}

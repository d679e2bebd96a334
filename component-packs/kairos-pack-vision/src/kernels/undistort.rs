//! Lens undistortion: a pinhole camera with radial and tangential distortion (the Brown–Conrady model
//! OpenCV calibrates: k1, k2, k3 radial, p1, p2 tangential), read from a calibration file and applied
//! through a remap table computed once per image size.
//!
//! ```toml
//! # Intrinsics of the camera at this image size, pixels.
//! width = 640
//! height = 480
//! fx = 525.0
//! fy = 525.0
//! cx = 319.5
//! cy = 239.5
//! # Distortion (any left out is 0).
//! k1 = -0.28
//! k2 = 0.07
//! p1 = 0.0
//! p2 = 0.0
//! k3 = 0.0
//! ```

use std::path::Path;

use serde::Deserialize;
use toml::Spanned;

use super::View;

/// Why a calibration file was refused: `file:line:column: what`, and the fix where there is one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct CalibrationError(pub String);

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileFormat {
    width: Spanned<u32>,
    height: Spanned<u32>,
    fx: Spanned<f64>,
    fy: Spanned<f64>,
    cx: Spanned<f64>,
    cy: Spanned<f64>,
    #[serde(default)]
    k1: Option<Spanned<f64>>,
    #[serde(default)]
    k2: Option<Spanned<f64>>,
    #[serde(default)]
    k3: Option<Spanned<f64>>,
    #[serde(default)]
    p1: Option<Spanned<f64>>,
    #[serde(default)]
    p2: Option<Spanned<f64>>,
}

/// A calibrated camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// The image size the intrinsics are for.
    pub width: u32,
    /// The image height.
    pub height: u32,
    /// Focal lengths, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point, pixels.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Radial coefficients k1, k2, k3.
    pub radial: [f64; 3],
    /// Tangential coefficients p1, p2.
    pub tangential: [f64; 2],
}

impl Calibration {
    /// Reads and checks the calibration file at `path`.
    pub fn load(path: &Path) -> Result<Calibration, CalibrationError> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            CalibrationError(format!(
                "cannot read the calibration file {}: {e}",
                path.display()
            ))
        })?;
        Calibration::parse(&text, &path.display().to_string())
    }

    /// Parses and checks `text`; errors are located as `shown:line:column`.
    pub fn parse(text: &str, shown: &str) -> Result<Calibration, CalibrationError> {
        let at = |offset: usize, what: &str| {
            let (line, column) = kairos_sdk::text::line_column(text, offset);
            CalibrationError(format!("{shown}:{line}:{column}: {what}"))
        };
        let file: FileFormat =
            toml::from_str(text).map_err(|e| at(e.span().map_or(0, |s| s.start), e.message()))?;
        let finite = |value: &Spanned<f64>, name: &str| {
            if value.get_ref().is_finite() {
                Ok(*value.get_ref())
            } else {
                Err(at(value.span().start, &format!("{name} is not a finite number")))
            }
        };
        let optional =
            |value: &Option<Spanned<f64>>, name: &str| value.as_ref().map_or(Ok(0.0), |v| finite(v, name));
        for (value, name) in [(&file.width, "width"), (&file.height, "height")] {
            if *value.get_ref() == 0 {
                return Err(at(
                    value.span().start,
                    &format!("{name} must be at least 1 pixel"),
                ));
            }
        }
        for (value, name) in [(&file.fx, "fx"), (&file.fy, "fy")] {
            if finite(value, name)? <= 0.0 {
                return Err(at(
                    value.span().start,
                    &format!("the focal length {name} must be positive (pixels)"),
                ));
            }
        }
        let (width, height) = (*file.width.get_ref(), *file.height.get_ref());
        for (value, name, side) in [(&file.cx, "cx", width), (&file.cy, "cy", height)] {
            let v = finite(value, name)?;
            if !(0.0..=f64::from(side)).contains(&v) {
                return Err(at(
                    value.span().start,
                    &format!("the principal point {name} = {v} lies outside the image (0 to {side})"),
                ));
            }
        }
        Ok(Calibration {
            width,
            height,
            fx: *file.fx.get_ref(),
            fy: *file.fy.get_ref(),
            cx: *file.cx.get_ref(),
            cy: *file.cy.get_ref(),
            radial: [
                optional(&file.k1, "k1")?,
                optional(&file.k2, "k2")?,
                optional(&file.k3, "k3")?,
            ],
            tangential: [optional(&file.p1, "p1")?, optional(&file.p2, "p2")?],
        })
    }

    /// Where the ideal (undistorted) pixel (u, v) lies in the distorted image.
    pub fn distorted(&self, u: f64, v: f64) -> (f64, f64) {
        let (x, y) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let r2 = x * x + y * y;
        let [k1, k2, k3] = self.radial;
        let [p1, p2] = self.tangential;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        (self.fx * xd + self.cx, self.fy * yd + self.cy)
    }
}

/// Steps of a pixel the source position is rounded to, as OpenCV's `remap` does (`INTER_BITS` = 5).
const STEPS: u16 = 32;
/// The bits of the bilinear weights, which always sum to `1 << WEIGHT_BITS`.
const WEIGHT_BITS: u32 = 10;

/// One destination pixel's source: the top-left of its 2×2 neighbourhood (`None`: outside, black) and
/// the bilinear weights in 10-bit fixed point, summing to exactly 1024.
#[derive(Debug, Clone, Copy)]
struct Tap {
    source: Option<(u32, u32)>,
    weights: [u16; 4],
}

/// A remap table for one image size.
#[derive(Debug, Clone)]
pub struct Undistortion {
    width: usize,
    height: usize,
    taps: Vec<Tap>,
}

impl Undistortion {
    /// The table for `calibration` at its own image size.
    pub fn new(calibration: &Calibration) -> Self {
        let (width, height) = (calibration.width as usize, calibration.height as usize);
        let mut taps = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                let (x, y) = calibration.distorted(u as f64, v as f64);
                let (x0, y0) = (x.floor(), y.floor());
                let inside = x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < width as f64 && y0 + 1.0 < height as f64;
                // The fractions in 1/32 of a pixel: products of whole steps sum to exactly 32², so a
                // uniform image stays uniform (rounding each weight on its own can sum to more, and wrap).
                let step = |f: f64| ((f * f64::from(STEPS)).round() as u16).min(STEPS);
                let (ax, ay) = (step(x - x0), step(y - y0));
                let (bx, by) = (STEPS - ax, STEPS - ay);
                taps.push(Tap {
                    source: inside.then_some((x0 as u32, y0 as u32)),
                    weights: [bx * by, ax * by, bx * ay, ax * ay],
                });
            }
        }
        Undistortion { width, height, taps }
    }

    /// The image size it is for.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Undistorts `src` (of this size) into the packed `dst`.
    pub fn apply(&self, src: &View<'_>, dst: &mut [u8]) {
        let channels = src.channels;
        for (tap, out) in self.taps.iter().zip(dst.chunks_exact_mut(channels.max(1))) {
            let Some((x, y)) = tap.source else {
                out.fill(0);
                continue;
            };
            let (x, y) = (x as usize, y as usize);
            let (top, bottom) = (src.row(y), src.row(y + 1));
            for (c, value) in out.iter_mut().enumerate() {
                let at = x * channels + c;
                let sum = u32::from(top[at]) * u32::from(tap.weights[0])
                    + u32::from(top[at + channels]) * u32::from(tap.weights[1])
                    + u32::from(bottom[at]) * u32::from(tap.weights[2])
                    + u32::from(bottom[at + channels]) * u32::from(tap.weights[3]);
                *value = ((sum + (1 << (WEIGHT_BITS - 1))) >> WEIGHT_BITS) as u8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Calibration, Undistortion, View};

    const CAMERA: &str = "width = 64\nheight = 48\nfx = 50.0\nfy = 50.0\ncx = 32.0\ncy = 24.0\nk1 = -0.3\nk2 = 0.1\np1 = 0.001\n";

    #[test]
    fn a_point_where_the_lens_put_it_comes_back_where_a_pinhole_would_see_it() {
        let calibration = Calibration::parse(CAMERA, "cam.toml").unwrap();
        // A dot at the distorted position of the ideal pixel (56, 40), near a corner where the lens
        // bends most.
        let (x, y) = calibration.distorted(56.0, 40.0);
        assert!((x - 56.0).abs() > 2.0, "the lens moves it noticeably: {x}");
        let mut pixels = vec![0_u8; 64 * 48];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            pixels[(y.floor() as usize + dy) * 64 + x.floor() as usize + dx] = 250;
        }
        let view = View::packed(64, 48, 1, &pixels).unwrap();
        let mut out = vec![0; 64 * 48];
        Undistortion::new(&calibration).apply(&view, &mut out);
        assert_eq!(out[40 * 64 + 56], 250);
        // No distortion: the image passes unchanged.
        let plain = Calibration {
            radial: [0.0; 3],
            tangential: [0.0; 2],
            ..calibration
        };
        let ramp: Vec<u8> = (0..64 * 48).map(|i| (i % 251) as u8).collect();
        let view = View::packed(64, 48, 1, &ramp).unwrap();
        Undistortion::new(&plain).apply(&view, &mut out);
        let inner = |image: &[u8]| {
            (0..47)
                .flat_map(|y| (0..63).map(move |x| (x, y)))
                .map(|(x, y)| image[y * 64 + x])
                .collect::<Vec<u8>>()
        };
        assert_eq!(inner(&out), inner(&ramp));
    }

    #[test]
    fn a_uniform_image_stays_uniform_wherever_its_pixels_come_from() {
        let calibration = Calibration::parse(CAMERA, "cam.toml").unwrap();
        let table = Undistortion::new(&calibration);
        let undistorted = |level: u8| {
            let src = vec![level; 64 * 48];
            let mut dst = vec![0_u8; 64 * 48];
            table.apply(&View::packed(64, 48, 1, &src).unwrap(), &mut dst);
            dst
        };
        // Black only where the source is outside the image, the same pixels whatever the level; elsewhere
        // the level, exactly (a white pixel never wraps to black).
        let outside: Vec<bool> = undistorted(1).iter().map(|v| *v == 0).collect();
        assert!(outside.iter().filter(|o| !**o).count() > 64 * 48 / 2);
        for level in [255_u8, 254, 128, 1] {
            for (at, (value, outside)) in undistorted(level).iter().zip(&outside).enumerate() {
                let expected = if *outside { 0 } else { level };
                assert_eq!(*value, expected, "level {level} at pixel {at}");
            }
        }
    }

    #[test]
    fn calibration_files_with_errors_are_refused_with_the_place() {
        let cases = [
            (
                CAMERA.replace("fx = 50.0", "fx = -50.0"),
                "cam.toml:3:6",
                "positive",
            ),
            (
                CAMERA.replace("cx = 32.0", "cx = 320.0"),
                "cam.toml:5:6",
                "outside the image",
            ),
            (
                CAMERA.replace("k1 = -0.3", "k1 = nan"),
                "cam.toml:7:6",
                "not a finite number",
            ),
            (CAMERA.replace("k2", "kk2"), "cam.toml:8:1", "unknown field"),
            (
                CAMERA.replace("fy = 50.0\n", ""),
                "cam.toml:1:1",
                "missing field `fy`",
            ),
            (
                CAMERA.replace("width = 64", "width = \"wide\""),
                "cam.toml:1:9",
                "invalid type",
            ),
        ];
        for (text, place, words) in cases {
            let error = Calibration::parse(&text, "cam.toml").unwrap_err().0;
            assert!(error.starts_with(place) && error.contains(words), "{error}");
        }
    }
}

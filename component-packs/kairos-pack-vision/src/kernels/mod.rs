//! The image kernels, as pure functions on byte rows: no component, no context, so each can be tested
//! and benchmarked alone. Sources are [`View`]s (any stride); destinations are packed rows
//! (`width × channels` bytes each) that the caller allocates, usually from the shared pixel pool.
//!
//! Hot loops are written so the compiler vectorises them (fixed-point integers, no bounds checks in the
//! inner loop) and are compiled twice by `multiversion`: for AVX2 and for baseline x86-64. The one
//! exception is bilinear resizing's gather across a row ([`linear`]), which no compiler vectorises: it is
//! written with AVX2 intrinsics, next to the portable loop that gives the same values elsewhere.

pub mod color;
pub mod draw;
pub mod edges;
pub mod filter;
pub mod geometry;
pub mod hough;
pub mod jpeg;
pub mod linear;
pub mod turbojpeg;
pub mod undistort;
pub mod yuv;

/// Borrowed pixels: `height` rows of `width × channels` bytes, `stride` bytes apart.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Bytes per pixel.
    pub channels: usize,
    /// Bytes from one row's start to the next's.
    pub stride: usize,
    /// At least `stride × (height − 1) + width × channels` bytes.
    pub data: &'a [u8],
}

impl<'a> View<'a> {
    /// A tightly packed view; `None` when `data` is too short.
    pub fn packed(width: usize, height: usize, channels: usize, data: &'a [u8]) -> Option<Self> {
        let view = View {
            width,
            height,
            channels,
            stride: width * channels,
            data,
        };
        view.fits().then_some(view)
    }

    /// Whether `data` holds every row.
    pub fn fits(&self) -> bool {
        self.height == 0
            || self.stride >= self.row_bytes()
                && self.data.len() >= self.stride * (self.height - 1) + self.row_bytes()
    }

    /// Bytes of pixels in one row.
    pub fn row_bytes(&self) -> usize {
        self.width * self.channels
    }

    /// Row `y`'s pixels (empty past the end).
    #[inline]
    pub fn row(&self, y: usize) -> &'a [u8] {
        let start = y * self.stride;
        self.data.get(start..start + self.row_bytes()).unwrap_or_default()
    }

    /// Whether rows follow each other with no gap, so the pixels are one slice.
    pub fn is_packed(&self) -> bool {
        self.stride == self.row_bytes()
    }

    /// All pixels as one slice, when packed.
    pub fn pixels(&self) -> Option<&'a [u8]> {
        self.data
            .get(..self.row_bytes() * self.height)
            .filter(|_| self.is_packed())
    }

    /// All pixels as one slice: borrowed when packed, else its rows copied together.
    pub fn contiguous(&self) -> std::borrow::Cow<'a, [u8]> {
        match self.pixels() {
            Some(pixels) => std::borrow::Cow::Borrowed(pixels),
            None => (0..self.height)
                .flat_map(|y| self.row(y).iter().copied())
                .collect(),
        }
    }
}

/// Row `y` reflected into `0..height` the way OpenCV's default border does (`gfedcb|abcdefgh|gfedcba`),
/// so results match it at the edges.
#[inline]
pub(crate) fn reflect_101(y: isize, height: usize) -> usize {
    let last = height as isize - 1;
    if last <= 0 {
        return 0;
    }
    let mut y = y;
    loop {
        if y < 0 {
            y = -y;
        } else if y > last {
            y = 2 * last - y;
        } else {
            return y as usize;
        }
    }
}

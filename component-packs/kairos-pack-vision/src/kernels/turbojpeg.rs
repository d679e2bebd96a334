//! libjpeg-turbo's `TurboJPEG` API, loaded from the system at run time where it is installed (Debian and
//! Ubuntu: `libturbojpeg0`; Fedora: `turbojpeg`): the same encoder OpenCV uses, with its hand-written
//! SIMD DCT and Huffman coding, about three times faster than the pure-Rust encoder.
//!
//! Decision: loaded with `dlopen`, not linked. The first build of Kairos needs no C library, NASM or
//! `pkg-config`, and a machine without the library still encodes (with `jpeg-encoder`); where it is
//! there, it is used. Only the five functions of the `TurboJPEG` 2 API that compressing needs are called,
//! whose signatures have been stable since libjpeg-turbo 1.2.
#![allow(
    unsafe_code,
    reason = "calling a C library loaded at run time; each call says why it is sound"
)]

use std::ffi::{CStr, c_char, c_int, c_uchar, c_ulong, c_void};
use std::sync::OnceLock;

use super::View;
use super::color::Layout;
use super::jpeg::JpegError;

type Handle = *mut c_void;

/// The functions used, from the library found.
struct Api {
    init_compress: unsafe extern "C" fn() -> Handle,
    #[allow(
        clippy::type_complexity,
        reason = "the C signature as turbojpeg.h declares it"
    )]
    compress2: unsafe extern "C" fn(
        Handle,
        *const c_uchar,
        c_int,
        c_int,
        c_int,
        c_int,
        *mut *mut c_uchar,
        *mut c_ulong,
        c_int,
        c_int,
        c_int,
    ) -> c_int,
    buf_size: unsafe extern "C" fn(c_int, c_int, c_int) -> c_ulong,
    destroy: unsafe extern "C" fn(Handle) -> c_int,
    error_text: unsafe extern "C" fn(Handle) -> *mut c_char,
    /// Kept loaded for as long as the process runs: the functions above point into it.
    _library: libloading::Library,
}

/// turbojpeg.h's pixel formats, subsamplings and flags used here.
const TJPF_RGB: c_int = 0;
const TJPF_BGR: c_int = 1;
const TJPF_GRAY: c_int = 6;
const TJPF_RGBA: c_int = 7;
const TJPF_BGRA: c_int = 8;
const TJSAMP_420: c_int = 2;
const TJSAMP_GRAY: c_int = 3;
/// Write into the buffer given, never reallocate it (it is sized with `tjBufSize`).
const TJFLAG_NOREALLOC: c_int = 1024;
/// The accurate integer DCT (libjpeg's `JDCT_ISLOW`), as OpenCV uses: `TurboJPEG` 2 defaults to the fast
/// one, whose pixels differ (by 2 levels on average on a noisy image at quality 90).
const TJFLAG_ACCURATEDCT: c_int = 4096;

/// The library's file names, the versioned one first (the unversioned link comes with the -dev package).
const NAMES: [&str; 2] = ["libturbojpeg.so.0", "libturbojpeg.so"];

fn api() -> Option<&'static Api> {
    static API: OnceLock<Option<Api>> = OnceLock::new();
    API.get_or_init(|| NAMES.iter().find_map(|name| load(name)))
        .as_ref()
}

fn load(name: &str) -> Option<Api> {
    // SAFETY: loading libturbojpeg runs no initialisation code with preconditions of its own.
    let library = unsafe { libloading::Library::new(name) }.ok()?;
    // SAFETY: each symbol is declared with the signature turbojpeg.h gives it (`TurboJPEG` 2 API), and the
    // pointers are used only while `library`, stored beside them, stays loaded.
    unsafe {
        Some(Api {
            init_compress: *library.get(b"tjInitCompress\0").ok()?,
            compress2: *library.get(b"tjCompress2\0").ok()?,
            buf_size: *library.get(b"tjBufSize\0").ok()?,
            destroy: *library.get(b"tjDestroy\0").ok()?,
            error_text: *library.get(b"tjGetErrorStr2\0").ok()?,
            _library: library,
        })
    }
}

/// Whether libjpeg-turbo can be loaded on this machine.
pub fn available() -> bool {
    api().is_some()
}

/// One `TurboJPEG` compressor: used by one component at a time, as the library requires.
pub struct Compressor {
    api: &'static Api,
    handle: Handle,
}

impl std::fmt::Debug for Compressor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Compressor(libjpeg-turbo)")
    }
}

// SAFETY: a `TurboJPEG` handle may move between threads; it is used by one at a time (`&mut self`).
unsafe impl Send for Compressor {}

impl Compressor {
    /// A compressor, where the library is installed.
    pub fn new() -> Option<Self> {
        let api = api()?;
        // SAFETY: no arguments; a null handle is an allocation failure, refused here.
        let handle = unsafe { (api.init_compress)() };
        (!handle.is_null()).then_some(Compressor { api, handle })
    }

    /// `src` (in `layout`) as a baseline JPEG of `quality` (1–100), 4:2:0 chroma (grey: one component),
    /// appended to `out`.
    pub fn encode(
        &mut self,
        src: &View<'_>,
        layout: Layout,
        quality: u8,
        out: &mut Vec<u8>,
    ) -> Result<(), JpegError> {
        let too_large = || JpegError::TooLarge(src.width, src.height);
        let width = c_int::try_from(src.width).map_err(|_| too_large())?;
        let height = c_int::try_from(src.height).map_err(|_| too_large())?;
        let pitch = c_int::try_from(src.stride).map_err(|_| too_large())?;
        if src.width > 65_535 || src.height > 65_535 {
            return Err(too_large());
        }
        let (format, subsampling) = match layout {
            Layout::Gray => (TJPF_GRAY, TJSAMP_GRAY),
            Layout::Rgb => (TJPF_RGB, TJSAMP_420),
            Layout::Bgr => (TJPF_BGR, TJSAMP_420),
            Layout::Rgba => (TJPF_RGBA, TJSAMP_420),
            Layout::Bgra => (TJPF_BGRA, TJSAMP_420),
        };
        if src.channels != layout.channels() || !src.fits() {
            return Err(JpegError::Encode("the pixels do not fill the image".to_owned()));
        }
        // SAFETY: plain arithmetic on the sizes given.
        let most = unsafe { (self.api.buf_size)(width, height, subsampling) };
        let most = usize::try_from(most).map_err(|_| too_large())?;
        out.reserve(most);
        let start = out.len();
        let mut written: c_ulong = c_ulong::try_from(out.capacity() - start).unwrap_or(c_ulong::MAX);
        // SAFETY: `start` is within the allocation, which has `written` bytes free after it.
        let mut destination = unsafe { out.as_mut_ptr().add(start) };
        let expected = destination;
        // SAFETY: `src.data` holds `height` rows of `width × channels` bytes, `pitch` apart (checked by
        // `fits`); `destination` has `written` ≥ tjBufSize bytes, and NOREALLOC keeps the library from
        // freeing or replacing it; `self.handle` is a live compressor used by this thread alone.
        let failed = unsafe {
            (self.api.compress2)(
                self.handle,
                src.data.as_ptr(),
                width,
                pitch,
                height,
                format,
                &raw mut destination,
                &raw mut written,
                subsampling,
                c_int::from(quality.clamp(1, 100)),
                TJFLAG_NOREALLOC | TJFLAG_ACCURATEDCT,
            )
        };
        if failed != 0 || destination != expected {
            // SAFETY: the handle is live; the text is the library's, valid until its next call.
            let reason = unsafe { CStr::from_ptr((self.api.error_text)(self.handle)) };
            return Err(JpegError::Encode(reason.to_string_lossy().into_owned()));
        }
        let written = usize::try_from(written).unwrap_or(0).min(out.capacity() - start);
        // SAFETY: the library wrote `written` bytes from `start`, within the capacity.
        unsafe { out.set_len(start + written) };
        Ok(())
    }
}

impl Drop for Compressor {
    fn drop(&mut self) {
        // SAFETY: the handle came from tjInitCompress and is destroyed once.
        unsafe { (self.api.destroy)(self.handle) };
    }
}

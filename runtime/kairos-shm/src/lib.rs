//! Pixel buffers in shared memory: how a runtime's images reach a client on its machine without a copy.
//!
//! A producer (a camera) renders straight into a [`SharedBuffer`], an anonymous shared-memory file
//! (Linux `memfd`) that the runtime maps. A client on the same machine whose subscription asked for
//! `shared_pixels` receives, instead of the pixels, a [`PixelsReference`]: the runtime's process id, the
//! buffer's file descriptor there, and the buffer's identity and generation. [`SharedPixelsReader`] maps
//! `/proc/PID/fd/FD` read-only (once per buffer: the runtime recycles a few buffers) and copies the pixels
//! out.
//!
//! Buffers are recycled, so the reader must know that the pixels it copied are still the frame it was
//! told about. Each buffer starts with a header whose `generation` works as a sequence lock: odd while the
//! owner writes, even once the pixels are final. The reader checks the generation before and after its
//! copy; a buffer rewritten meanwhile gives [`SharedPixelsError::Replaced`], never torn pixels. The runtime
//! keeps a published frame alive at least until it publishes the next one, so this happens only to a
//! client that fell a whole frame period behind.
//!
//! Layout of the file: a 64-byte header (`magic`, `id`, `len`, `generation`: four little-endian u64), then
//! `len` bytes of pixels.

#![allow(
    unsafe_code,
    reason = "mapping a shared-memory file and reading the header's atomics and the pixels in place"
)]

use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

/// Bytes before the pixels in a buffer's file.
pub const HEADER_LEN: usize = 64;

/// The first eight bytes of every buffer's file.
const MAGIC: u64 = u64::from_le_bytes(*b"KPIXBUF1");

/// How many buffers a reader keeps mapped before it unmaps them all and starts over.
const READER_MAPPINGS: usize = 32;

/// Where an image's pixels lie in the runtime's shared memory, as a frame header names them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PixelsReference {
    /// The runtime's process id.
    pub pid: u32,
    /// The buffer's file descriptor in that process (`/proc/PID/fd/FD`).
    pub fd: i32,
    /// The buffer's identity, unique within the process (a descriptor number is reused, an id never).
    pub id: u64,
    /// The generation holding this frame's pixels (even).
    pub generation: u64,
    /// The pixels' length in bytes.
    pub len: u64,
}

/// Why shared pixels could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SharedPixelsError {
    /// The buffer could not be opened or mapped (another user's runtime, a process that ended).
    #[error("cannot map the runtime's pixel buffer {path}: {reason}")]
    Unreachable {
        /// `/proc/PID/fd/FD`.
        path: String,
        /// What the system said.
        reason: String,
    },
    /// The file is not a pixel buffer, or not the one named.
    #[error("{path} is not the pixel buffer the frame names")]
    NotTheBuffer {
        /// `/proc/PID/fd/FD`.
        path: String,
    },
    /// The runtime reused the buffer for a newer frame before the copy ended.
    #[error("the frame's pixels were replaced by a newer frame before they could be read")]
    Replaced,
    /// Shared pixel buffers exist on Linux only.
    #[error("shared pixel buffers need Linux")]
    Unsupported,
}

/// The header at the start of a buffer's file.
#[repr(C)]
struct Header {
    magic: AtomicU64,
    id: AtomicU64,
    len: AtomicU64,
    generation: AtomicU64,
}

const _: () = assert!(size_of::<Header>() <= HEADER_LEN);

/// A mapping of a whole buffer file, unmapped on drop.
#[derive(Debug)]
struct Mapping {
    start: std::ptr::NonNull<u8>,
    len: usize,
}

// SAFETY: the mapping is plain memory owned by this value; the header is only touched through atomics and
// the pixels through `&`/`&mut` borrows of the owning buffer, so sharing it between threads is sound.
unsafe impl Send for Mapping {}
// SAFETY: as for `Send`.
unsafe impl Sync for Mapping {}

impl Mapping {
    #[allow(
        clippy::cast_ptr_alignment,
        reason = "a mapping starts on a page boundary, aligned for any header"
    )]
    fn header(&self) -> &Header {
        // SAFETY: every mapping is at least HEADER_LEN bytes (checked when made), page-aligned, and the
        // header's fields are atomics, valid for any bit pattern.
        unsafe { &*self.start.as_ptr().cast::<Header>() }
    }

    fn pixels_ptr(&self) -> *mut u8 {
        // SAFETY: HEADER_LEN is within the mapping (checked when made).
        unsafe { self.start.as_ptr().add(HEADER_LEN) }
    }
}

#[cfg(target_os = "linux")]
mod sys {
    use std::ffi::CString;
    use std::io;
    use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

    use super::Mapping;

    pub fn memfd(name: &str, len: usize) -> io::Result<OwnedFd> {
        let name = CString::new(name).map_err(io::Error::other)?;
        // SAFETY: a valid C string; the returned descriptor is checked and then owned.
        let raw = unsafe { libc::memfd_create(name.as_ptr(), libc::MFD_CLOEXEC) };
        if raw < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `raw` is a fresh descriptor that nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        let size = libc::off_t::try_from(len).map_err(io::Error::other)?;
        // SAFETY: plain system calls on a descriptor we own. `fallocate` reserves the pages now, so running
        // out of memory is an error here rather than a SIGBUS when the pixels are first written.
        unsafe {
            if libc::ftruncate(fd.as_raw_fd(), size) != 0 {
                return Err(io::Error::last_os_error());
            }
            if libc::fallocate(fd.as_raw_fd(), 0, 0, size) != 0 {
                return Err(io::Error::last_os_error());
            }
        }
        Ok(fd)
    }

    pub fn map(fd: &OwnedFd, len: usize, writable: bool) -> io::Result<Mapping> {
        let protection = if writable {
            libc::PROT_READ | libc::PROT_WRITE
        } else {
            libc::PROT_READ
        };
        // SAFETY: a new shared mapping of `len` bytes of a file we hold open; checked for failure.
        let start = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                protection,
                libc::MAP_SHARED,
                fd.as_raw_fd(),
                0,
            )
        };
        if start == libc::MAP_FAILED {
            return Err(io::Error::last_os_error());
        }
        let start =
            std::ptr::NonNull::new(start.cast::<u8>()).ok_or_else(|| io::Error::other("mmap gave null"))?;
        Ok(Mapping { start, len })
    }

    pub fn file_len(fd: &OwnedFd) -> io::Result<usize> {
        let file = std::fs::File::from(fd.try_clone()?);
        usize::try_from(file.metadata()?.len()).map_err(io::Error::other)
    }

    impl Drop for Mapping {
        fn drop(&mut self) {
            // SAFETY: the mapping was made by `map` with this start and length and is unmapped only here.
            unsafe {
                libc::munmap(self.start.as_ptr().cast(), self.len);
            }
        }
    }
}

#[cfg(not(target_os = "linux"))]
impl Drop for Mapping {
    fn drop(&mut self) {}
}

/// A pixel buffer in shared memory, owned by the runtime: written while it is `&mut`, then read by the
/// runtime and, through [`PixelsReference`]s, by clients on its machine.
#[derive(Debug)]
pub struct SharedBuffer {
    mapping: Mapping,
    #[cfg(target_os = "linux")]
    fd: std::os::fd::OwnedFd,
    id: u64,
    len: usize,
}

impl SharedBuffer {
    /// A new buffer of `len` bytes of pixels (zeros), ready to be written.
    #[cfg(target_os = "linux")]
    pub fn create(len: usize) -> std::io::Result<Self> {
        static NEXT_ID: AtomicU64 = AtomicU64::new(1);
        let file_len = HEADER_LEN
            .checked_add(len)
            .ok_or_else(|| std::io::Error::other("pixel buffer too large"))?;
        let fd = sys::memfd("kairos-pixels", file_len)?;
        let mapping = sys::map(&fd, file_len, true)?;
        let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
        let header = mapping.header();
        header.id.store(id, Ordering::Relaxed);
        header.len.store(len as u64, Ordering::Relaxed);
        header.generation.store(1, Ordering::Relaxed);
        header.magic.store(MAGIC, Ordering::Release);
        Ok(SharedBuffer { mapping, fd, id, len })
    }

    /// Shared pixel buffers exist on Linux only.
    #[cfg(not(target_os = "linux"))]
    pub fn create(_len: usize) -> std::io::Result<Self> {
        Err(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "shared pixel buffers need Linux",
        ))
    }

    /// The pixels' length in bytes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the buffer holds no pixels.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Starts rewriting a buffer whose earlier pixels may still be referenced: readers of an earlier
    /// generation will see [`SharedPixelsError::Replaced`].
    pub fn begin_write(&mut self) {
        let generation = &self.mapping.header().generation;
        let current = generation.load(Ordering::Relaxed);
        if current.is_multiple_of(2) {
            generation.store(current + 1, Ordering::Relaxed);
            // Readers that see any of the new pixels must also see the odd generation.
            std::sync::atomic::fence(Ordering::Release);
        }
    }

    /// Ends writing: the pixels are final under a new even generation.
    pub fn end_write(&mut self) {
        let generation = &self.mapping.header().generation;
        let current = generation.load(Ordering::Relaxed);
        if !current.is_multiple_of(2) {
            generation.store(current + 1, Ordering::Release);
        }
    }

    /// The pixels.
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: `len` bytes after the header lie within the mapping; this process writes them only
        // through `bytes_mut`, which needs `&mut self`.
        unsafe { std::slice::from_raw_parts(self.mapping.pixels_ptr(), self.len) }
    }

    /// The pixels, to write.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as in `bytes`, and `&mut self` makes this the only borrow in this process. Clients map
        // the file read-only; the one other writer, a Python component's worker, writes only a buffer the
        // runtime handed it before freezing, and the runtime reads none of it until the worker has written.
        unsafe { std::slice::from_raw_parts_mut(self.mapping.pixels_ptr(), self.len) }
    }

    /// How a client on this machine finds the pixels as they are now.
    pub fn reference(&self) -> PixelsReference {
        #[cfg(target_os = "linux")]
        let fd = std::os::fd::AsRawFd::as_raw_fd(&self.fd);
        #[cfg(not(target_os = "linux"))]
        let fd = -1;
        PixelsReference {
            pid: std::process::id(),
            fd,
            id: self.id,
            generation: self.mapping.header().generation.load(Ordering::Acquire),
            len: self.len as u64,
        }
    }
}

/// Copies pixels out of a runtime's shared buffers, keeping the buffers it has seen mapped.
#[derive(Debug, Default)]
pub struct SharedPixelsReader {
    mappings: std::collections::HashMap<(u32, i32), (u64, Mapping)>,
}

impl SharedPixelsReader {
    /// A reader with nothing mapped yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The pixels `reference` names, copied out of the runtime's buffer.
    pub fn read(&mut self, reference: &PixelsReference) -> Result<Vec<u8>, SharedPixelsError> {
        let key = (reference.pid, reference.fd);
        let current = self.mappings.get(&key).is_some_and(|(id, _)| *id == reference.id);
        if !current {
            self.mappings.remove(&key);
            if self.mappings.len() >= READER_MAPPINGS {
                self.mappings.clear();
            }
            let mapping = Self::open(reference)?;
            self.mappings.insert(key, (reference.id, mapping));
        }
        let (_, mapping) = self.mappings.get(&key).ok_or(SharedPixelsError::Replaced)?;
        let len = usize::try_from(reference.len).map_err(|_| SharedPixelsError::Replaced)?;
        if HEADER_LEN.checked_add(len).is_none_or(|end| end > mapping.len) {
            return Err(SharedPixelsError::NotTheBuffer {
                path: proc_path(reference),
            });
        }
        let generation = &mapping.header().generation;
        if generation.load(Ordering::Acquire) != reference.generation {
            return Err(SharedPixelsError::Replaced);
        }
        let mut pixels = Vec::with_capacity(len);
        // SAFETY: `len` bytes after the header lie within the mapping (checked above) and `pixels` has room
        // for them. The runtime may rewrite them meanwhile (it recycles buffers); the generation check
        // after the copy throws such a copy away, the sequence lock's usual rule.
        unsafe {
            std::ptr::copy_nonoverlapping(mapping.pixels_ptr(), pixels.as_mut_ptr(), len);
            pixels.set_len(len);
        }
        std::sync::atomic::fence(Ordering::Acquire);
        if generation.load(Ordering::Relaxed) != reference.generation {
            return Err(SharedPixelsError::Replaced);
        }
        Ok(pixels)
    }

    #[cfg(target_os = "linux")]
    fn open(reference: &PixelsReference) -> Result<Mapping, SharedPixelsError> {
        let path = proc_path(reference);
        let unreachable = |error: std::io::Error| SharedPixelsError::Unreachable {
            path: path.clone(),
            reason: error.to_string(),
        };
        let file = std::fs::File::open(&path).map_err(unreachable)?;
        let fd = std::os::fd::OwnedFd::from(file);
        let file_len = sys::file_len(&fd).map_err(unreachable)?;
        if file_len < HEADER_LEN {
            return Err(SharedPixelsError::NotTheBuffer { path });
        }
        let mapping = sys::map(&fd, file_len, false).map_err(unreachable)?;
        let header = mapping.header();
        if header.magic.load(Ordering::Acquire) != MAGIC || header.id.load(Ordering::Relaxed) != reference.id
        {
            return Err(SharedPixelsError::NotTheBuffer { path });
        }
        Ok(mapping)
    }

    #[cfg(not(target_os = "linux"))]
    fn open(_reference: &PixelsReference) -> Result<Mapping, SharedPixelsError> {
        Err(SharedPixelsError::Unsupported)
    }
}

fn proc_path(reference: &PixelsReference) -> String {
    format!("/proc/{}/fd/{}", reference.pid, reference.fd)
}

/// Whether this process may map the shared pixel buffers of process `pid` (the same user, and a kernel
/// that lets it look at that process's descriptors).
pub fn can_map_buffers_of(pid: u32) -> bool {
    cfg!(target_os = "linux") && std::fs::read_dir(format!("/proc/{pid}/fd")).is_ok()
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::{SharedBuffer, SharedPixelsError, SharedPixelsReader};

    fn written(len: usize, value: u8) -> SharedBuffer {
        let mut buffer = SharedBuffer::create(len).expect("memfd");
        buffer.bytes_mut().fill(value);
        buffer.end_write();
        buffer
    }

    #[test]
    fn a_reader_copies_the_pixels_a_reference_names() {
        let buffer = written(1000, 7);
        let mut reader = SharedPixelsReader::new();
        let pixels = reader.read(&buffer.reference()).expect("readable");
        assert_eq!(pixels, vec![7; 1000]);
    }

    #[test]
    fn a_rewritten_buffer_is_reported_replaced_not_read_torn() {
        let mut buffer = written(64, 1);
        let old = buffer.reference();
        let mut reader = SharedPixelsReader::new();
        assert!(reader.read(&old).is_ok());
        buffer.begin_write();
        assert_eq!(
            reader.read(&old),
            Err(SharedPixelsError::Replaced),
            "while being written"
        );
        buffer.bytes_mut().fill(2);
        buffer.end_write();
        assert_eq!(reader.read(&old), Err(SharedPixelsError::Replaced), "after");
        assert_eq!(reader.read(&buffer.reference()).expect("new frame"), vec![2; 64]);
    }

    #[test]
    fn a_reference_to_another_buffer_or_process_is_an_error() {
        let buffer = written(16, 3);
        let mut reader = SharedPixelsReader::new();
        let mut wrong_id = buffer.reference();
        wrong_id.id += 1000;
        assert!(matches!(
            reader.read(&wrong_id),
            Err(SharedPixelsError::NotTheBuffer { .. })
        ));
        let mut no_process = buffer.reference();
        no_process.pid = u32::MAX;
        let error = reader.read(&no_process).expect_err("no such process");
        assert!(error.to_string().contains("/proc/4294967295/fd/"), "{error}");
    }

    #[test]
    fn a_reference_longer_than_the_buffer_is_refused() {
        let buffer = written(16, 3);
        let mut reference = buffer.reference();
        reference.len = 1 << 20;
        let mut reader = SharedPixelsReader::new();
        assert!(matches!(
            reader.read(&reference),
            Err(SharedPixelsError::NotTheBuffer { .. })
        ));
    }
}

//! Image pixel buffers: written once by their producer ([`PixelsMut`]), then shared by every sample that
//! carries them ([`Pixels`]), never copied.
//!
//! Large buffers live in shared memory (on Linux) and are recycled: a camera that asks for a frame gets
//! back a buffer of an earlier frame that nothing holds any more, so it neither faults in fresh pages nor
//! zeroes them, and a studio on the same machine reads the pixels where the camera wrote them
//! (`kairos_shm`). Small buffers, and any buffer where shared memory cannot be had,
//! are ordinary heap memory; nothing but [`Pixels::shared_reference`] tells them apart.

use std::collections::VecDeque;
use std::fmt;
use std::ops::{Deref, DerefMut};
use std::sync::{Arc, Mutex, PoisonError};

use kairos_shm::{PixelsReference, SharedBuffer};

/// Buffers from this many bytes on are put in shared memory: below it, a copy costs less than a mapping.
pub const SHARED_FROM_BYTES: usize = 256 * 1024;

/// At most this many unused shared buffers are kept for reuse, and at most this many bytes of them.
const POOL_BUFFERS: usize = 8;
const POOL_BYTES: usize = 256 << 20;

/// Unused shared buffers, oldest first.
static POOL: Mutex<VecDeque<SharedBuffer>> = Mutex::new(VecDeque::new());

fn take_from_pool(len: usize) -> Option<SharedBuffer> {
    let mut pool = POOL.lock().unwrap_or_else(PoisonError::into_inner);
    // The oldest fitting buffer: the one a client on this machine is least likely to be still copying.
    let at = pool.iter().position(|buffer| buffer.len() == len)?;
    pool.remove(at)
}

fn return_to_pool(buffer: SharedBuffer) {
    let mut pool = POOL.lock().unwrap_or_else(PoisonError::into_inner);
    pool.push_back(buffer);
    while pool.len() > POOL_BUFFERS || pool.iter().map(SharedBuffer::len).sum::<usize>() > POOL_BYTES {
        pool.pop_front();
    }
}

/// A pixel buffer being written by its producer.
///
/// Its bytes start as zeros or as the pixels of an earlier frame (buffers are recycled): a producer
/// writes every byte it means, or calls [`PixelsMut::zeroed`].
pub struct PixelsMut(Writable);

enum Writable {
    Heap(Vec<u8>),
    Shared(SharedBuffer),
}

impl PixelsMut {
    /// A buffer of `len` bytes, in shared memory when it is large and shared memory can be had.
    pub fn new(len: usize) -> Self {
        if len >= SHARED_FROM_BYTES {
            let buffer = take_from_pool(len).map_or_else(|| SharedBuffer::create(len), Ok);
            match buffer {
                Ok(mut buffer) => {
                    buffer.begin_write();
                    return PixelsMut(Writable::Shared(buffer));
                }
                Err(error) => warn_once_heap(&error),
            }
        }
        PixelsMut(Writable::Heap(vec![0; len]))
    }

    /// A buffer of `len` zero bytes.
    pub fn zeroed(len: usize) -> Self {
        let mut pixels = Self::new(len);
        if matches!(pixels.0, Writable::Shared(_)) {
            pixels.fill(0);
        }
        pixels
    }

    /// Where the buffer lies in shared memory, when it does: what another process on this machine (a
    /// Python component's worker) maps to draw the pixels in place before the buffer is frozen.
    pub fn shared_reference(&self) -> Option<PixelsReference> {
        match &self.0 {
            Writable::Heap(_) => None,
            Writable::Shared(buffer) => Some(buffer.reference()),
        }
    }

    /// The finished pixels, to share.
    pub fn freeze(self) -> Pixels {
        match self.0 {
            Writable::Heap(bytes) => Pixels::from(bytes),
            Writable::Shared(mut buffer) => {
                buffer.end_write();
                Pixels(Arc::new(SharedPixels(Some(buffer))))
            }
        }
    }
}

fn warn_once_heap(error: &std::io::Error) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    WARNED.call_once(|| {
        tracing::warn!(
            "image buffers stay in ordinary memory (no shared memory: {error}); local viewers get a copy"
        );
    });
}

impl Deref for PixelsMut {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match &self.0 {
            Writable::Heap(bytes) => bytes,
            Writable::Shared(buffer) => buffer.bytes(),
        }
    }
}

impl DerefMut for PixelsMut {
    fn deref_mut(&mut self) -> &mut [u8] {
        match &mut self.0 {
            Writable::Heap(bytes) => bytes,
            Writable::Shared(buffer) => buffer.bytes_mut(),
        }
    }
}

impl fmt::Debug for PixelsMut {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PixelsMut").field("len", &self.len()).finish()
    }
}

/// Where a [`Pixels`]' bytes lie.
trait Storage: Send + Sync {
    fn bytes(&self) -> &[u8];

    /// The buffer, writable again, when this storage can give it up without a copy.
    fn take_writable(&mut self) -> Option<Writable> {
        None
    }

    fn shared_reference(&self) -> Option<PixelsReference> {
        None
    }
}

impl Storage for Vec<u8> {
    fn bytes(&self) -> &[u8] {
        self
    }

    fn take_writable(&mut self) -> Option<Writable> {
        Some(Writable::Heap(std::mem::take(self)))
    }
}

impl Storage for Arc<[u8]> {
    fn bytes(&self) -> &[u8] {
        self
    }
}

/// A finished shared-memory buffer; back to the pool when the last sample holding it goes.
struct SharedPixels(Option<SharedBuffer>);

impl Storage for SharedPixels {
    fn bytes(&self) -> &[u8] {
        self.0.as_ref().map_or(&[], SharedBuffer::bytes)
    }

    fn shared_reference(&self) -> Option<PixelsReference> {
        self.0.as_ref().map(SharedBuffer::reference)
    }

    fn take_writable(&mut self) -> Option<Writable> {
        let mut buffer = self.0.take()?;
        // Writing again is what recycling through the pool does; readers elsewhere see the new
        // generation exactly as they would for a recycled buffer.
        buffer.begin_write();
        Some(Writable::Shared(buffer))
    }
}

impl Drop for SharedPixels {
    fn drop(&mut self) {
        if let Some(buffer) = self.0.take() {
            return_to_pool(buffer);
        }
    }
}

/// An image's finished pixels, shared by every clone: cloning never copies them.
#[derive(Clone)]
pub struct Pixels(Arc<dyn Storage>);

impl Pixels {
    /// Where the pixels lie in shared memory, when they do: what a client on this machine maps instead
    /// of receiving a copy.
    pub fn shared_reference(&self) -> Option<PixelsReference> {
        self.0.shared_reference()
    }

    /// The buffer to write into in place, when this value alone holds it (no clone anywhere: not in a
    /// buffer, a sample or a viewer); otherwise the value back, unchanged. An operation that transforms
    /// pixels one for one tries this before it allocates.
    pub fn try_into_mut(mut self) -> Result<PixelsMut, Pixels> {
        match Arc::get_mut(&mut self.0).and_then(Storage::take_writable) {
            Some(writable) => Ok(PixelsMut(writable)),
            None => Err(self),
        }
    }

    /// Whether two values share one buffer (not merely equal bytes).
    pub fn ptr_eq(&self, other: &Pixels) -> bool {
        std::ptr::addr_eq(Arc::as_ptr(&self.0), Arc::as_ptr(&other.0))
    }
}

impl Deref for Pixels {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        self.0.bytes()
    }
}

impl AsRef<[u8]> for Pixels {
    fn as_ref(&self) -> &[u8] {
        self
    }
}

impl PartialEq for Pixels {
    fn eq(&self, other: &Self) -> bool {
        self.ptr_eq(other) || **self == **other
    }
}

impl fmt::Debug for Pixels {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Pixels")
            .field("len", &self.len())
            .field("shared", &self.shared_reference().is_some())
            .finish()
    }
}

impl From<Vec<u8>> for Pixels {
    /// Takes the vector as it is: no copy.
    fn from(bytes: Vec<u8>) -> Self {
        Pixels(Arc::new(bytes))
    }
}

impl From<Arc<[u8]>> for Pixels {
    fn from(bytes: Arc<[u8]>) -> Self {
        Pixels(Arc::new(bytes))
    }
}

impl From<&[u8]> for Pixels {
    fn from(bytes: &[u8]) -> Self {
        Pixels::from(bytes.to_vec())
    }
}

impl From<PixelsMut> for Pixels {
    fn from(pixels: PixelsMut) -> Self {
        pixels.freeze()
    }
}

#[cfg(test)]
mod tests {
    use super::{Pixels, PixelsMut, SHARED_FROM_BYTES};

    #[test]
    fn pixels_held_once_are_written_in_place_and_shared_ones_are_not() {
        for len in [16, SHARED_FROM_BYTES] {
            let mut first = PixelsMut::new(len);
            first.fill(3);
            let address = first.as_ptr();
            let pixels = first.freeze();
            let clone = pixels.clone();
            let pixels = pixels.try_into_mut().expect_err("a clone shares it");
            drop(clone);
            let mut again = pixels.try_into_mut().expect("held once");
            assert_eq!(again.as_ptr(), address, "the same buffer, not a copy");
            again[0] = 7;
            let pixels = again.freeze();
            assert_eq!((pixels[0], pixels[1]), (7, 3));
        }
    }

    #[test]
    fn small_buffers_stay_on_the_heap_and_large_ones_are_shared_on_linux() {
        let small = PixelsMut::zeroed(16).freeze();
        assert!(small.shared_reference().is_none());
        let mut large = PixelsMut::new(SHARED_FROM_BYTES);
        large.fill(9);
        let large = large.freeze();
        assert_eq!(large.shared_reference().is_some(), cfg!(target_os = "linux"));
        assert!(large.iter().all(|b| *b == 9));
    }

    #[test]
    fn clones_share_one_buffer_and_a_dropped_buffer_is_reused_under_a_new_generation() {
        let len = SHARED_FROM_BYTES + 4096 * 3;
        let mut first = PixelsMut::new(len);
        first.fill(1);
        let first = first.freeze();
        let clone = first.clone();
        assert!(first.ptr_eq(&clone));
        let Some(old) = first.shared_reference() else {
            return; // not Linux
        };
        drop((first, clone));
        let mut second = PixelsMut::zeroed(len);
        assert!(second.iter().all(|b| *b == 0), "zeroed clears a recycled buffer");
        second.fill(2);
        let second = second.freeze();
        let new = second.shared_reference().expect("shared");
        // Another test may have taken the buffer meanwhile; when this one got it back, its generation moved.
        if new.id == old.id {
            assert!(new.generation > old.generation);
        }
        let mut reader = kairos_shm::SharedPixelsReader::new();
        assert!(reader.read(&old).is_err() || new.id != old.id);
        assert_eq!(reader.read(&new).expect("readable"), vec![2; len]);
    }

    #[test]
    fn equal_bytes_are_equal_pixels_wherever_they_lie() {
        let mut shared = PixelsMut::new(SHARED_FROM_BYTES);
        shared.fill(5);
        assert_eq!(shared.freeze(), Pixels::from(vec![5; SHARED_FROM_BYTES]));
    }
}

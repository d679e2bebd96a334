//! The synchronisation primitives the buffers use, switched to `loom`'s models under `--cfg loom` so the
//! buffer's interleavings can be checked exhaustively.

#[cfg(loom)]
pub(crate) use loom::sync::atomic::{AtomicBool, AtomicU64, Ordering, fence};
#[cfg(loom)]
pub(crate) use loom::sync::{Mutex, MutexGuard};
#[cfg(loom)]
pub(crate) use loom::thread::{Thread, current as current_thread, park};

#[cfg(not(loom))]
pub(crate) use std::sync::atomic::{AtomicBool, AtomicU64, Ordering, fence};
#[cfg(not(loom))]
pub(crate) use std::sync::{Mutex, MutexGuard};
#[cfg(not(loom))]
pub(crate) use std::thread::{Thread, current as current_thread, park};

/// Parks the current thread for at most `timeout` (loom has no timed park: it parks until woken).
#[cfg(not(loom))]
pub(crate) fn park_timeout(timeout: std::time::Duration) {
    std::thread::park_timeout(timeout);
}

#[cfg(loom)]
pub(crate) fn park_timeout(_timeout: std::time::Duration) {
    loom::thread::yield_now();
}

/// How many times a waiting thread re-checks before it gives up its core or parks: about a microsecond
/// of spinning (one `pause` measured 25 ns on an AMD EPYC, about 40 on recent Intel cores), long enough
/// for a writer that keeps up to deliver the next sample, short enough that threads spinning in vain do
/// not starve others when there are more threads than cores.
#[cfg(not(loom))]
pub(crate) const SPINS: u32 = 40;
#[cfg(loom)]
pub(crate) const SPINS: u32 = 1;

/// One step of a wait that is expected to end within nanoseconds.
#[cfg(not(loom))]
pub(crate) fn spin() {
    std::hint::spin_loop();
}

#[cfg(loom)]
pub(crate) fn spin() {
    loom::thread::yield_now();
}

/// One step of a wait that may need another thread to be scheduled.
#[cfg(not(loom))]
pub(crate) fn yield_now() {
    std::thread::yield_now();
}

#[cfg(loom)]
pub(crate) fn yield_now() {
    loom::thread::yield_now();
}

/// The fence of the side of a two-sided handshake that runs often (the writer for every sample, a reader
/// for every read): free where [`heavy_fence`] can reach into other threads, a full fence elsewhere.
///
/// Each handshake here is the same: one side stores a flag and then loads the other side's flag, and the
/// other side does the reverse; a full fence between the store and the load on both sides guarantees
/// that at least one of them sees the other. `membarrier` lets the rare side pay for both: it makes
/// every running thread of the process execute a full barrier, so the frequent side needs none.
#[inline]
pub(crate) fn light_fence() {
    LightFence::decided().run();
}

/// [`light_fence`] with the process's choice looked up once, by code that fences for every sample: the
/// lookup would otherwise be most of the cost of a fence that compiles to nothing.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct LightFence {
    /// Whether a compiler fence is enough ([`heavy_fence`] reaches into other threads). `false`, a full
    /// fence, is always right.
    compiler_only: bool,
}

impl LightFence {
    /// The process's choice, deciding it if nobody has yet: it never changes afterwards.
    #[inline]
    pub(crate) fn decided() -> Self {
        #[cfg(not(loom))]
        let compiler_only = asymmetric_fences();
        #[cfg(loom)]
        let compiler_only = false;
        LightFence { compiler_only }
    }

    /// Runs the fence.
    #[inline]
    pub(crate) fn run(self) {
        if self.compiler_only {
            std::sync::atomic::compiler_fence(Ordering::SeqCst);
        } else {
            fence(Ordering::SeqCst);
        }
    }
}

/// The fence of the side of a handshake that runs rarely (a thread about to sleep, a reader attaching).
#[cfg(not(loom))]
pub(crate) fn heavy_fence() {
    if !asymmetric_fences() || !membarrier(MEMBARRIER_CMD_PRIVATE_EXPEDITED) {
        fence(Ordering::SeqCst);
    }
}

#[cfg(loom)]
pub(crate) fn heavy_fence() {
    fence(Ordering::SeqCst);
}

#[cfg(not(loom))]
const MEMBARRIER_CMD_PRIVATE_EXPEDITED: i32 = 1 << 3;
#[cfg(not(loom))]
const MEMBARRIER_CMD_REGISTER_PRIVATE_EXPEDITED: i32 = 1 << 4;

/// Whether this process may use expedited `membarrier` (Linux 4.14 and later): decided once, on first use,
/// by registering for it. Until it is decided both sides fence, and after it both agree.
#[cfg(not(loom))]
#[inline]
fn asymmetric_fences() -> bool {
    match ASYMMETRIC_FENCES.load(Ordering::Acquire) {
        1 => true,
        2 => false,
        _ => decide_asymmetric_fences(),
    }
}

/// 0 until decided, then 1 where expedited `membarrier` is usable and 2 where it is not.
#[cfg(not(loom))]
static ASYMMETRIC_FENCES: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

#[cfg(not(loom))]
#[cold]
fn decide_asymmetric_fences() -> bool {
    let usable = membarrier(MEMBARRIER_CMD_REGISTER_PRIVATE_EXPEDITED);
    ASYMMETRIC_FENCES.store(if usable { 1 } else { 2 }, Ordering::Release);
    // Threads that fenced before the decision keep working: a full fence on both sides is always
    // correct, and from here on the heavy side also reaches them.
    usable
}

#[cfg(all(not(loom), target_os = "linux"))]
#[allow(
    unsafe_code,
    reason = "the membarrier system call has no safe wrapper; it takes no pointers"
)]
fn membarrier(command: i32) -> bool {
    // SAFETY: membarrier(cmd, flags, cpu_id) reads no memory of ours; an unsupported command returns -1.
    unsafe { libc::syscall(libc::SYS_membarrier, command, 0, 0) == 0 }
}

#[cfg(all(not(loom), not(target_os = "linux")))]
fn membarrier(_command: i32) -> bool {
    false
}

/// An `UnsafeCell` whose accesses loom can check for data races.
#[cfg(not(loom))]
#[derive(Debug, Default)]
pub(crate) struct UnsafeCell<T>(std::cell::UnsafeCell<T>);

#[cfg(not(loom))]
impl<T> UnsafeCell<T> {
    pub(crate) fn new(value: T) -> Self {
        UnsafeCell(std::cell::UnsafeCell::new(value))
    }

    pub(crate) fn with<R>(&self, f: impl FnOnce(*const T) -> R) -> R {
        f(self.0.get())
    }

    pub(crate) fn with_mut<R>(&self, f: impl FnOnce(*mut T) -> R) -> R {
        f(self.0.get())
    }
}

#[cfg(loom)]
pub(crate) use loom::cell::UnsafeCell;

/// Locks a mutex, recovering the data if a panicking thread poisoned it: every critical section in
/// this crate leaves the state consistent before it can panic, so the data stays valid.
pub(crate) fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    match mutex.lock() {
        Ok(guard) => guard,
        Err(poisoned) => poisoned.into_inner(),
    }
}

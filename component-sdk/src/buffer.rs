//! The circular buffer each output owns, and the five reader policies (paper, section 2.2.2).
//!
//! One writer, any number of readers, and no lock on the way of a sample. The ring has a fixed number
//! of slots, each stamped with the sequence number of the sample it holds. The writer stamps a slot after
//! filling it, then advances `written`; a reader keeps its own cursor (the next sequence it has not
//! consumed) and clones samples out of the slots, which shares their payload: nothing heavy is copied.
//!
//! Three rules keep readers and the writer apart without a lock:
//! - A NeverSkipping reader's unread samples are never overwritten: the writer waits while that reader's
//!   share is full, so such a reader clones without any check.
//! - Any other reader may be lapped. Before cloning it announces the sequence it is cloning (`cloning`)
//!   and then checks the slot's stamp; a writer about to replace a sample that some reader may still
//!   reach marks the slot `REPLACING` first and then waits out a clone of that sequence. Both sides put a
//!   sequentially consistent fence between their store and their load, so at least one of them sees the
//!   other. A reader that finds the slot replaced does not announce again until the slot holds its new
//!   sample: announcing in a loop could keep the writer waiting.
//! - The writer knows which samples a reader may still reach from the cursor the reader publishes; it
//!   keeps the last value it saw and reloads it only when that value would stop it, so a reader that
//!   keeps up costs the writer nothing per sample.
//!
//! Each reader publishes its counters under a sequence lock of its own, so a snapshot from another
//! thread always satisfies `written = read + skipped + overwritten + queued` exactly. A FIFO reader's
//! lapping is accounted lazily: samples beyond its share count as overwritten the moment they are,
//! whether the reader looked yet or not.
//!
//! The set of readers changes under a mutex that neither reads nor writes take. A reader attaching
//! while the writer runs waits until the writer is between two writes; every later write sees it (the
//! same store-fence-load handshake, the heavy fence on the attaching side).
#![allow(
    unsafe_code,
    reason = "the slots are shared between the writer and the readers without a lock; each access states \
              the rule above that makes it race-free, and the loom models check them"
)]

use std::fmt;
use std::ops::Deref;
use std::sync::Arc;

use kairos_diagram::{MAX_BUFFER_SIZE, ReaderPolicy};

use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::stats::{LinkCounters, SharedLatency};
use crate::sync::{
    AtomicBool, AtomicU64, Mutex, Ordering, SPINS, UnsafeCell, fence, heavy_fence, light_fence, lock, spin,
    yield_now,
};

/// Why a blocking read returned without a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// The runtime is stopping the component.
    #[error("stopped")]
    Stopped,
    /// The component is asked to handle a pause, a property change or an action first.
    #[error("interrupted to apply a control request")]
    Interrupted,
    /// The writer closed the stream and everything in it has been read.
    #[error("end of stream")]
    EndOfStream,
    /// Nothing to read now, in a context that may not block (a reactive component).
    #[error("no data")]
    NoData,
}

/// Why a write did not happen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WriteError {
    /// The writer waited for a NeverSkipping reader and was stopped meanwhile.
    #[error("stopped while waiting for a NeverSkipping reader to make room")]
    Stopped,
}

/// How one reader attaches to an output.
#[derive(Debug, Clone)]
pub struct ReaderConfig {
    /// The reader policy.
    pub policy: ReaderPolicy,
    /// This reader's logical buffer size; `None` takes the output's. At most the ring's size.
    pub capacity: Option<usize>,
    /// Keep one sample in this many (1 keeps all). Ignored by Sampling, which resamples in time anyway.
    pub subsampling: u32,
    /// The link's name for statistics and warnings (`sine1.out -> gain1.in`).
    pub link: String,
}

impl ReaderConfig {
    /// A reader with `policy`, the output's buffer size and no subsampling.
    pub fn new(policy: ReaderPolicy, link: impl Into<String>) -> Self {
        ReaderConfig {
            policy,
            capacity: None,
            subsampling: 1,
            link: link.into(),
        }
    }
}

/// A slot's stamp before its first sample.
const EMPTY: u64 = u64::MAX;
/// A slot's stamp while the writer replaces a sample some reader may be cloning.
const REPLACING: u64 = u64::MAX - 1;
/// A reader's `cloning` while it clones nothing.
const IDLE: u64 = u64::MAX;

/// Keeps what the writer and the readers each change often on cache lines of their own.
#[repr(align(128))]
#[derive(Default)]
struct Padded<T>(T);

impl<T> Deref for Padded<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

#[repr(align(128))]
struct Slot {
    /// The sequence number of the sample held, [`EMPTY`] or [`REPLACING`].
    stamp: AtomicU64,
    sample: UnsafeCell<Option<Sample>>,
}

/// What a reader publishes for the writer and for statistics. Only the reader writes it.
struct Progress {
    /// Sequence lock over the fields below: odd while the reader updates them.
    version: AtomicU64,
    cursor: AtomicU64,
    read: AtomicU64,
    skipped: AtomicU64,
    overwritten: AtomicU64,
    repeated: AtomicU64,
    /// The sequence the reader is cloning now, or [`IDLE`].
    cloning: AtomicU64,
}

/// Counters as the reader last published them.
#[derive(Clone, Copy)]
struct Published {
    cursor: u64,
    read: u64,
    skipped: u64,
    overwritten: u64,
    repeated: u64,
}

struct ReaderShared {
    link: Arc<str>,
    policy: ReaderPolicy,
    capacity: u64,
    joined_at: u64,
    signal: Arc<RunSignal>,
    attached: AtomicBool,
    /// `written` when the reader detached ([`EMPTY`] while attached): its counts freeze there.
    detached_at: AtomicU64,
    progress: Padded<Progress>,
    /// Written by the reader for every sample: kept off the lines the writer reads for every sample.
    latency: Padded<SharedLatency>,
}

impl ReaderShared {
    /// The oldest sequence this reader may still clone, given a cursor it published.
    fn floor(&self, cursor: u64) -> u64 {
        match self.policy {
            ReaderPolicy::Fifo | ReaderPolicy::NeverSkipping => cursor,
            // These clone the newest sample, which is at least the one before their cursor.
            ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext | ReaderPolicy::Sampling => {
                cursor.saturating_sub(1)
            }
        }
    }

    /// A consistent copy of the reader's counters (sequence-lock read).
    fn published(&self) -> Published {
        let p = &self.progress;
        loop {
            let before = p.version.load(Ordering::Acquire);
            if !before.is_multiple_of(2) {
                yield_now();
                continue;
            }
            let copy = Published {
                cursor: p.cursor.load(Ordering::Relaxed),
                read: p.read.load(Ordering::Relaxed),
                skipped: p.skipped.load(Ordering::Relaxed),
                overwritten: p.overwritten.load(Ordering::Relaxed),
                repeated: p.repeated.load(Ordering::Relaxed),
            };
            fence(Ordering::Acquire);
            if p.version.load(Ordering::Relaxed) == before {
                return copy;
            }
        }
    }

    fn counters(&self, counts: Published, written_now: u64) -> LinkCounters {
        let detached_at = self.detached_at.load(Ordering::Acquire);
        let written = if detached_at == EMPTY {
            written_now
        } else {
            detached_at
        };
        let mut counters = counters_of(self.policy, self.capacity, self.joined_at, counts, written);
        counters.latency = self.latency.snapshot().summary();
        counters
    }
}

/// The counters of a reader that had `counts` when `written` samples had been written. A FIFO reader
/// whose pending samples exceed its share has lost the excess to the writer, looked or not.
fn counters_of(
    policy: ReaderPolicy,
    capacity: u64,
    joined_at: u64,
    counts: Published,
    written: u64,
) -> LinkCounters {
    let written = written.max(counts.cursor);
    let mut queued = written - counts.cursor;
    let mut overwritten = counts.overwritten;
    if policy == ReaderPolicy::Fifo && queued > capacity {
        overwritten += queued - capacity;
        queued = capacity;
    }
    LinkCounters {
        written: written - joined_at,
        read: counts.read,
        skipped: counts.skipped,
        overwritten,
        queued,
        repeated: counts.repeated,
        latency: crate::stats::LatencySummary::default(),
    }
}

/// The signals of reactive readers, run by the writer after each write.
type ReactiveReaders = Arc<[Arc<RunSignal>]>;

/// A reader as the writer follows it.
struct Watched {
    reader: Arc<ReaderShared>,
    /// The reader's cursor when the writer last looked; the real one is never behind it.
    seen_cursor: u64,
}

/// The writer's view of the readers, changed only by the thread inside a write.
#[derive(Default)]
struct WriterState {
    /// The `version` of the reader set this view was taken at.
    version: u64,
    readers: Vec<Watched>,
    /// Signals of the readers that have threads: each write notifies them (an unpark only if armed).
    threads: Vec<Arc<RunSignal>>,
    /// Reactive readers, run after each write once the write is over (they may write themselves).
    reactive: Option<ReactiveReaders>,
}

impl WriterState {
    /// The writer's view of the readers attached now, from the registry.
    fn of_attached_readers(shared: &Shared) -> Self {
        let registry = lock(&shared.registry);
        let readers: Vec<Watched> = registry
            .readers
            .iter()
            .filter(|r| r.attached.load(Ordering::Acquire))
            .map(|reader| Watched {
                reader: Arc::clone(reader),
                seen_cursor: reader.progress.cursor.load(Ordering::Acquire),
            })
            .collect();
        let (reactive, threads): (Vec<_>, Vec<_>) = readers
            .iter()
            .map(|w| Arc::clone(&w.reader.signal))
            .partition(|signal| signal.is_reactive());
        WriterState {
            version: shared.version.load(Ordering::SeqCst),
            readers,
            threads,
            reactive: (!reactive.is_empty()).then(|| Arc::from(reactive)),
        }
    }

    /// A NeverSkipping reader with no room for one more sample, if any.
    fn full_reader(&mut self, written: u64) -> Option<Arc<ReaderShared>> {
        for watched in &mut self.readers {
            let reader = &watched.reader;
            if reader.policy != ReaderPolicy::NeverSkipping || written - watched.seen_cursor < reader.capacity
            {
                continue;
            }
            watched.seen_cursor = reader.progress.cursor.load(Ordering::Acquire);
            if written - watched.seen_cursor >= reader.capacity && reader.attached.load(Ordering::Acquire) {
                return Some(Arc::clone(reader));
            }
        }
        None
    }

    /// Makes sure no reader is cloning sequence `old` out of `slot` before it is replaced.
    fn claim(&mut self, slot: &Slot, old: u64) {
        let mut marked = false;
        for watched in &mut self.readers {
            let reader = &watched.reader;
            // NeverSkipping readers are past `old`: the writer waited for them (rule 1).
            if reader.policy == ReaderPolicy::NeverSkipping || reader.floor(watched.seen_cursor) > old {
                continue;
            }
            watched.seen_cursor = reader.progress.cursor.load(Ordering::Acquire);
            if reader.floor(watched.seen_cursor) > old {
                continue;
            }
            if !marked {
                slot.stamp.store(REPLACING, Ordering::Relaxed);
                // Paired with the fence in `Reader::clone_announced`: one of the two sees the other.
                fence(Ordering::SeqCst);
                marked = true;
            }
            while reader.progress.cloning.load(Ordering::Acquire) == old {
                spin();
            }
        }
    }
}

struct Registry {
    default_capacity: u64,
    /// Every reader that ever attached, detached ones included (their counts stay visible).
    readers: Vec<Arc<ReaderShared>>,
    blocked_writer: Option<Arc<RunSignal>>,
}

struct Shared {
    output: String,
    /// A power of two long, at least the largest reader share.
    slots: Box<[Slot]>,
    /// `slots.len() - 1`: a sequence's slot is `sequence & mask` (no division on the way of a sample).
    mask: u64,
    /// How many samples were written: the next sequence number. Only the writer stores it.
    written: Padded<AtomicU64>,
    /// Odd while a thread is inside a write; it then owns `writer_state`.
    writer_epoch: Padded<AtomicU64>,
    writer_state: UnsafeCell<WriterState>,
    /// Bumped whenever a reader attaches or detaches.
    version: Padded<AtomicU64>,
    closed: AtomicBool,
    /// Set while the writer sleeps waiting for a NeverSkipping reader.
    writer_waiting: Padded<AtomicBool>,
    registry: Mutex<Registry>,
}

// SAFETY: `slots` and `writer_state` are the only fields without their own synchronisation; the module
// documentation gives the rules under which threads touch them, and `Sample` is `Send + Sync`.
unsafe impl Sync for Shared {}
// SAFETY: as above; nothing in `Shared` is tied to a thread.
unsafe impl Send for Shared {}

impl Shared {
    fn slot(&self, sequence: u64) -> &Slot {
        &self.slots[(sequence & self.mask) as usize]
    }

    /// Waits until no write is in progress; any write that starts later sees the current `version`.
    fn wait_for_writer_between_writes(&self) {
        let epoch = self.writer_epoch.load(Ordering::SeqCst);
        if epoch.is_multiple_of(2) {
            return;
        }
        while self.writer_epoch.load(Ordering::SeqCst) == epoch {
            yield_now();
        }
    }

    /// A sample for a reader that attached or was counted by the writer (rule 1 or 2 guarantees the slot
    /// holds `sequence` unchanged while this runs).
    fn clone_unchecked(&self, sequence: u64) -> Option<Sample> {
        // No check of the stamp here: a writer may mark the slot REPLACING meanwhile, and then waits for
        // this clone to end.
        let slot = self.slot(sequence);
        // SAFETY: rule 1, or `cloning` announced with the stamp checked after (rule 2): the writer does
        // not replace this slot's sample until the clone is over.
        slot.sample.with(|sample| unsafe { (*sample).clone() })
    }

    fn wake_blocked_writer(&self) {
        let writer = lock(&self.registry).blocked_writer.take();
        if let Some(writer) = writer {
            writer.wake();
        }
    }
}

/// Inside a write: owns the writer's state until dropped.
struct WriteGuard<'a> {
    shared: &'a Shared,
    epoch: u64,
}

impl<'a> WriteGuard<'a> {
    /// Enters a write, with a view of the readers as of now.
    fn enter(shared: &'a Shared) -> Self {
        loop {
            let guard = Self::take_turn(shared);
            // Paired with the heavy fence in `attach`: either this sees the new version, or the attaching
            // reader sees this write in progress and waits it out.
            light_fence();
            let version = shared.version.load(Ordering::SeqCst);
            // SAFETY: inside a write (odd epoch taken by this thread): nobody else touches the state.
            if shared.writer_state.with(|state| unsafe { (*state).version }) == version {
                return guard;
            }
            // Leave the write before taking the registry: an attaching reader holds it while it waits
            // for the writer to be between writes.
            drop(guard);
            let fresh = WriterState::of_attached_readers(shared);
            let guard = Self::take_turn(shared);
            // SAFETY: inside a write, as above.
            shared.writer_state.with_mut(|state| unsafe { *state = fresh });
            drop(guard);
        }
    }

    /// Makes the epoch odd for this thread, waiting out another thread's write to the same output.
    fn take_turn(shared: &'a Shared) -> Self {
        loop {
            let epoch = shared.writer_epoch.load(Ordering::Relaxed);
            if epoch.is_multiple_of(2)
                && shared
                    .writer_epoch
                    .compare_exchange(epoch, epoch + 1, Ordering::SeqCst, Ordering::Relaxed)
                    .is_ok()
            {
                return WriteGuard {
                    shared,
                    epoch: epoch + 1,
                };
            }
            yield_now();
        }
    }

    fn with_state<R>(&mut self, f: impl FnOnce(&mut WriterState) -> R) -> R {
        // SAFETY: inside a write, and `&mut self` keeps this the only borrow.
        self.shared
            .writer_state
            .with_mut(|state| f(unsafe { &mut *state }))
    }

    /// Puts `sample` in the next slot, makes it visible and notifies the readers' threads. Returns the
    /// sample it replaced and the reactive readers to run.
    fn publish(&mut self, sample: Sample) -> (Option<Sample>, Option<ReactiveReaders>) {
        let shared = self.shared;
        let sequence = shared.written.load(Ordering::Relaxed);
        let slot = shared.slot(sequence);
        if let Some(old) = sequence.checked_sub(shared.slots.len() as u64) {
            self.with_state(|state| state.claim(slot, old));
        }
        // SAFETY: inside a write; `claim` (rule 2) and the NeverSkipping wait (rule 1) leave no reader
        // cloning the sample this slot held.
        let replaced = slot.sample.with_mut(|held| unsafe { (*held).replace(sample) });
        slot.stamp.store(sequence, Ordering::Release);
        shared.written.store(sequence + 1, Ordering::Release);
        let reactive = self.with_state(|state| {
            for signal in &state.threads {
                signal.notify_data();
            }
            state.reactive.clone()
        });
        (replaced, reactive)
    }
}

impl Drop for WriteGuard<'_> {
    fn drop(&mut self) {
        self.shared.writer_epoch.store(self.epoch + 1, Ordering::Release);
    }
}

/// The circular buffer of one output. Cloning gives another handle to the same buffer.
#[derive(Clone)]
pub struct OutputBuffer {
    shared: Arc<Shared>,
}

impl fmt::Debug for OutputBuffer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("OutputBuffer")
            .field("output", &self.shared.output)
            .field("slots", &self.shared.slots.len())
            .finish_non_exhaustive()
    }
}

impl OutputBuffer {
    /// A buffer of `capacity` samples (at least one) for the output named `output` (`sine1.out`).
    pub fn new(output: impl Into<String>, capacity: usize) -> Self {
        Self::with_slots(output, capacity, capacity)
    }

    /// A buffer whose readers get `capacity` samples by default, with room for a reader that asks for up
    /// to `slots` (a connection with a larger buffer size than its output's).
    ///
    /// Both are cut to [`kairos_diagram::MAX_BUFFER_SIZE`] (with a warning): the slots are allocated here,
    /// and a size from a pack or a program must not take the process down.
    pub fn with_slots(output: impl Into<String>, capacity: usize, slots: usize) -> Self {
        let output = output.into();
        if capacity.max(slots) > MAX_BUFFER_SIZE {
            tracing::warn!(
                "buffer of {output} asked for {} samples; it holds {MAX_BUFFER_SIZE}, the maximum",
                capacity.max(slots)
            );
        }
        let capacity = capacity.clamp(1, MAX_BUFFER_SIZE);
        let slots = slots.clamp(capacity, MAX_BUFFER_SIZE).next_power_of_two();
        OutputBuffer {
            shared: Arc::new(Shared {
                output,
                mask: slots as u64 - 1,
                slots: (0..slots)
                    .map(|_| Slot {
                        stamp: AtomicU64::new(EMPTY),
                        sample: UnsafeCell::new(None),
                    })
                    .collect(),
                written: Padded(AtomicU64::new(0)),
                writer_epoch: Padded(AtomicU64::new(0)),
                writer_state: UnsafeCell::new(WriterState::default()),
                version: Padded(AtomicU64::new(1)),
                closed: AtomicBool::new(false),
                writer_waiting: Padded(AtomicBool::new(false)),
                registry: Mutex::new(Registry {
                    default_capacity: capacity as u64,
                    readers: Vec::new(),
                    blocked_writer: None,
                }),
            }),
        }
    }

    /// The output's name.
    pub fn output(&self) -> &str {
        &self.shared.output
    }

    /// Attaches a reader that wakes `signal` when data arrives. A reader attached after samples were
    /// written sees the newest one as pending, so Sampling and LastOrNext readers have data at once.
    /// A capacity larger than the buffer's slots is cut to them, with a warning naming the link.
    pub fn attach(&self, config: ReaderConfig, signal: Arc<RunSignal>) -> Reader {
        let shared = &*self.shared;
        let mut registry = lock(&shared.registry);
        let slots = shared.slots.len() as u64;
        let mut capacity = config
            .capacity
            .map_or(registry.default_capacity, |c| c.max(1) as u64);
        if capacity > slots {
            tracing::warn!(
                "link {} asks for a buffer of {capacity} samples but {} holds {slots}; it gets {slots}",
                config.link,
                shared.output
            );
            capacity = slots;
        }
        shared.version.fetch_add(1, Ordering::SeqCst);
        heavy_fence();
        shared.wait_for_writer_between_writes();
        let joined_at = shared.written.load(Ordering::SeqCst).saturating_sub(1);
        let reader = Arc::new(ReaderShared {
            link: Arc::from(config.link),
            policy: config.policy,
            capacity,
            joined_at,
            signal: Arc::clone(&signal),
            attached: AtomicBool::new(true),
            detached_at: AtomicU64::new(EMPTY),
            progress: Padded(Progress {
                version: AtomicU64::new(0),
                cursor: AtomicU64::new(joined_at),
                read: AtomicU64::new(0),
                skipped: AtomicU64::new(0),
                overwritten: AtomicU64::new(0),
                repeated: AtomicU64::new(0),
                cloning: AtomicU64::new(IDLE),
            }),
            latency: Padded(SharedLatency::default()),
        });
        registry.readers.push(Arc::clone(&reader));
        drop(registry);
        Reader {
            buffer: self.clone(),
            shared: reader,
            policy: config.policy,
            capacity,
            subsampling: u64::from(config.subsampling.max(1)),
            subsample_countdown: 0,
            counts: Published {
                cursor: joined_at,
                read: 0,
                skipped: 0,
                overwritten: 0,
                repeated: 0,
            },
            signal,
        }
    }

    /// Writes a sample, waking every reader. Blocks only while a NeverSkipping reader's share is full;
    /// `writer` is the writing component's signal, through which the runtime can stop that wait.
    pub fn write(&self, sample: Sample, writer: &Arc<RunSignal>) -> Result<(), WriteError> {
        let shared = &*self.shared;
        let mut guard = loop {
            let mut guard = WriteGuard::enter(shared);
            if shared.closed.load(Ordering::Acquire) {
                return Ok(());
            }
            let written = shared.written.load(Ordering::Relaxed);
            match guard.with_state(|state| state.full_reader(written)) {
                None => break guard,
                Some(reader) => {
                    drop(guard);
                    self.wait_for_room(&reader, written, writer)?;
                }
            }
        };
        let (replaced, reactive) = guard.publish(sample);
        drop(guard);
        // Dropped outside the write: the last reference to a large payload frees it here.
        drop(replaced);
        for signal in reactive.iter().flat_map(|signals| signals.iter()) {
            signal.notify_data();
        }
        Ok(())
    }

    /// Waits until `reader` has room for the sample after `written`, it detached, or the writer is stopped.
    fn wait_for_room(
        &self,
        reader: &ReaderShared,
        written: u64,
        writer: &Arc<RunSignal>,
    ) -> Result<(), WriteError> {
        let shared = &*self.shared;
        let has_room = || {
            !reader.attached.load(Ordering::Acquire)
                || written - reader.progress.cursor.load(Ordering::Acquire) < reader.capacity
        };
        for _ in 0..SPINS {
            if has_room() {
                return Ok(());
            }
            spin();
        }
        loop {
            if writer.stop_requested() {
                return Err(WriteError::Stopped);
            }
            lock(&shared.registry).blocked_writer = Some(Arc::clone(writer));
            shared.writer_waiting.store(true, Ordering::Relaxed);
            // Paired with the light fence in `Reader::try_read`: a reader that made room before the flag
            // was up is seen here, one that makes room after it sees the flag.
            heavy_fence();
            if !has_room() && !writer.stop_requested() {
                writer.park();
            }
            shared.writer_waiting.store(false, Ordering::Relaxed);
            if has_room() {
                return Ok(());
            }
        }
    }

    /// Closes the stream: readers get what is left, then [`ReadError::EndOfStream`]; later writes are dropped.
    pub fn close(&self) {
        self.shared.closed.store(true, Ordering::SeqCst);
        let signals: Vec<Arc<RunSignal>> = lock(&self.shared.registry)
            .readers
            .iter()
            .filter(|r| r.attached.load(Ordering::Acquire))
            .map(|r| Arc::clone(&r.signal))
            .collect();
        for signal in signals {
            signal.wake();
        }
    }

    /// How many samples were written in all.
    pub fn written(&self) -> u64 {
        self.shared.written.load(Ordering::Acquire)
    }

    /// The counters of every reader that ever attached (a detached one frozen where it left), with its
    /// link name.
    pub fn link_counters(&self) -> Vec<(Arc<str>, LinkCounters)> {
        let readers = lock(&self.shared.registry).readers.clone();
        readers
            .iter()
            .map(|reader| {
                // Counts first: `written` read after them is at least their cursor.
                let counts = reader.published();
                let written = self.shared.written.load(Ordering::Acquire);
                (Arc::clone(&reader.link), reader.counters(counts, written))
            })
            .collect()
    }
}

/// One reader of an output's buffer: the reading end of a link. Dropping it detaches it.
pub struct Reader {
    buffer: OutputBuffer,
    shared: Arc<ReaderShared>,
    policy: ReaderPolicy,
    capacity: u64,
    subsampling: u64,
    /// Samples still to pass over before the next one kept.
    subsample_countdown: u64,
    /// The counters, cursor included, as this reader knows them (published after each change).
    counts: Published,
    signal: Arc<RunSignal>,
}

impl fmt::Debug for Reader {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Reader")
            .field("output", &self.buffer.shared.output)
            .field("policy", &self.policy)
            .finish_non_exhaustive()
    }
}

impl Reader {
    /// The reader's policy.
    pub fn policy(&self) -> ReaderPolicy {
        self.policy
    }

    /// The output this reader reads.
    pub fn output(&self) -> &str {
        self.buffer.output()
    }

    /// The next sample under the reader's policy, without blocking. WaitForNext behaves as LastOrNext
    /// here: without waiting there is no "next", so the newest unread sample is the closest answer.
    pub fn try_read(&mut self) -> Option<Sample> {
        if self.policy == ReaderPolicy::NeverSkipping && self.subsampling == 1 {
            // The usual lossless link gets a straight path: no policy loop, and one move of the 112-byte
            // sample fewer (measured: 18 ns a read instead of 26).
            // `next_never_skipping` inlined by hand: returning the sample through it costs a move.
            let cursor = self.never_skipping_ready()?;
            let sample = self.buffer.shared.clone_unchecked(cursor)?;
            self.counts.cursor = cursor + 1;
            self.count_kept(&sample);
            self.signal.disarm();
            self.make_room_for_writer();
            return Some(sample);
        }
        let cursor_before = self.counts.cursor;
        let sample = self.take();
        if sample.is_some() {
            self.signal.disarm();
        }
        if self.policy == ReaderPolicy::NeverSkipping && self.counts.cursor != cursor_before {
            self.make_room_for_writer();
        }
        sample
    }

    /// After a NeverSkipping reader moved its cursor: wakes a writer waiting for room.
    fn make_room_for_writer(&self) {
        // Paired with the writer raising `writer_waiting` before it looks at the cursor again.
        light_fence();
        if self.buffer.shared.writer_waiting.load(Ordering::Relaxed) {
            self.buffer.shared.wake_blocked_writer();
        }
    }

    /// Counts a sample handed to the component and publishes the counters.
    fn count_kept(&mut self, sample: &Sample) {
        self.counts.read += 1;
        self.shared.latency.record(sample.latency_nanos());
        self.publish();
    }

    /// The next sample under the reader's policy, sleeping until one arrives.
    ///
    /// Returns early with [`ReadError::Stopped`] when the component is stopped, and with
    /// [`ReadError::Interrupted`] when `interruptible` and the runtime wants the component's attention.
    pub fn read(&mut self, interruptible: bool) -> Result<Sample, ReadError> {
        if self.policy == ReaderPolicy::WaitForNext {
            self.skip_pending();
        }
        let mut spins = 0;
        loop {
            if let Some(sample) = self.try_read() {
                return Ok(sample);
            }
            if self.buffer.shared.closed.load(Ordering::Acquire) {
                // Whatever was written before the close is visible now.
                return self.try_read().ok_or(ReadError::EndOfStream);
            }
            if self.signal.stop_requested() {
                return Err(ReadError::Stopped);
            }
            if interruptible && self.signal.wants_attention() {
                return Err(ReadError::Interrupted);
            }
            // A writer that keeps up refills within a microsecond: cheaper to wait for it than to sleep.
            if spins < SPINS {
                spins += 1;
                spin();
                continue;
            }
            // The first call only arms the signal: the loop re-checks once more, then sleeps.
            self.signal.park();
        }
    }

    /// Whether a sample is waiting for this reader (a Sampling reader: whether any exists at all).
    pub fn has_pending(&self) -> bool {
        let written = self.buffer.written();
        match self.policy {
            ReaderPolicy::Sampling => written > 0,
            _ => self.counts.cursor < written,
        }
    }

    /// Skips everything pending (counted as skipped by policy); the next read waits for a new sample.
    pub fn skip_pending(&mut self) {
        let written = self.buffer.written();
        if written > self.counts.cursor {
            self.counts.skipped += written - self.counts.cursor;
            self.counts.cursor = written;
            self.publish();
        }
    }

    /// This link's counters.
    pub fn counters(&self) -> LinkCounters {
        self.shared.counters(self.counts, self.buffer.written())
    }

    /// Whether the writer closed the stream and nothing is left to read.
    pub fn is_exhausted(&self) -> bool {
        self.buffer.shared.closed.load(Ordering::Acquire) && self.counts.cursor >= self.buffer.written()
    }

    /// Takes the next sample under the policy and subsampling, updating and publishing the counters.
    fn take(&mut self) -> Option<Sample> {
        loop {
            let sample = match self.policy {
                ReaderPolicy::NeverSkipping => self.next_never_skipping()?,
                ReaderPolicy::Fifo => self.next_fifo()?,
                ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext => self.newest_unread()?,
                ReaderPolicy::Sampling => return self.sampled(),
            };
            // Counts down to the next kept sample: no division per sample.
            let keep = self.subsample_countdown == 0;
            self.subsample_countdown = if keep {
                self.subsampling - 1
            } else {
                self.subsample_countdown - 1
            };
            if keep {
                self.count_kept(&sample);
                return Some(sample);
            }
            self.counts.skipped += 1;
            self.publish();
        }
    }

    /// NeverSkipping: the sample at the cursor, which the writer cannot have replaced (rule 1).
    fn next_never_skipping(&mut self) -> Option<Sample> {
        let cursor = self.never_skipping_ready()?;
        let sample = self.buffer.shared.clone_unchecked(cursor)?;
        self.counts.cursor = cursor + 1;
        Some(sample)
    }

    /// NeverSkipping: the cursor, if its sample was written.
    ///
    /// That is read from the slot's stamp, not from `written`: the slot's cache line comes to this core
    /// anyway, and leaving `written` alone spares both cores a transfer per sample.
    fn never_skipping_ready(&self) -> Option<u64> {
        let cursor = self.counts.cursor;
        (self.buffer.shared.slot(cursor).stamp.load(Ordering::Acquire) == cursor).then_some(cursor)
    }

    /// FIFO: the oldest sample still within this reader's share; what the writer lapped counts overwritten.
    fn next_fifo(&mut self) -> Option<Sample> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            if cursor >= written {
                return None;
            }
            if written - cursor > self.capacity {
                let lapped = written - cursor - self.capacity;
                self.counts.overwritten += lapped;
                self.counts.cursor += lapped;
            }
            match self.clone_announced(self.counts.cursor) {
                Ok(sample) => {
                    self.counts.cursor += 1;
                    return Some(sample);
                }
                Err(written_at_least) => written = written_at_least,
            }
        }
    }

    /// LastOrNext and WaitForNext: the newest sample if it is unread; older unread ones are skipped.
    fn newest_unread(&mut self) -> Option<Sample> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            if cursor >= written {
                return None;
            }
            match self.clone_announced(written - 1) {
                Ok(sample) => {
                    self.counts.skipped += written - 1 - cursor;
                    self.counts.cursor = written;
                    return Some(sample);
                }
                Err(written_at_least) => written = written_at_least,
            }
        }
    }

    /// Sampling: the newest sample, again if nothing newer came (unless the stream is closed).
    fn sampled(&mut self) -> Option<Sample> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            if written == 0 {
                return None;
            }
            let again = cursor >= written;
            if again && self.buffer.shared.closed.load(Ordering::Acquire) {
                // A closed stream has nothing new to give: end it rather than repeat forever.
                return None;
            }
            let sample = match self.clone_announced(written - 1) {
                Ok(sample) => sample,
                Err(written_at_least) => {
                    written = written_at_least;
                    continue;
                }
            };
            if again {
                self.counts.repeated += 1;
                self.publish();
            } else {
                self.counts.skipped += written - 1 - cursor;
                self.counts.cursor = written;
                self.count_kept(&sample);
            }
            return Some(sample);
        }
    }

    /// Clones `sequence` unless the writer replaced it or is replacing it (rule 2). On a miss it returns
    /// how many samples were written at least, from the newer sample the slot holds once the writer is
    /// through with it: a reader lapped while it looked learns by how much.
    ///
    /// After a miss the reader does not announce again until the slot holds its new sample: a reader
    /// that kept announcing the sequence a writer is waiting out could keep that writer waiting.
    fn clone_announced(&self, sequence: u64) -> Result<Sample, u64> {
        let cloning = &self.shared.progress.cloning;
        cloning.store(sequence, Ordering::Relaxed);
        // Paired with the fence in `WriterState::claim`: one of the two sees the other.
        fence(Ordering::SeqCst);
        let slot = self.buffer.shared.slot(sequence);
        let mut stamp = slot.stamp.load(Ordering::Acquire);
        let sample = (stamp == sequence).then(|| self.buffer.shared.clone_unchecked(sequence));
        cloning.store(IDLE, Ordering::Release);
        // A slot stamped with a sequence holds its sample, so `flatten` drops nothing real.
        if let Some(sample) = sample.flatten() {
            return Ok(sample);
        }
        while stamp == REPLACING {
            spin();
            stamp = slot.stamp.load(Ordering::Acquire);
        }
        Err(self.buffer.written().max(stamp.saturating_add(1)))
    }

    /// Publishes the counters under the reader's sequence lock.
    fn publish(&self) {
        let p = &self.shared.progress;
        let version = p.version.load(Ordering::Relaxed);
        p.version.store(version + 1, Ordering::Relaxed);
        fence(Ordering::Release);
        p.read.store(self.counts.read, Ordering::Relaxed);
        p.skipped.store(self.counts.skipped, Ordering::Relaxed);
        p.overwritten.store(self.counts.overwritten, Ordering::Relaxed);
        p.repeated.store(self.counts.repeated, Ordering::Relaxed);
        // Release: the writer that sees this cursor may replace what the reader cloned before it.
        p.cursor.store(self.counts.cursor, Ordering::Release);
        p.version.store(version + 2, Ordering::Release);
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        let shared = &*self.buffer.shared;
        let registry = lock(&shared.registry);
        self.shared
            .detached_at
            .store(shared.written.load(Ordering::Acquire), Ordering::Release);
        self.shared.attached.store(false, Ordering::SeqCst);
        shared.version.fetch_add(1, Ordering::SeqCst);
        drop(registry);
        // A writer waiting for this reader's room waits no more.
        shared.wake_blocked_writer();
    }
}

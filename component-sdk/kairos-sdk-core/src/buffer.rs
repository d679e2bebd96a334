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
//! From the cursors it last saw the writer also knows how many writes no rule can stop
//! (`unobstructed_until`). Those take a straight path that looks at no reader and does not read the slot
//! it fills, unless the sample there owns shared data that must be dropped; the sample is moved in eight
//! bytes at a time (see `move_into` for why). A NeverSkipping reader without subsampling has a straight
//! path too: the stamp says the sample is there, its bytes are copied (unless the stream has ever carried
//! shared data, when the payload is looked at), and only the cursor is published. Both paths are inlined
//! into their callers; everything else is out of line.
//!
//! Each reader publishes its counters under a sequence lock of its own, so a snapshot from another
//! thread always satisfies `written = read + skipped + overwritten + queued` exactly. The read count is
//! not published: it follows from the cursor and the others. Lapping is accounted lazily: samples beyond
//! a reader's share count as overwritten (FIFO) or skipped (readers of the newest) the moment they are,
//! whether the reader looked yet or not, so `queued` never exceeds the share.
//!
//! Subsampling belongs to the stream: a reader keeps the samples whose sequence is a multiple of its
//! subsampling, and its policy applies to those (`Subsampling`).
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
use std::mem::{self, MaybeUninit};
use std::ops::Deref;
use std::sync::Arc;

use kairos_diagram::{MAX_BUFFER_SIZE, ReaderPolicy};

use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::stats::{LinkCounters, SharedLatency};
use crate::sync::{
    AtomicBool, AtomicU64, LightFence, Mutex, Ordering, SPINS, UnsafeCell, fence, heavy_fence, light_fence,
    lock, spin, yield_now,
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
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WriteError {
    /// The writer waited for a NeverSkipping reader and was stopped meanwhile.
    #[error("stopped while waiting for a NeverSkipping reader to make room")]
    Stopped,
    /// The NeverSkipping reader to wait for runs in the writer's own thread (both in one execution
    /// group): it cannot make room until the write returns, so the write would wait for ever.
    #[error(
        "the NeverSkipping link '{link}' is full ({capacity} samples) and its reader runs in this same \
         thread (one execution group), so it cannot read until this write returns; give the link a \
         larger capacity or another policy, or take one of its ends out of the group"
    )]
    ReaderInWritersThread {
        /// The link's name, as in the statistics.
        link: Arc<str>,
        /// The reader's share of the ring.
        capacity: u64,
    },
}

/// How one reader attaches to an output.
#[derive(Debug, Clone)]
pub struct ReaderConfig {
    /// The reader policy.
    pub policy: ReaderPolicy,
    /// This reader's logical buffer size; `None` takes the output's. At most the ring's size.
    pub capacity: Option<usize>,
    /// Keep one sample in this many of the producer's sequence (1 keeps all): the samples whose sequence
    /// number is a multiple of it. The policy then applies to that stream, whatever the policy.
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
    /// Initialised once the slot is first written. Whether its sample must be dropped when replaced is
    /// the writer's `slot_needs_drop` flag for the slot.
    sample: UnsafeCell<MaybeUninit<Sample>>,
}

/// What a reader publishes for the writer and for statistics. Only the reader writes it.
struct Progress {
    /// Sequence lock over the fields below: odd while the reader updates them.
    version: AtomicU64,
    cursor: AtomicU64,
    skipped: AtomicU64,
    overwritten: AtomicU64,
    repeated: AtomicU64,
    /// The sequence the reader is cloning now, or [`IDLE`].
    cloning: AtomicU64,
}

/// Which samples of the producer's sequence a reader keeps: those whose sequence number is a multiple
/// of N. A property of the stream, not of the reads: whatever the policy, and however often the reader
/// looks, it sees the same samples (and never waits for a sample subsampling would not keep).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Subsampling(u64);

impl Subsampling {
    fn new(one_in: u32) -> Self {
        Subsampling(u64::from(one_in.max(1)))
    }

    /// The first kept sequence at or after `sequence`.
    fn kept_from(self, sequence: u64) -> u64 {
        match self.0 {
            1 => sequence,
            n => sequence.div_ceil(n).saturating_mul(n),
        }
    }

    /// The newest kept sequence before `end`, if there is one.
    fn kept_before(self, end: u64) -> Option<u64> {
        let last = end.checked_sub(1)?;
        // No division on the way of every read when nothing is subsampled.
        Some(if self.0 == 1 { last } else { last - last % self.0 })
    }

    /// How many kept sequences lie in `from..to`.
    fn kept_in(self, from: u64, to: u64) -> u64 {
        match self.0 {
            _ if to <= from => 0,
            1 => to - from,
            n => to.div_ceil(n) - from.div_ceil(n),
        }
    }
}

/// Counters as the reader last published them.
///
/// How many samples were read is not among them: every sequence from the reader's join to its cursor
/// was read, skipped or overwritten, so it follows from the others (see [`Published::read`]). A read
/// on the straight path then changes the cursor alone, which needs no sequence lock.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Published {
    cursor: u64,
    skipped: u64,
    overwritten: u64,
    repeated: u64,
}

struct ReaderShared {
    link: Arc<str>,
    policy: ReaderPolicy,
    capacity: u64,
    subsampling: Subsampling,
    joined_at: u64,
    signal: Arc<RunSignal>,
    attached: AtomicBool,
    /// `written` when the reader detached ([`EMPTY`] while attached): its counts freeze there.
    detached_at: AtomicU64,
    progress: Padded<Progress>,
    /// Written by the reader for every sample: kept off the lines the writer reads for every sample.
    latency: Padded<SharedLatency>,
}

impl Published {
    /// How many samples the reader got: those from its join (`joined_at`) to its cursor that it neither
    /// skipped nor lost to the writer.
    fn read(&self, joined_at: u64) -> u64 {
        (self.cursor - joined_at).saturating_sub(self.skipped + self.overwritten)
    }
}

impl ReaderShared {
    /// The oldest sequence this reader may still clone, given a cursor it published.
    fn floor(&self, cursor: u64) -> u64 {
        match self.policy {
            ReaderPolicy::Fifo | ReaderPolicy::NeverSkipping => cursor,
            // These clone the newest kept sample, which is at least the newest kept before their cursor
            // (Sampling clones that one again when nothing newer is kept).
            ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext | ReaderPolicy::Sampling => {
                self.subsampling.kept_before(cursor).unwrap_or(0)
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
        let mut counters = counters_of(self, counts, written);
        counters.latency = self.latency.snapshot().summary();
        counters
    }
}

/// The counters of `reader` when it had published `counts` and `written` samples had been written.
///
/// `queued` never exceeds the reader's share: samples the writer laps before the reader looks are
/// accounted at once, as the reader will account them when it does look. A FIFO reader has lost them to
/// the writer (overwritten, those its subsampling keeps; skipped, the others); LastOrNext, WaitForNext
/// and Sampling would have passed over them anyway, a lapped sample never being the newest (skipped).
fn counters_of(reader: &ReaderShared, counts: Published, written: u64) -> LinkCounters {
    let written = written.max(counts.cursor);
    let mut queued = written - counts.cursor;
    let mut skipped = counts.skipped;
    let mut overwritten = counts.overwritten;
    if queued > reader.capacity && reader.policy != ReaderPolicy::NeverSkipping {
        let lapped_until = written - reader.capacity;
        let lapped = lapped_until - counts.cursor;
        let lost = match reader.policy {
            ReaderPolicy::Fifo => reader.subsampling.kept_in(counts.cursor, lapped_until),
            _ => 0,
        };
        overwritten += lost;
        skipped += lapped - lost;
        queued = reader.capacity;
    }
    LinkCounters {
        written: written - reader.joined_at,
        read: counts.read(reader.joined_at),
        skipped,
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

impl Watched {
    /// The first sequence whose write must look at this reader, as far as its cursor last seen tells.
    ///
    /// Writing sequence `s` needs no look at a NeverSkipping reader while `s - cursor < capacity`
    /// (rule 1), nor at another reader while the sample it replaces, `s - slots`, is below that
    /// reader's floor (rule 2). The cursor seen is never ahead of the real one, so this errs on the safe
    /// side.
    fn first_obstructed_write(&self, slots: u64) -> u64 {
        if self.reader.policy == ReaderPolicy::NeverSkipping {
            self.seen_cursor.saturating_add(self.reader.capacity)
        } else {
            self.reader.floor(self.seen_cursor).saturating_add(slots)
        }
    }
}

/// The writer's view of the readers, changed only by the thread inside a write.
#[derive(Default)]
struct WriterState {
    /// The `version` of the reader set this view was taken at.
    version: u64,
    /// The first sequence whose write must look at the readers again: before it, as far as the cursors
    /// last seen tell, no NeverSkipping reader's share is full and no other reader can still reach the
    /// sample a write replaces. Until then a write takes the straight path ([`OutputBuffer::write`]).
    unobstructed_until: u64,
    readers: Vec<Watched>,
    /// Signals of the readers that have threads: each write notifies them (an unpark only if armed).
    threads: Vec<Arc<RunSignal>>,
    /// Reactive readers, run after each write once the write is over (they may write themselves).
    reactive: Option<ReactiveReaders>,
    /// The fence of the writer's side of its handshakes, looked up once (a full one until then).
    light_fence: LightFence,
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
        let mut state = WriterState {
            version: shared.version.load(Ordering::SeqCst),
            unobstructed_until: 0,
            readers,
            threads,
            reactive: (!reactive.is_empty()).then(|| Arc::from(reactive)),
            light_fence: LightFence::decided(),
        };
        // After `version`: `close` raises the flag before it bumps the version, so a view taken at the
        // new version sees the stream closed, and one at the old version is replaced at the next write.
        state.unobstructed_until = if shared.closed.load(Ordering::Acquire) {
            0
        } else {
            state.first_obstructed_write(shared.slots.len() as u64)
        };
        state
    }

    /// The first sequence a write may not take the straight path for.
    fn first_obstructed_write(&self, slots: u64) -> u64 {
        self.readers
            .iter()
            .map(|watched| watched.first_obstructed_write(slots))
            .min()
            .unwrap_or(u64::MAX)
    }

    /// After a write that had to look at the readers: reloads the cursors of those that would stop the
    /// next write, so that while the readers keep up only about one write in a share looks at them.
    fn look_ahead(&mut self, next: u64, slots: u64) {
        for watched in &mut self.readers {
            if watched.first_obstructed_write(slots) <= next {
                watched.seen_cursor = watched.reader.progress.cursor.load(Ordering::Acquire);
            }
        }
        self.unobstructed_until = self.first_obstructed_write(slots);
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

/// An index below `Shared::mask + 1`, the length of `Shared::slots` and `Shared::slot_needs_drop`.
#[derive(Clone, Copy)]
struct SlotIndex(usize);

/// One flag per slot: whether its sample owns shared data (and so must be dropped when replaced). The
/// writer reads one per write, so they lie on cache lines of their own: a neighbour in the heap that
/// another thread writes (a reader's latency counts, say) would take the line away at every write.
struct DropFlags {
    lines: Box<[FlagLine]>,
    /// How many flags are up: while none is, a write need not look at its slot's.
    raised: usize,
}

#[repr(align(128))]
#[derive(Clone, Copy)]
struct FlagLine([bool; FLAGS_PER_LINE]);

const FLAGS_PER_LINE: usize = 128;

impl DropFlags {
    /// All down, for `slots` slots.
    fn new(slots: usize) -> Self {
        DropFlags {
            lines: vec![FlagLine([false; FLAGS_PER_LINE]); slots.div_ceil(FLAGS_PER_LINE)].into_boxed_slice(),
            raised: 0,
        }
    }

    /// # Safety
    ///
    /// `index` is below the slot count given to [`Self::new`].
    #[inline]
    unsafe fn get(&self, SlotIndex(index): SlotIndex) -> bool {
        self.raised != 0
            // SAFETY: as the caller guarantees, the line exists.
            && unsafe { self.lines.get_unchecked(index / FLAGS_PER_LINE).0[index % FLAGS_PER_LINE] }
    }

    /// # Safety
    ///
    /// As [`Self::get`].
    #[inline]
    unsafe fn set(&mut self, SlotIndex(index): SlotIndex, value: bool) {
        // SAFETY: as the caller guarantees, the line exists.
        let flag =
            unsafe { &mut self.lines.get_unchecked_mut(index / FLAGS_PER_LINE).0[index % FLAGS_PER_LINE] };
        if *flag != value {
            *flag = value;
            if value {
                self.raised += 1;
            } else {
                self.raised -= 1;
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
    /// Per slot, whether its sample owns shared data (an `Arc`) and must be dropped when replaced.
    /// Touched only inside a write, like `writer_state`.
    slot_needs_drop: UnsafeCell<DropFlags>,
    /// Raised (for good) before the first sample that owns shared data is stamped: until then a reader
    /// copies samples without looking at their payload.
    carries_shared_data: AtomicBool,
    /// Bumped whenever a reader attaches or detaches and when the stream is closed: the straight path
    /// of a write looks at this alone.
    version: Padded<AtomicU64>,
    closed: AtomicBool,
    /// Set while the writer sleeps waiting for a NeverSkipping reader.
    writer_waiting: Padded<AtomicBool>,
    registry: Mutex<Registry>,
}

// SAFETY: `slots`, `writer_state` and `slot_needs_drop` are the only fields without their own
// synchronisation; the module documentation gives the rules under which threads touch them, and `Sample` is
// `Send + Sync`.
unsafe impl Sync for Shared {}
// SAFETY: as above; nothing in `Shared` is tied to a thread.
unsafe impl Send for Shared {}

impl Shared {
    /// The index of the slot of `sequence`, in `slots` and in `slot_needs_drop`: both are `mask + 1`
    /// long, so it needs no bounds check on the way of a sample.
    #[inline]
    fn slot_index(&self, sequence: u64) -> SlotIndex {
        SlotIndex((sequence & self.mask) as usize)
    }

    #[inline]
    fn slot(&self, sequence: u64) -> &Slot {
        let SlotIndex(index) = self.slot_index(sequence);
        // SAFETY: `slot_index` is below `slots.len()`.
        unsafe { self.slots.get_unchecked(index) }
    }

    /// Puts the sample at `sample` in the slot of `sequence` and stamps it. Returns the sample it
    /// replaced when that one owns shared data (and so must be dropped, outside the write).
    ///
    /// # Safety
    ///
    /// Inside a write (odd epoch taken by this thread); no reader can still reach the sample the slot
    /// holds (rules 1 and 2); `sample` is a valid sample the caller forgets afterwards.
    #[inline]
    unsafe fn put(&self, sequence: u64, sample: *const Sample) -> Option<Sample> {
        // SAFETY: inside a write, as the caller guarantees: nobody else touches the flags or the slot.
        let replaced = unsafe { self.holds_sample_to_drop(sequence) }.then(|| {
            // SAFETY: as above; a raised flag means the slot holds a sample, which is read out here
            // and so no longer needs a drop there. `slot_index` is in bounds.
            unsafe {
                self.slot_needs_drop
                    .with_mut(|flags| (*flags).set(self.slot_index(sequence), false));
                self.slot(sequence).sample.with(|held| (*held).assume_init_read())
            }
        });
        // SAFETY: the sample the slot held, if one needed dropping, was read out just above.
        unsafe { self.put_over_plain(sequence, sample) };
        replaced
    }

    /// Whether the slot of `sequence` holds a sample that owns shared data (its `slot_needs_drop` flag).
    ///
    /// # Safety
    ///
    /// Inside a write: only the writer touches the flags.
    #[inline]
    unsafe fn holds_sample_to_drop(&self, sequence: u64) -> bool {
        let index = self.slot_index(sequence);
        // SAFETY: as the caller guarantees; `slot_index` is in bounds.
        self.slot_needs_drop.with(|flags| unsafe { (*flags).get(index) })
    }

    /// Puts the sample at `sample` over the plain sample (or none) in the slot of `sequence`, and stamps
    /// it: the writer's straight path, which does not read the slot at all.
    ///
    /// Why not: the reader that cloned the sample last may hold the slot's cache lines, and loading
    /// them back would cost the writer a round trip to that core on every write.
    ///
    /// # Safety
    ///
    /// As [`Self::put`], and the slot's sample owns no shared data (its `slot_needs_drop` flag is down).
    #[inline]
    unsafe fn put_over_plain(&self, sequence: u64, sample: *const Sample) {
        let index = self.slot_index(sequence);
        let slot = self.slot(sequence);
        // SAFETY: as the caller guarantees; writing over a plain sample loses nothing; `slot_index` is
        // in bounds.
        unsafe {
            // The flag is down (a plain sample or none): raised only for a sample that owns shared
            // data, so a plain one is put without a store to the flags.
            if (*sample).payload.owns_shared_data() {
                self.slot_needs_drop.with_mut(|flags| (*flags).set(index, true));
                // Before the stamp (release), which readers acquire before they look at this.
                if !self.carries_shared_data.load(Ordering::Relaxed) {
                    self.carries_shared_data.store(true, Ordering::Relaxed);
                }
            }
            move_into(slot, sample);
        }
        slot.stamp.store(sequence, Ordering::Release);
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

    /// A clone of sample `sequence`, which the caller saw stamped in its slot: rule 1 or 2 guarantees
    /// the slot holds it unchanged while this runs.
    #[inline]
    fn clone_unchecked(&self, sequence: u64) -> Sample {
        // No check of the stamp here: a writer may mark the slot REPLACING meanwhile, and then waits for
        // this clone to end.
        let slot = self.slot(sequence);
        // SAFETY: the stamp the caller saw (acquire) follows the sample's write, so the slot is
        // initialised; rule 1, or `cloning` announced with the stamp checked after (rule 2), keeps the
        // writer from replacing it until the clone is over.
        slot.sample.with(|sample| {
            // SAFETY: as above.
            let sample = unsafe { (*sample).assume_init_ref() };
            // The stamp the caller acquired follows the raising of `carries_shared_data` for a sample that
            // needs it.
            if self.carries_shared_data.load(Ordering::Relaxed) && sample.payload.owns_shared_data() {
                clone_shared(sample)
            } else {
                // SAFETY: a plain sample owns nothing, so a copy of its bytes is a clone of it; taken
                // whole, without the field-by-field build of `clone` that the caller's move then
                // reloads.
                unsafe { std::ptr::read(sample) }
            }
        })
    }

    #[cold]
    fn wake_blocked_writer(&self) {
        let writer = lock(&self.registry).blocked_writer.take();
        if let Some(writer) = writer {
            writer.wake();
        }
    }
}

/// A clone of a sample that owns shared data: kept out of the readers' straight path, where samples are
/// mostly plain.
#[inline(never)]
fn clone_shared(sample: &Sample) -> Sample {
    sample.clone()
}

impl Drop for Shared {
    fn drop(&mut self) {
        // Plain samples own nothing; the flags name the slots whose samples do.
        let slots = &self.slots;
        self.slot_needs_drop.with_mut(|flags| {
            for (index, slot) in slots.iter().enumerate() {
                // SAFETY: `&mut self`: no write or clone is in progress; `index` is below the slot
                // count; a raised flag means the slot holds a sample, initialised when the flag was
                // raised.
                if unsafe { (*flags).get(SlotIndex(index)) } {
                    // SAFETY: as above: the raised flag says the sample is initialised, and it is
                    // dropped once, here, as the buffer goes.
                    slot.sample
                        .with_mut(|sample| unsafe { (*sample).assume_init_drop() });
                }
            }
        });
    }
}

/// Moves the sample at `sample` into `slot`, eight bytes at a time.
///
/// Why eight: the sample was usually built just before, by stores of eight bytes or more that may
/// still sit in this core's store buffer. An eight-byte load inside one of them is forwarded from it;
/// the sixteen-byte loads of a plain move are not, and then wait until every older store reaches the
/// cache, which for the writer means the previous sample's slot stores, each waiting for the reader's
/// core to give up the line. The volatile reads keep the compiler from widening the loads again.
/// Measured on benchmark 3: 24 M/s instead of 20 M/s across two cores.
///
/// # Safety
///
/// Inside a write; the slot's sample, if any, has been read out or needs no drop; `sample` is a valid
/// sample that the caller forgets afterwards (its bytes now live in the slot).
#[inline]
unsafe fn move_into(slot: &Slot, sample: *const Sample) {
    const {
        assert!(size_of::<Sample>().is_multiple_of(8) && align_of::<Sample>() >= 8);
    }
    let source = sample.cast::<MaybeUninit<u64>>();
    slot.sample.with_mut(|held| {
        let target = held.cast::<MaybeUninit<u64>>();
        for word in 0..size_of::<Sample>() / 8 {
            // SAFETY: both point to a whole `Sample`, aligned to 8; `MaybeUninit` words carry padding
            // bytes as they are.
            unsafe { target.add(word).write(source.add(word).read_volatile()) };
        }
    });
}

/// Inside a write: owns the writer's state until dropped.
struct WriteGuard<'a> {
    shared: &'a Shared,
    epoch: u64,
}

impl<'a> WriteGuard<'a> {
    /// Enters a write, with a view of the readers as of now, starting from `turn` if the caller already
    /// took it.
    fn enter(shared: &'a Shared, mut turn: Option<Self>) -> Self {
        loop {
            let guard = turn.take().unwrap_or_else(|| Self::take_turn(shared));
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

    /// The sequence this write puts, if it may take the straight path: the reader set is the one the
    /// writer's view was taken at (and the stream is still open), the sequence is below
    /// `unobstructed_until`, and the slot holds a plain sample or none.
    #[inline]
    fn unobstructed_sequence(&self) -> Option<u64> {
        let shared = self.shared;
        // SAFETY: inside a write (odd epoch taken by this thread): nobody else touches the state.
        let (state_version, unobstructed_until, light_fence) = shared.writer_state.with(|state| unsafe {
            (
                (*state).version,
                (*state).unobstructed_until,
                (*state).light_fence,
            )
        });
        // Paired with the heavy fence in `attach`, as in `enter`. A view not yet taken fences fully.
        light_fence.run();
        let version = shared.version.load(Ordering::SeqCst);
        let written = shared.written.load(Ordering::Relaxed);
        let unobstructed = state_version == version && written < unobstructed_until;
        // SAFETY: inside a write, as above.
        (unobstructed && !unsafe { shared.holds_sample_to_drop(written) }).then_some(written)
    }

    /// Makes the epoch odd for this thread, waiting out another thread's write to the same output.
    fn take_turn(shared: &'a Shared) -> Self {
        loop {
            if let Some(guard) = Self::try_take_turn(shared) {
                return guard;
            }
            yield_now();
        }
    }

    /// Makes the epoch odd for this thread unless another thread is writing to the same output.
    #[inline]
    fn try_take_turn(shared: &'a Shared) -> Option<Self> {
        let epoch = shared.writer_epoch.load(Ordering::Relaxed);
        let free = epoch.is_multiple_of(2)
            && shared
                .writer_epoch
                .compare_exchange(epoch, epoch + 1, Ordering::SeqCst, Ordering::Relaxed)
                .is_ok();
        free.then_some(WriteGuard {
            shared,
            epoch: epoch + 1,
        })
    }

    fn with_state<R>(&mut self, f: impl FnOnce(&mut WriterState) -> R) -> R {
        // SAFETY: inside a write, and `&mut self` keeps this the only borrow.
        self.shared
            .writer_state
            .with_mut(|state| f(unsafe { &mut *state }))
    }

    /// Makes sample `sequence`, just put in its slot, visible and notifies the readers' threads.
    /// Returns the reactive readers, to run once the write is over.
    #[inline]
    fn announce(&mut self, sequence: u64) -> Option<ReactiveReaders> {
        self.shared.written.store(sequence + 1, Ordering::Release);
        self.with_state(|state| {
            for signal in &state.threads {
                signal.notify_thread(state.light_fence);
            }
            state.reactive.clone()
        })
    }
}

impl Drop for WriteGuard<'_> {
    #[inline]
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
                        sample: UnsafeCell::new(MaybeUninit::uninit()),
                    })
                    .collect(),
                written: Padded(AtomicU64::new(0)),
                writer_epoch: Padded(AtomicU64::new(0)),
                writer_state: UnsafeCell::new(WriterState::default()),
                slot_needs_drop: UnsafeCell::new(DropFlags::new(slots)),
                carries_shared_data: AtomicBool::new(false),
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
        let subsampling = Subsampling::new(config.subsampling);
        if subsampling.0 > slots && config.policy.reads_newest() {
            tracing::warn!(
                "link {} keeps one sample in {} but {} holds {slots}: the newest kept sample may be gone \
                 before it is read; give the output a buffer of at least {} samples",
                config.link,
                subsampling.0,
                shared.output,
                subsampling.0
            );
        }
        shared.version.fetch_add(1, Ordering::SeqCst);
        heavy_fence();
        shared.wait_for_writer_between_writes();
        let joined_at = shared.written.load(Ordering::SeqCst).saturating_sub(1);
        let reader = Arc::new(ReaderShared {
            link: Arc::from(config.link),
            policy: config.policy,
            capacity,
            subsampling,
            joined_at,
            signal: Arc::clone(&signal),
            attached: AtomicBool::new(true),
            detached_at: AtomicU64::new(EMPTY),
            progress: Padded(Progress {
                version: AtomicU64::new(0),
                cursor: AtomicU64::new(joined_at),
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
            subsampling,
            counts: Published {
                cursor: joined_at,
                skipped: 0,
                overwritten: 0,
                repeated: 0,
            },
            signal,
            straight: config.policy == ReaderPolicy::NeverSkipping && config.subsampling <= 1,
            light_fence: LightFence::decided(),
        }
    }

    /// Writes a sample, waking every reader. Blocks only while a NeverSkipping reader's share is full;
    /// `writer` is the writing component's signal, through which the runtime can stop that wait.
    #[inline(always)]
    #[expect(
        clippy::inline_always,
        reason = "left to itself the compiler calls it, and a sample moved through a call costs a copy: \
                  benchmark 3 measured 1.4 ns a write"
    )]
    pub fn write(&self, sample: Sample, writer: &Arc<RunSignal>) -> Result<(), WriteError> {
        // The straight path, taken by almost every write while the readers keep up: no loop over the
        // readers, and small enough to inline, so the sample is not copied once more on its way in.
        let Some(mut guard) = WriteGuard::try_take_turn(&self.shared) else {
            return self.write_with_checks(sample, None, writer);
        };
        let Some(sequence) = guard.unobstructed_sequence() else {
            return self.write_with_checks(sample, Some(guard), writer);
        };
        let shared = &*self.shared;
        // SAFETY: inside a write, below `unobstructed_until`: no reader can still reach the sample this
        // slot held, and it is a plain one (`unobstructed_sequence`); `sample` is forgotten right after.
        unsafe { shared.put_over_plain(sequence, &raw const sample) };
        mem::forget(sample);
        let reactive = guard.announce(sequence);
        drop(guard);
        if let Some(reactive) = reactive {
            Self::run_reactive(&reactive);
        }
        Ok(())
    }

    /// A write that looks at the readers: it waits for a NeverSkipping reader's room, waits out clones of
    /// the sample it replaces, and then looks ahead to how many writes may take the straight path.
    #[cold]
    #[inline(never)]
    fn write_with_checks(
        &self,
        sample: Sample,
        mut turn: Option<WriteGuard<'_>>,
        writer: &Arc<RunSignal>,
    ) -> Result<(), WriteError> {
        let shared = &*self.shared;
        let mut guard = loop {
            let mut guard = WriteGuard::enter(shared, turn.take());
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
        let sequence = shared.written.load(Ordering::Relaxed);
        let slots = shared.slots.len() as u64;
        if let Some(old) = sequence.checked_sub(slots) {
            let slot = shared.slot(sequence);
            guard.with_state(|state| state.claim(slot, old));
        }
        // SAFETY: inside a write; `claim` (rule 2) and the NeverSkipping wait (rule 1) leave no reader
        // cloning the sample this slot held; `sample` is forgotten right after.
        let replaced = unsafe { shared.put(sequence, &raw const sample) };
        mem::forget(sample);
        let reactive = guard.announce(sequence);
        guard.with_state(|state| state.look_ahead(sequence + 1, slots));
        drop(guard);
        // Dropped outside the write: the last reference to a large payload frees it here.
        drop(replaced);
        if let Some(reactive) = reactive {
            Self::run_reactive(&reactive);
        }
        Ok(())
    }

    /// Runs the reactive readers after a write, once it is over (they may write themselves).
    #[inline(never)]
    fn run_reactive(reactive: &ReactiveReaders) {
        for signal in reactive.iter() {
            signal.notify_data();
        }
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
        if !has_room() && reader.signal.is_bound_to_current_thread() {
            return Err(WriteError::ReaderInWritersThread {
                link: Arc::clone(&reader.link),
                capacity: reader.capacity,
            });
        }
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
        // Sends the next write off the straight path, to the check of `closed`.
        self.shared.version.fetch_add(1, Ordering::SeqCst);
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

    /// How many samples the ring holds: at least the largest share of a reader.
    pub fn slots(&self) -> usize {
        self.shared.slots.len()
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

/// A sample a read took: one not read before, or the one a Sampling reader read last, again.
enum Taken {
    New(Sample),
    Again(Sample),
}

/// One reader of an output's buffer: the reading end of a link. Dropping it detaches it.
pub struct Reader {
    buffer: OutputBuffer,
    shared: Arc<ReaderShared>,
    policy: ReaderPolicy,
    capacity: u64,
    subsampling: Subsampling,
    /// The counters, cursor included, as this reader knows them (published after each change).
    counts: Published,
    signal: Arc<RunSignal>,
    /// NeverSkipping without subsampling: reads take the straight path of [`Self::try_read`].
    straight: bool,
    /// The fence of this reader's side of its handshake with the writer, looked up once.
    light_fence: LightFence,
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
    #[inline(always)]
    #[expect(
        clippy::inline_always,
        reason = "as for `OutputBuffer::write`: the straight path is small, and a call costs the sample a copy"
    )]
    pub fn try_read(&mut self) -> Option<Sample> {
        if !self.straight {
            return self.try_read_by_policy();
        }
        let cursor = self.never_skipping_ready()?;
        Some(self.take_straight(cursor))
    }

    /// The straight path's read of the sample at `cursor`, which [`Self::never_skipping_ready`] found written.
    ///
    /// The usual lossless link: small enough to inline, so that the sample goes from its slot to the
    /// caller in one move; no policy loop; only the cursor is published.
    #[inline(always)]
    #[expect(
        clippy::inline_always,
        reason = "called from the inlined `read` and `try_read`; a call here would cost the sample a copy"
    )]
    fn take_straight(&mut self, cursor: u64) -> Sample {
        let sample = self.buffer.shared.clone_unchecked(cursor);
        self.counts.cursor = cursor + 1;
        self.shared.latency.record(sample.latency_nanos());
        // Only the cursor changed (the read count follows from it), so no sequence lock. Release: the
        // writer that sees this cursor may replace the sample cloned above.
        self.shared.progress.cursor.store(cursor + 1, Ordering::Release);
        self.signal.disarm();
        self.make_room_for_writer();
        sample
    }

    /// [`Self::try_read`] for every policy and subsampling.
    #[inline(never)]
    fn try_read_by_policy(&mut self) -> Option<Sample> {
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
    #[inline]
    fn make_room_for_writer(&self) {
        // Paired with the writer raising `writer_waiting` before it looks at the cursor again.
        self.light_fence.run();
        if self.buffer.shared.writer_waiting.load(Ordering::Relaxed) {
            self.buffer.shared.wake_blocked_writer();
        }
    }

    /// The next sample under the reader's policy, sleeping until one arrives.
    ///
    /// Returns early with [`ReadError::Stopped`] when the component is stopped, and with
    /// [`ReadError::Interrupted`] when `interruptible` and the runtime wants the component's attention.
    #[inline(always)]
    #[expect(
        clippy::inline_always,
        reason = "as for `OutputBuffer::write`: the straight path is small, and a call costs the sample a copy"
    )]
    pub fn read(&mut self, interruptible: bool) -> Result<Sample, ReadError> {
        // A sample already waiting on the straight path: no call, and one move to the caller (not two
        // through an `Option`).
        if self.straight
            && let Some(cursor) = self.never_skipping_ready()
        {
            return Ok(self.take_straight(cursor));
        }
        self.read_waiting(interruptible)
    }

    /// [`Self::read`] past its straight path: under any policy, sleeping until a sample arrives.
    #[inline(never)]
    fn read_waiting(&mut self, interruptible: bool) -> Result<Sample, ReadError> {
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
            self.signal.park_for_input();
        }
    }

    /// Whether a sample is waiting for this reader (a Sampling reader: whether any exists at all).
    pub fn has_pending(&self) -> bool {
        let written = self.buffer.written();
        match self.policy {
            ReaderPolicy::Sampling => written > 0,
            _ => self.subsampling.kept_from(self.counts.cursor) < written,
        }
    }

    /// Skips everything pending (counted as skipped by policy); the next read waits for a new sample.
    pub fn skip_pending(&mut self) {
        let before = self.counts.cursor;
        self.pass_all(self.buffer.written());
        if self.counts.cursor != before {
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
        let before = self.counts;
        let taken = match self.policy {
            ReaderPolicy::NeverSkipping => self.next_never_skipping().map(Taken::New),
            ReaderPolicy::Fifo => self.next_fifo().map(Taken::New),
            ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext => self.newest_unread().map(Taken::New),
            ReaderPolicy::Sampling => self.sampled(),
        };
        if let Some(Taken::New(sample)) = &taken {
            self.shared.latency.record(sample.latency_nanos());
        }
        if self.counts != before {
            self.publish();
        }
        taken.map(|(Taken::New(sample) | Taken::Again(sample))| sample)
    }

    /// Moves the cursor over the written samples before the next kept one, counting them as skipped.
    /// Returns whether the cursor is now on a kept sample that was written.
    fn pass_to_kept(&mut self, written: u64) -> bool {
        let cursor = self.counts.cursor;
        let kept = self.subsampling.kept_from(cursor);
        let passed = kept.min(written.max(cursor));
        self.counts.skipped += passed - cursor;
        self.counts.cursor = passed;
        kept < written
    }

    /// Moves the cursor over every written sample, counting them as skipped.
    fn pass_all(&mut self, written: u64) {
        let cursor = self.counts.cursor;
        if written > cursor {
            self.counts.skipped += written - cursor;
            self.counts.cursor = written;
        }
    }

    /// NeverSkipping: the next kept sample, which the writer cannot have replaced (rule 1).
    fn next_never_skipping(&mut self) -> Option<Sample> {
        if self.subsampling.0 > 1 && !self.pass_to_kept(self.buffer.written()) {
            return None;
        }
        let cursor = self.never_skipping_ready()?;
        let sample = self.buffer.shared.clone_unchecked(cursor);
        self.counts.cursor = cursor + 1;
        Some(sample)
    }

    /// NeverSkipping: the cursor, if its sample was written.
    ///
    /// That is read from the slot's stamp, not from `written`: the slot's cache line comes to this core
    /// anyway, and leaving `written` alone spares both cores a transfer per sample.
    #[inline]
    fn never_skipping_ready(&self) -> Option<u64> {
        let cursor = self.counts.cursor;
        (self.buffer.shared.slot(cursor).stamp.load(Ordering::Acquire) == cursor).then_some(cursor)
    }

    /// FIFO: the oldest kept sample still within this reader's share. What the writer lapped counts as
    /// overwritten (or skipped, what subsampling would have passed over anyway), as in `counters_of`.
    fn next_fifo(&mut self) -> Option<Sample> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            if cursor >= written {
                return None;
            }
            if written - cursor > self.capacity {
                let lapped_until = written - self.capacity;
                let lost = self.subsampling.kept_in(cursor, lapped_until);
                self.counts.overwritten += lost;
                self.counts.skipped += lapped_until - cursor - lost;
                self.counts.cursor = lapped_until;
            }
            if !self.pass_to_kept(written) {
                return None;
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

    /// The newest kept sample below `written`, if the ring may still hold it. A ring of fewer slots than
    /// the subsampling can have lost it (`attach` warns of that; the runtime sizes rings so it cannot).
    fn newest_kept(&self, written: u64) -> Option<u64> {
        let newest = self.subsampling.kept_before(written)?;
        (written - newest <= self.buffer.shared.slots.len() as u64).then_some(newest)
    }

    /// LastOrNext and WaitForNext: the newest kept sample if it is unread; older unread ones are skipped.
    fn newest_unread(&mut self) -> Option<Sample> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            if cursor >= written {
                return None;
            }
            let Some(newest) = self.newest_kept(written).filter(|&newest| newest >= cursor) else {
                // Only samples subsampling leaves out are pending (or the kept one is gone).
                self.pass_all(written);
                return None;
            };
            match self.clone_announced(newest) {
                Ok(sample) => {
                    self.counts.skipped += written - 1 - cursor;
                    self.counts.cursor = written;
                    return Some(sample);
                }
                Err(written_at_least) => written = written_at_least,
            }
        }
    }

    /// Sampling: the newest kept sample, again if nothing newer was kept (unless the stream is closed).
    fn sampled(&mut self) -> Option<Taken> {
        let mut written = self.buffer.written();
        loop {
            let cursor = self.counts.cursor;
            let newest = self.newest_kept(written)?;
            let again = newest < cursor;
            if again && self.buffer.shared.closed.load(Ordering::Acquire) {
                // A closed stream has nothing new to give: end it rather than repeat forever.
                return None;
            }
            let sample = match self.clone_announced(newest) {
                Ok(sample) => sample,
                Err(written_at_least) => {
                    written = written_at_least;
                    continue;
                }
            };
            if again {
                // What is pending, if anything, subsampling leaves out.
                self.pass_all(written);
                self.counts.repeated += 1;
                return Some(Taken::Again(sample));
            }
            self.counts.skipped += written - 1 - cursor;
            self.counts.cursor = written;
            return Some(Taken::New(sample));
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
        if let Some(sample) = sample {
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

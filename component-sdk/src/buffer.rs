//! The circular buffer each output owns, and the five reader policies (paper, section 2.2.2).
//!
//! One writer, any number of readers. Each reader keeps a cursor (the sequence number of the next sample
//! it has not consumed) and its own logical capacity; the ring is as large as the largest of them. Every
//! state change happens under one short lock, which keeps the counting identity
//! `written = read + skipped + overwritten + queued` exact for every reader at every instant. Samples are
//! cloned out, which shares their payload: nothing heavy is copied.
//!
//! Blocked readers sleep on their component's [`RunSignal`] and are woken by the writer after it releases
//! the lock. Only a NeverSkipping reader can make the writer wait.

use std::fmt;
use std::sync::Arc;

use kairos_diagram::ReaderPolicy;

use crate::sample::Sample;
use crate::signal::RunSignal;
use crate::stats::{LatencyHistogram, LinkCounters};
use crate::sync::{Mutex, lock};

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
    /// This reader's logical buffer size; `None` takes the output's.
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

struct ReaderState {
    link: Arc<str>,
    policy: ReaderPolicy,
    capacity: u64,
    subsampling: u64,
    subsample_count: u64,
    attached: bool,
    detached_at: Option<u64>,
    joined_at: u64,
    cursor: u64,
    read: u64,
    skipped: u64,
    overwritten: u64,
    repeated: u64,
    latency: LatencyHistogram,
}

impl ReaderState {
    fn counters(&self, written: u64) -> LinkCounters {
        // A detached reader's counts freeze where it left.
        let written = self.detached_at.unwrap_or(written);
        LinkCounters {
            written: written - self.joined_at,
            read: self.read,
            skipped: self.skipped,
            overwritten: self.overwritten,
            queued: written - self.cursor,
            repeated: self.repeated,
            latency: self.latency.summary(),
        }
    }
}

struct State {
    slots: Vec<Option<Sample>>,
    written: u64,
    default_capacity: u64,
    readers: Vec<ReaderState>,
    wakers: Arc<[Arc<RunSignal>]>,
    blocked_writer: Option<Arc<RunSignal>>,
    closed: bool,
}

impl State {
    fn slot(&self, sequence: u64) -> Option<&Sample> {
        let len = self.slots.len() as u64;
        self.slots.get((sequence % len) as usize)?.as_ref()
    }

    fn newest(&self) -> Option<&Sample> {
        self.slot(self.written.checked_sub(1)?)
    }

    /// Whether a NeverSkipping reader has no room left for one more sample.
    fn never_skipping_full(&self) -> bool {
        self.readers.iter().any(|r| {
            r.attached && r.policy == ReaderPolicy::NeverSkipping && self.written - r.cursor >= r.capacity
        })
    }

    /// Makes the ring at least `capacity` long, keeping every sample a reader may still need.
    fn grow(&mut self, capacity: u64) {
        let old_len = self.slots.len() as u64;
        if capacity <= old_len {
            return;
        }
        let mut slots: Vec<Option<Sample>> = (0..capacity).map(|_| None).collect();
        let first_kept = self.written.saturating_sub(old_len);
        for sequence in first_kept..self.written {
            let sample = self
                .slots
                .get_mut((sequence % old_len) as usize)
                .and_then(Option::take);
            if let Some(slot) = slots.get_mut((sequence % capacity) as usize) {
                *slot = sample;
            }
        }
        self.slots = slots;
    }

    /// Takes the next sample for reader `index` under its policy, updating its counters.
    fn take(&mut self, index: usize) -> Option<Sample> {
        let written = self.written;
        loop {
            let reader = self.readers.get(index)?;
            let (policy, cursor) = (reader.policy, reader.cursor);
            let (sample, new_cursor, skipped) = match policy {
                ReaderPolicy::Fifo | ReaderPolicy::NeverSkipping => {
                    if cursor >= written {
                        return None;
                    }
                    (self.slot(cursor)?.clone(), cursor + 1, 0)
                }
                ReaderPolicy::LastOrNext | ReaderPolicy::WaitForNext => {
                    if cursor >= written {
                        return None;
                    }
                    (self.newest()?.clone(), written, written - 1 - cursor)
                }
                ReaderPolicy::Sampling => {
                    if cursor >= written {
                        // A closed stream has nothing new to give: end it rather than repeat forever.
                        if self.closed {
                            return None;
                        }
                        let again = self.newest()?.clone();
                        if let Some(reader) = self.readers.get_mut(index) {
                            reader.repeated += 1;
                        }
                        return Some(again);
                    }
                    (self.newest()?.clone(), written, written - 1 - cursor)
                }
            };
            let reader = self.readers.get_mut(index)?;
            reader.cursor = new_cursor;
            reader.skipped += skipped;
            let keep = policy == ReaderPolicy::Sampling || reader.subsample_count % reader.subsampling == 0;
            reader.subsample_count += 1;
            if keep {
                reader.read += 1;
                reader.latency.record(sample.latency_nanos());
                return Some(sample);
            }
            reader.skipped += 1;
        }
    }
}

struct Shared {
    output: String,
    state: Mutex<State>,
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
            .finish_non_exhaustive()
    }
}

impl OutputBuffer {
    /// A buffer of `capacity` samples (at least one) for the output named `output` (`sine1.out`).
    pub fn new(output: impl Into<String>, capacity: usize) -> Self {
        let capacity = capacity.max(1) as u64;
        OutputBuffer {
            shared: Arc::new(Shared {
                output: output.into(),
                state: Mutex::new(State {
                    slots: (0..capacity).map(|_| None).collect(),
                    written: 0,
                    default_capacity: capacity,
                    readers: Vec::new(),
                    wakers: Arc::from(Vec::new()),
                    blocked_writer: None,
                    closed: false,
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
    pub fn attach(&self, config: ReaderConfig, signal: Arc<RunSignal>) -> Reader {
        let mut state = lock(&self.shared.state);
        let capacity = config
            .capacity
            .map_or(state.default_capacity, |c| c.max(1) as u64);
        state.grow(capacity);
        let joined_at = state.written.saturating_sub(1);
        state.readers.push(ReaderState {
            link: Arc::from(config.link),
            policy: config.policy,
            capacity,
            subsampling: u64::from(config.subsampling.max(1)),
            subsample_count: 0,
            attached: true,
            detached_at: None,
            joined_at,
            cursor: joined_at,
            read: 0,
            skipped: 0,
            overwritten: 0,
            repeated: 0,
            latency: LatencyHistogram::default(),
        });
        let index = state.readers.len() - 1;
        let mut wakers: Vec<Arc<RunSignal>> = state.wakers.iter().cloned().collect();
        wakers.push(Arc::clone(&signal));
        state.wakers = Arc::from(wakers);
        drop(state);
        Reader {
            buffer: self.clone(),
            index,
            policy: config.policy,
            signal,
        }
    }

    /// Writes a sample, waking every reader. Blocks only while a NeverSkipping reader's share is full;
    /// `writer` is the writing component's signal, through which the runtime can stop that wait.
    pub fn write(&self, sample: Sample, writer: &Arc<RunSignal>) -> Result<(), WriteError> {
        let mut state = lock(&self.shared.state);
        while state.never_skipping_full() {
            if writer.stop_requested() {
                return Err(WriteError::Stopped);
            }
            state.blocked_writer = Some(Arc::clone(writer));
            drop(state);
            writer.park();
            state = lock(&self.shared.state);
        }
        state.blocked_writer = None;
        if state.closed {
            return Ok(());
        }
        let len = state.slots.len() as u64;
        let index = (state.written % len) as usize;
        let replaced = state.slots.get_mut(index).and_then(|slot| slot.replace(sample));
        state.written += 1;
        let written = state.written;
        for reader in &mut state.readers {
            if reader.attached
                && reader.policy == ReaderPolicy::Fifo
                && written - reader.cursor > reader.capacity
            {
                let lapped = written - reader.cursor - reader.capacity;
                reader.overwritten += lapped;
                reader.cursor += lapped;
            }
        }
        let wakers = Arc::clone(&state.wakers);
        drop(state);
        // Dropped outside the lock: the last reference to a large payload frees it here.
        drop(replaced);
        for waker in wakers.iter() {
            waker.notify_data();
        }
        Ok(())
    }

    /// Closes the stream: readers get what is left, then [`ReadError::EndOfStream`]; later writes are dropped.
    pub fn close(&self) {
        let mut state = lock(&self.shared.state);
        state.closed = true;
        let wakers = Arc::clone(&state.wakers);
        drop(state);
        for waker in wakers.iter() {
            waker.wake();
        }
    }

    /// How many samples were written in all.
    pub fn written(&self) -> u64 {
        lock(&self.shared.state).written
    }

    /// The newest sample, if any, without consuming anything.
    pub fn newest(&self) -> Option<Sample> {
        lock(&self.shared.state).newest().cloned()
    }

    /// The counters of every reader that ever attached (a detached one frozen where it left), with its
    /// link name.
    pub fn link_counters(&self) -> Vec<(Arc<str>, LinkCounters)> {
        let state = lock(&self.shared.state);
        state
            .readers
            .iter()
            .map(|r| (Arc::clone(&r.link), r.counters(state.written)))
            .collect()
    }
}

/// One reader of an output's buffer: the reading end of a link. Dropping it detaches it.
pub struct Reader {
    buffer: OutputBuffer,
    index: usize,
    policy: ReaderPolicy,
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
        let mut state = lock(&self.buffer.shared.state);
        let sample = state.take(self.index);
        // Wake a blocked writer even without a sample: subsampling may have consumed some and made room.
        let writer = state.blocked_writer.take();
        drop(state);
        if let Some(writer) = writer {
            writer.wake();
        }
        sample
    }

    /// The next sample under the reader's policy, sleeping until one arrives.
    ///
    /// Returns early with [`ReadError::Stopped`] when the component is stopped, and with
    /// [`ReadError::Interrupted`] when `interruptible` and the runtime wants the component's attention.
    pub fn read(&mut self, interruptible: bool) -> Result<Sample, ReadError> {
        if self.policy == ReaderPolicy::WaitForNext {
            self.skip_pending();
        }
        loop {
            let mut state = lock(&self.buffer.shared.state);
            let sample = state.take(self.index);
            // Wake a blocked writer even without a sample: subsampling may have consumed some and made room.
            let writer = state.blocked_writer.take();
            let closed = state.closed;
            drop(state);
            if let Some(writer) = writer {
                writer.wake();
            }
            if let Some(sample) = sample {
                return Ok(sample);
            }
            if closed {
                return Err(ReadError::EndOfStream);
            }
            if self.signal.stop_requested() {
                return Err(ReadError::Stopped);
            }
            if interruptible && self.signal.wants_attention() {
                return Err(ReadError::Interrupted);
            }
            self.signal.park();
        }
    }

    /// Whether a sample is waiting for this reader (a Sampling reader: whether any exists at all).
    pub fn has_pending(&self) -> bool {
        let state = lock(&self.buffer.shared.state);
        state.readers.get(self.index).is_some_and(|r| match r.policy {
            ReaderPolicy::Sampling => state.written > 0,
            _ => r.cursor < state.written,
        })
    }

    /// Skips everything pending (counted as skipped by policy); the next read waits for a new sample.
    pub fn skip_pending(&mut self) {
        let mut state = lock(&self.buffer.shared.state);
        let written = state.written;
        if let Some(reader) = state.readers.get_mut(self.index) {
            reader.skipped += written - reader.cursor;
            reader.cursor = written;
        }
    }

    /// This link's counters.
    pub fn counters(&self) -> LinkCounters {
        let state = lock(&self.buffer.shared.state);
        state
            .readers
            .get(self.index)
            .map(|r| r.counters(state.written))
            .unwrap_or_default()
    }

    /// Whether the writer closed the stream and nothing is left to read.
    pub fn is_exhausted(&self) -> bool {
        let state = lock(&self.buffer.shared.state);
        state.closed
            && state
                .readers
                .get(self.index)
                .is_none_or(|r| r.cursor >= state.written)
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        let mut state = lock(&self.buffer.shared.state);
        let written = state.written;
        if let Some(reader) = state.readers.get_mut(self.index) {
            reader.attached = false;
            reader.detached_at = Some(written);
        }
        // One entry per attached reader: remove one, the component may read this output twice.
        let mut wakers: Vec<Arc<RunSignal>> = state.wakers.iter().cloned().collect();
        if let Some(position) = wakers.iter().position(|w| Arc::ptr_eq(w, &self.signal)) {
            wakers.remove(position);
        }
        state.wakers = Arc::from(wakers);
        let writer = state.blocked_writer.take();
        drop(state);
        if let Some(writer) = writer {
            writer.wake();
        }
    }
}

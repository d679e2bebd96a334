//! The signal a running component is woken through: new data, stop, pause, or a control request.

use std::fmt;
use std::sync::OnceLock;
use std::time::Duration;

use crate::sync::{
    AtomicBool, LightFence, Ordering, Thread, current_thread, heavy_fence, park, park_timeout,
};
use crate::throttle::STATUS_PERIOD;

/// One per component: the thread that runs it and the flags the runtime raises to get its attention.
///
/// Writers wake readers through it; the runtime wakes it to stop, pause, or deliver property changes and
/// actions. Waking is a futex at most, and nothing at all when the thread is not asleep: a thread arms
/// `sleeping` before it parks (see [`Self::park`]) and writers unpark only an armed one.
///
/// Every write to an output this component reads looks at `sleeping`, so the signal keeps cache lines of
/// its own: a neighbour in the heap that some thread writes often would take the line from the writer.
#[repr(align(128))]
pub struct RunSignal {
    thread: OnceLock<Thread>,
    sleeping: AtomicBool,
    stop: AtomicBool,
    paused: AtomicBool,
    control_pending: AtomicBool,
    /// The component worked since it last went quiet: a read that then sleeps a status period wakes it
    /// once, so that its status covers that work (see [`crate::component::StatusSchedule`]).
    quiet_break_armed: AtomicBool,
    /// A read slept a status period after work: the component's loop publishes its status.
    went_quiet: AtomicBool,
    /// The thread sleeps in a read, for input (not for room in a reader's share, nor for a tick): a
    /// stop's drain learns from it that a consumer has read all it can.
    awaiting_input: AtomicBool,
    reactive: Option<Box<dyn Fn() + Send + Sync>>,
}

impl fmt::Debug for RunSignal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RunSignal")
            .field("stop", &self.stop.load(Ordering::Relaxed))
            .field("paused", &self.paused.load(Ordering::Relaxed))
            .field("control_pending", &self.control_pending.load(Ordering::Relaxed))
            .field("reactive", &self.reactive.is_some())
            .finish_non_exhaustive()
    }
}

impl Default for RunSignal {
    fn default() -> Self {
        Self::new()
    }
}

impl RunSignal {
    /// A signal for a component that runs in a thread of its own (bound later with [`Self::bind_current_thread`]).
    pub fn new() -> Self {
        RunSignal {
            thread: OnceLock::new(),
            sleeping: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            paused: AtomicBool::new(false),
            control_pending: AtomicBool::new(false),
            quiet_break_armed: AtomicBool::new(false),
            went_quiet: AtomicBool::new(false),
            awaiting_input: AtomicBool::new(false),
            reactive: None,
        }
    }

    /// A signal for a reactive component: waking it runs `on_data` in the waker's thread.
    pub fn reactive(on_data: impl Fn() + Send + Sync + 'static) -> Self {
        RunSignal {
            reactive: Some(Box::new(on_data)),
            ..Self::new()
        }
    }

    /// Records the calling thread as the one to wake. Call it first thing in the component's thread.
    pub fn bind_current_thread(&self) {
        let _ = self.thread.set(current_thread());
    }

    /// Whether the calling thread is the one this signal wakes: a writer that waited here for this
    /// component would wait for itself (two members of one execution group).
    pub fn is_bound_to_current_thread(&self) -> bool {
        self.thread
            .get()
            .is_some_and(|thread| thread.id() == current_thread().id())
    }

    /// Whether the component runs without a thread of its own.
    pub fn is_reactive(&self) -> bool {
        self.reactive.is_some()
    }

    /// New data arrived for the component: unpark its thread if it is going to sleep, or run it now if it
    /// is reactive. Call it after the data is visible.
    #[inline]
    pub fn notify_data(&self) {
        if let Some(on_data) = &self.reactive {
            if !self.stop.load(Ordering::Acquire) && !self.paused.load(Ordering::Acquire) {
                on_data();
            }
            return;
        }
        self.notify_thread(LightFence::decided());
    }

    /// [`Self::notify_data`] for a component known to have a thread of its own (not reactive): an output
    /// buffer sorts its readers' signals once, not at every write, and looks its fence up once too.
    #[inline]
    pub(crate) fn notify_thread(&self, light_fence: LightFence) {
        // Paired with the heavy fence in `park`: either the sleeper's re-check sees the data, or this
        // sees it armed.
        light_fence.run();
        if self.sleeping.load(Ordering::Acquire) {
            self.wake();
        }
    }

    /// The component found what it waited for: writers need not wake it any more.
    #[inline]
    pub fn disarm(&self) {
        if self.sleeping.load(Ordering::Relaxed) {
            self.sleeping.store(false, Ordering::Relaxed);
        }
    }

    /// Unparks the component's thread, if it has one.
    pub fn wake(&self) {
        if let Some(thread) = self.thread.get() {
            thread.unpark();
        }
    }

    /// Asks the component to stop; blocked reads and writes return [`crate::ComponentError::Stopped`].
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Release);
        self.wake();
    }

    /// Whether a stop was requested.
    pub fn stop_requested(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    /// Pauses or resumes the component.
    pub fn set_paused(&self, paused: bool) {
        self.paused.store(paused, Ordering::Release);
        self.wake();
    }

    /// Whether the component is paused.
    pub fn is_paused(&self) -> bool {
        self.paused.load(Ordering::Acquire)
    }

    /// Marks that property changes or actions wait to be applied, and wakes the component.
    pub fn raise_control(&self) {
        self.control_pending.store(true, Ordering::Release);
        self.wake();
    }

    /// Clears the control mark; returns whether it was set.
    pub fn take_control(&self) -> bool {
        self.control_pending.swap(false, Ordering::AcqRel)
    }

    /// Whether a blocked call should return to the component's loop: stop, pause or control requested,
    /// or the component went quiet after work and its status is to be published.
    pub fn wants_attention(&self) -> bool {
        self.stop.load(Ordering::Acquire)
            || self.paused.load(Ordering::Acquire)
            || self.control_pending.load(Ordering::Acquire)
            || self.went_quiet.load(Ordering::Relaxed)
    }

    /// The component did some work: the next read that sleeps a whole status period returns to its loop
    /// once. Called by the component's own thread after each cycle; a load when already armed, so the
    /// line writers read `sleeping` from is not written at every cycle.
    #[inline]
    pub fn arm_quiet_break(&self) {
        if !self.quiet_break_armed.load(Ordering::Relaxed) {
            self.quiet_break_armed.store(true, Ordering::Relaxed);
        }
    }

    /// Whether a read went quiet since the last call (and clears it).
    #[inline]
    pub fn take_quiet(&self) -> bool {
        self.went_quiet.load(Ordering::Relaxed) && self.went_quiet.swap(false, Ordering::Relaxed)
    }

    /// Waits to be woken. Like [`std::thread::park`] it may return early, and callers re-check their
    /// condition in a loop: the first call after the thread was busy only arms the signal and returns, so
    /// that data written before the writer could see it armed is found by that re-check; the next call
    /// sleeps.
    ///
    /// A signal not yet bound to a thread binds the caller here: a thread parked under a signal no writer
    /// can unpark would sleep for ever.
    pub fn park(&self) {
        if !self.sleeping.load(Ordering::Relaxed) {
            self.thread.get_or_init(current_thread);
            // Release: a writer that sees the signal armed also sees the thread bound just above.
            self.sleeping.store(true, Ordering::Release);
            heavy_fence();
            return;
        }
        if self.quiet_break_armed.load(Ordering::Relaxed) {
            let asleep = std::time::Instant::now();
            park_timeout(STATUS_PERIOD);
            if asleep.elapsed() >= STATUS_PERIOD {
                // Only the component's own thread parks on its signal, so these need no ordering.
                self.quiet_break_armed.store(false, Ordering::Relaxed);
                self.went_quiet.store(true, Ordering::Relaxed);
            }
        } else {
            park();
        }
        self.sleeping.store(false, Ordering::Relaxed);
    }

    /// [`Self::park`] in a read waiting for input: while asleep, [`Self::awaits_input`] says so.
    pub fn park_for_input(&self) {
        let asleep = self.sleeping.load(Ordering::Relaxed);
        if asleep {
            // Only the component's own thread stores it; a stop's drain only looks.
            self.awaiting_input.store(true, Ordering::Relaxed);
        }
        self.park();
        if asleep {
            self.awaiting_input.store(false, Ordering::Relaxed);
        }
    }

    /// Whether the thread sleeps in a read waiting for input (as last seen: a hint, for a stop's drain).
    pub fn awaits_input(&self) -> bool {
        self.awaiting_input.load(Ordering::Relaxed)
    }

    /// Parks the calling thread until woken or `timeout` passes.
    pub fn park_timeout(&self, timeout: Duration) {
        park_timeout(timeout);
    }
}

//! Thread priority and CPU affinity, applied where the operating system allows.

use std::sync::atomic::{AtomicBool, Ordering};

use kairos_diagram::ThreadSettings;

static PRIORITY_WARNED: AtomicBool = AtomicBool::new(false);
static AFFINITY_WARNED: AtomicBool = AtomicBool::new(false);

/// Applies `settings` to the calling thread. A refusal by the OS is logged once per run and kind, not
/// per component: the diagram still runs, only without the requested scheduling.
pub fn apply_to_current_thread(component: &str, settings: &ThreadSettings) {
    if let Some(priority) = settings.priority
        && let Err(reason) = set_realtime_priority(priority)
        && !PRIORITY_WARNED.swap(true, Ordering::Relaxed)
    {
        tracing::warn!(
            "cannot set real-time priority {priority} for '{component}' ({reason}); components keep the normal \
             scheduler. Run with CAP_SYS_NICE or as root, or an rtprio limit in /etc/security/limits.conf"
        );
    }
    if !settings.affinity.is_empty()
        && let Err(reason) = set_affinity(&settings.affinity)
        && !AFFINITY_WARNED.swap(true, Ordering::Relaxed)
    {
        tracing::warn!(
            "cannot pin '{component}' to CPUs {:?} ({reason}); components run on any CPU",
            settings.affinity
        );
    }
}

/// Why the operating system did not give a thread the scheduling asked for.
#[derive(Debug, thiserror::Error)]
enum SchedulingRefused {
    /// A priority outside the real-time range (the text is the priority crate's).
    #[error("priority {priority}: {reason}")]
    PriorityOutOfRange { priority: u8, reason: String },
    /// Most often a missing `CAP_SYS_NICE` or rtprio limit.
    #[error("{0:?}")]
    Priority(thread_priority::Error),
    /// A CPU number beyond what the kernel's CPU set holds.
    #[error("CPU {cpu}: {source}")]
    Cpu { cpu: usize, source: nix::Error },
    /// The kernel refused the set (CPUs offline or outside the cgroup's).
    #[error("{0}")]
    Affinity(nix::Error),
    /// Not on this operating system.
    #[allow(dead_code, reason = "only built off Linux")]
    #[error("{0}")]
    Unsupported(&'static str),
}

#[cfg(unix)]
fn set_realtime_priority(priority: u8) -> Result<(), SchedulingRefused> {
    use thread_priority::unix::{
        RealtimeThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy, thread_native_id,
    };
    use thread_priority::{ThreadPriority, ThreadPriorityValue};
    let value = ThreadPriorityValue::try_from(priority.min(99))
        .map_err(|reason| SchedulingRefused::PriorityOutOfRange { priority, reason })?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(SchedulingRefused::Priority)
}

#[cfg(not(unix))]
fn set_realtime_priority(_priority: u8) -> Result<(), SchedulingRefused> {
    Err(SchedulingRefused::Unsupported(
        "real-time priorities are supported on Linux only",
    ))
}

#[cfg(target_os = "linux")]
fn set_affinity(cpus: &[usize]) -> Result<(), SchedulingRefused> {
    use nix::sched::{CpuSet, sched_setaffinity};
    use nix::unistd::Pid;
    let mut set = CpuSet::new();
    for &cpu in cpus {
        set.set(cpu)
            .map_err(|source| SchedulingRefused::Cpu { cpu, source })?;
    }
    // Pid 0 is the calling thread.
    sched_setaffinity(Pid::from_raw(0), &set).map_err(SchedulingRefused::Affinity)
}

#[cfg(not(target_os = "linux"))]
fn set_affinity(_cpus: &[usize]) -> Result<(), SchedulingRefused> {
    Err(SchedulingRefused::Unsupported(
        "CPU affinity is supported on Linux only",
    ))
}

/// CPU time consumed by the calling thread, in nanoseconds (0 where unsupported).
pub fn thread_cpu_nanos() -> u64 {
    #[cfg(target_os = "linux")]
    {
        use nix::time::{ClockId, clock_gettime};
        clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID).map_or(0, |t| {
            (t.tv_sec() as u64)
                .saturating_mul(1_000_000_000)
                .saturating_add(t.tv_nsec() as u64)
        })
    }
    #[cfg(not(target_os = "linux"))]
    {
        0
    }
}

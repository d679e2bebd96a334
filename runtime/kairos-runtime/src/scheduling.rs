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

#[cfg(unix)]
fn set_realtime_priority(priority: u8) -> Result<(), String> {
    use thread_priority::unix::{
        RealtimeThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy, thread_native_id,
    };
    use thread_priority::{ThreadPriority, ThreadPriorityValue};
    let value =
        ThreadPriorityValue::try_from(priority.min(99)).map_err(|e| format!("priority {priority}: {e}"))?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| format!("{e:?}"))
}

#[cfg(not(unix))]
fn set_realtime_priority(_priority: u8) -> Result<(), String> {
    Err("real-time priorities are supported on Linux only".to_owned())
}

#[cfg(target_os = "linux")]
fn set_affinity(cpus: &[usize]) -> Result<(), String> {
    use nix::sched::{CpuSet, sched_setaffinity};
    use nix::unistd::Pid;
    let mut set = CpuSet::new();
    for cpu in cpus {
        set.set(*cpu).map_err(|e| format!("CPU {cpu}: {e}"))?;
    }
    // Pid 0 is the calling thread.
    sched_setaffinity(Pid::from_raw(0), &set).map_err(|e| e.to_string())
}

#[cfg(not(target_os = "linux"))]
fn set_affinity(_cpus: &[usize]) -> Result<(), String> {
    Err("CPU affinity is supported on Linux only".to_owned())
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

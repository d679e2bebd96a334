//! Synchronised clocks between `kairos serve` instances (paper §2.3.1: a master and N slaves, "similar to
//! NTP"). A master answers on a UDP port of its own; a slave asks it every 250 ms (every 50 ms until it
//! has locked) with the four-timestamp exchange:
//!
//! t1 the slave sends, t2 the master receives, t3 the master answers, t4 the slave receives.
//! offset = ((t2 − t1) + (t3 − t4)) / 2, round-trip delay = (t4 − t1) − (t3 − t2).
//!
//! Both receptions are stamped by the kernel (`SO_TIMESTAMPNS`), so neither side's scheduling delays count.
//! Of the last 8 exchanges the one with the least delay gives the offset (a queued packet only ever
//! lengthens the delay, and an asymmetric one biases the offset by half of it). The slave's clock is a
//! [`DisciplinedClock`]: stepped at its first lock, slewed afterwards, never backwards.
//!
//! The master's reference is the machine's wall clock (`CLOCK_REALTIME`), which the real-time clock of its
//! diagrams follows.
//!
//! Where the machines' clocks are already kept by PTP or chrony, a runtime runs on its system clock
//! instead ([`SystemClock`], `--clock-system`) and only measures it against a master with the same
//! exchange, raising an alarm past a bound: Kairos never fights the daemon that owns the clock.

use std::collections::VecDeque;
use std::io::IoSliceMut;
use std::net::{SocketAddr, UdpSocket};
use std::os::fd::AsRawFd as _;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use kairos_sdk::{Clock, ClockState, ClockStatus, DisciplinedClock, RunSignal, Timestamp};
use nix::sys::socket::{ControlMessageOwned, MsgFlags, SockaddrStorage, recvmsg, setsockopt, sockopt};

/// The first bytes of every clock packet.
const MAGIC: &[u8; 4] = b"KCS1";
/// Exchanges whose least delay gives the offset.
const WINDOW: usize = 8;
/// An exchange slower than twice the best by more than this is left out of the rate estimate.
const RATE_DELAY_SLACK_NS: i64 = 20_000;
/// The name a slave's clock gives its source.
pub const MASTER_SOURCE: &str = "master";

/// The wall clock now, in ns since the UNIX epoch.
fn wall_now() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

/// Receives one packet into `buffer`: its length, sender and kernel reception time (wall clock, ns).
fn receive_stamped(socket: &UdpSocket, buffer: &mut [u8]) -> std::io::Result<(usize, SocketAddr, i64)> {
    let mut space = nix::cmsg_space!(nix::sys::time::TimeSpec);
    let mut slices = [IoSliceMut::new(buffer)];
    let message = recvmsg::<SockaddrStorage>(
        socket.as_raw_fd(),
        &mut slices,
        Some(&mut space),
        MsgFlags::empty(),
    )
    .map_err(std::io::Error::from)?;
    let mut stamped = None;
    for control in message.cmsgs().map_err(std::io::Error::from)? {
        if let ControlMessageOwned::ScmTimestampns(time) = control {
            stamped = Some(time.tv_sec() * 1_000_000_000 + time.tv_nsec());
        }
    }
    let from = message
        .address
        .and_then(|a| a.as_sockaddr_in().map(|v4| SocketAddr::V4((*v4).into())))
        .ok_or_else(|| std::io::Error::other("a clock packet from no IPv4 address"))?;
    // Without a kernel stamp (never seen on Linux), the time of reading is the next best.
    Ok((message.bytes, from, stamped.unwrap_or_else(wall_now)))
}

fn stamped_socket(bind: &str) -> std::io::Result<UdpSocket> {
    let socket = UdpSocket::bind(bind)?;
    setsockopt(&socket, sockopt::ReceiveTimestampns, &true).map_err(std::io::Error::from)?;
    Ok(socket)
}

fn read_i64(bytes: &[u8], at: usize) -> Option<i64> {
    bytes.get(at..at + 8)?.try_into().ok().map(i64::from_le_bytes)
}

/// Answers slaves on `bind` (`0.0.0.0:7401`) until the process ends.
pub fn run_master(bind: &str) -> std::io::Result<SocketAddr> {
    let socket = stamped_socket(bind)?;
    let address = socket.local_addr()?;
    std::thread::Builder::new()
        .name("k:clock".to_owned())
        .spawn(move || {
            let mut buffer = [0_u8; 64];
            loop {
                let Ok((read, from, received)) = receive_stamped(&socket, &mut buffer) else {
                    continue;
                };
                let (Some(b"KCS1"), Some(t1)) = (buffer.get(..4), read_i64(&buffer[..read], 4)) else {
                    continue;
                };
                let mut answer = Vec::with_capacity(28);
                answer.extend_from_slice(MAGIC);
                answer.extend_from_slice(&t1.to_le_bytes());
                answer.extend_from_slice(&received.to_le_bytes());
                answer.extend_from_slice(&wall_now().to_le_bytes());
                let _ = socket.send_to(&answer, from);
            }
        })?;
    Ok(address)
}

/// One exchange's result.
#[derive(Debug, Clone, Copy)]
struct Exchange {
    /// The master's time minus the slave's *uncorrected* (monotonic) time: unlike the offset against the
    /// slave's clock, it stays true while the clock is corrected, so an older exchange can still be used.
    base: i64,
    delay: i64,
    /// The uncorrected time it was made at: with a drifting machine, `base` moves on at the clock's rate.
    at: i64,
}

/// Sends the master one exchange stamped `t1` and waits for its answer: the master's `t2` and `t3`, and
/// the kernel's wall-clock stamp of the answer's arrival. `None` (warned about, at most once a second)
/// when it does not answer within the socket's timeout or answers something else.
fn ask_master(
    socket: &UdpSocket,
    master: SocketAddr,
    t1: i64,
    warned: &mut kairos_sdk::Throttle,
) -> Option<(i64, i64, i64)> {
    let mut ask = MAGIC.to_vec();
    ask.extend_from_slice(&t1.to_le_bytes());
    if let Err(e) = socket.send_to(&ask, master) {
        warned.warn(|| format!("clock master {master}: {e}"));
    }
    let mut buffer = [0_u8; 64];
    match receive_stamped(socket, &mut buffer) {
        Ok((read, _, received_wall)) => {
            let packet = &buffer[..read];
            let fields = (read_i64(packet, 4), read_i64(packet, 12), read_i64(packet, 20));
            match fields {
                (Some(echoed), Some(t2), Some(t3)) if packet.starts_with(MAGIC) && echoed == t1 => {
                    Some((t2, t3, received_wall))
                }
                _ => None,
            }
        }
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ) =>
        {
            warned.warn(|| format!("clock master {master} does not answer; the clock runs on, in holdover"));
            None
        }
        Err(e) => {
            warned.warn(|| format!("clock master {master}: {e}"));
            None
        }
    }
}

fn exchange_socket(master: SocketAddr) -> std::io::Result<UdpSocket> {
    let socket = stamped_socket(if master.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" })?;
    socket.set_read_timeout(Some(Duration::from_millis(200)))?;
    Ok(socket)
}

/// Follows the master at `master` (`HOST:PORT`) with `clock`, until the process ends.
pub fn run_slave(master: SocketAddr, clock: Arc<DisciplinedClock>) -> std::io::Result<()> {
    let socket = exchange_socket(master)?;
    std::thread::Builder::new()
        .name("k:clock".to_owned())
        .spawn(move || {
            let mut recent: VecDeque<Exchange> = VecDeque::with_capacity(WINDOW);
            let mut warned = kairos_sdk::Throttle::default();
            loop {
                let t1 = clock.now().as_nanos();
                if let Some((t2, t3, received_wall)) = ask_master(&socket, master, t1, &mut warned) {
                    // The kernel's stamp is wall-clock time; on this clock it was as long ago as on that one.
                    let now = clock.now().as_nanos();
                    let t4 = now - (wall_now() - received_wall);
                    // The clock is its uncorrected (monotonic) time plus its offset.
                    let uncorrected = clock.monotonic_ns();
                    let exchange = Exchange {
                        base: i64::midpoint(t2 - t1, t3 - t4) + (now - uncorrected),
                        delay: (t4 - t1) - (t3 - t2),
                        at: uncorrected,
                    };
                    recent.push_back(exchange);
                    while recent.len() > WINDOW {
                        recent.pop_front();
                    }
                    // Every exchange not much slower than the best feeds the rate estimate.
                    let least = recent.iter().map(|e| e.delay).min().unwrap_or(exchange.delay);
                    if exchange.delay <= least.saturating_mul(2).saturating_add(RATE_DELAY_SLACK_NS) {
                        clock.observe(
                            MASTER_SOURCE,
                            Timestamp(now),
                            Timestamp(uncorrected + exchange.base),
                        );
                    }
                    if let Some(best) = recent.iter().min_by_key(|e| e.delay) {
                        // The least-delayed exchange may be a few old: carried to now at the rate.
                        #[allow(clippy::cast_possible_truncation, clippy::cast_precision_loss, reason = "ns")]
                        let drifted = ((uncorrected - best.at) as f64 * clock.rate()) as i64;
                        let master_now = uncorrected + best.base + drifted;
                        clock.take_reference(MASTER_SOURCE, Timestamp(now), Timestamp(master_now));
                        // The offset is exact on a symmetric path; an asymmetric one biases it by at most
                        // half the round trip.
                        clock.set_error_bound(best.delay / 2);
                    }
                }
                let locked = clock.clock_status().references >= WINDOW as u64;
                std::thread::sleep(Duration::from_millis(if locked { 250 } else { 50 }));
            }
        })?;
    Ok(())
}

/// The source name a system clock gives in its status.
pub const SYSTEM_SOURCE: &str = "system";

/// The machine's own clock (`CLOCK_REALTIME`), kept by PTP or chrony, which a runtime runs on without
/// correcting it; measured against a master when one is named, its state is `alarm` while it is further
/// from the master than the bound. Read so that it never goes back within a run (a step back of the system
/// clock holds it still until it catches up).
#[derive(Debug)]
pub struct SystemClock {
    latest: AtomicI64,
    measured: Mutex<Measured>,
    alarm_ns: i64,
}

/// The last measurement against the master.
#[derive(Debug, Default)]
struct Measured {
    /// The master's time minus the system clock's, ns, from the least-delayed recent exchange.
    offset_ns: i64,
    /// Half that exchange's round trip, ns.
    bound_ns: i64,
    references: u64,
    last: Option<Instant>,
    /// Whether the alarm was raised (so it is logged once per crossing).
    alarmed: bool,
}

impl SystemClock {
    /// The system clock, alarming past `alarm` from the master it is measured against.
    pub fn new(alarm: Duration) -> Self {
        SystemClock {
            latest: AtomicI64::new(0),
            measured: Mutex::new(Measured::default()),
            alarm_ns: i64::try_from(alarm.as_nanos()).unwrap_or(i64::MAX),
        }
    }

    fn record(&self, offset_ns: i64, bound_ns: i64) {
        let mut measured = self.measured.lock().unwrap_or_else(PoisonError::into_inner);
        measured.offset_ns = offset_ns;
        measured.bound_ns = bound_ns;
        measured.references += 1;
        measured.last = Some(Instant::now());
        let beyond = offset_ns.abs() > self.alarm_ns;
        if beyond && !measured.alarmed {
            tracing::error!(
                "the system clock is {:+.3} ms from the clock master, beyond the {:.3} ms alarm bound: check the \
                 PTP or chrony daemon that keeps it",
                offset_ns as f64 * 1e-6,
                self.alarm_ns as f64 * 1e-6
            );
        } else if !beyond && measured.alarmed {
            tracing::info!(
                "the system clock is back within {:.3} ms of the clock master ({:+.1} µs)",
                self.alarm_ns as f64 * 1e-6,
                offset_ns as f64 * 1e-3
            );
        }
        measured.alarmed = beyond;
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Timestamp {
        let wall = wall_now();
        let before = self.latest.fetch_max(wall, Ordering::AcqRel);
        Timestamp(wall.max(before))
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        kairos_sdk::wait_in_real_time(self, deadline, signal)
    }

    fn describe(&self) -> String {
        "the system clock, kept by PTP or chrony and only measured by Kairos".to_owned()
    }

    fn status(&self) -> Option<ClockStatus> {
        let measured = self.measured.lock().unwrap_or_else(PoisonError::into_inner);
        let since_reference_s = measured.last.map(|at| at.elapsed().as_secs_f64());
        let state = ClockState::of_silence(since_reference_s).unwrap_or(if measured.alarmed {
            ClockState::Alarm
        } else {
            ClockState::Locked
        });
        Some(ClockStatus {
            source: SYSTEM_SOURCE.to_owned(),
            state,
            error_ns: measured.offset_ns,
            offset_ns: 0,
            step_ns: 0,
            references: measured.references,
            since_reference_s,
            error_bound_ns: (measured.references > 0).then_some(measured.bound_ns),
            rate_ppm: None,
        })
    }
}

/// Measures `clock` against the master at `master` every second, until the process ends.
pub fn run_system_check(master: SocketAddr, clock: Arc<SystemClock>) -> std::io::Result<()> {
    let socket = exchange_socket(master)?;
    std::thread::Builder::new()
        .name("k:clock".to_owned())
        .spawn(move || {
            let mut recent: VecDeque<(i64, i64)> = VecDeque::with_capacity(WINDOW);
            let mut warned = kairos_sdk::Throttle::default();
            loop {
                let t1 = wall_now();
                if let Some((t2, t3, t4)) = ask_master(&socket, master, t1, &mut warned) {
                    recent.push_back((i64::midpoint(t2 - t1, t3 - t4), (t4 - t1) - (t3 - t2)));
                    while recent.len() > WINDOW {
                        recent.pop_front();
                    }
                    if let Some((offset, delay)) = recent.iter().min_by_key(|(_, delay)| *delay) {
                        clock.record(*offset, delay / 2);
                    }
                }
                std::thread::sleep(Duration::from_millis(if recent.len() < WINDOW {
                    50
                } else {
                    1000
                }));
            }
        })?;
    Ok(())
}

/// What a forced start (hosts' clocks not locked, `kairos deploy --start-unlocked`) leaves in the
/// description of the clock, which recorders write into every file: shared by every clock a runtime
/// hands its engines, set at each start.
pub type StartNote = Arc<Mutex<Option<String>>>;

/// A runtime's clock, described with the [`StartNote`] of the run.
#[derive(Debug)]
pub struct NotedClock {
    inner: Arc<dyn Clock>,
    note: StartNote,
}

impl NotedClock {
    /// `inner`, described with `note`.
    pub fn new(inner: Arc<dyn Clock>, note: StartNote) -> Self {
        NotedClock { inner, note }
    }
}

impl Clock for NotedClock {
    fn now(&self) -> Timestamp {
        self.inner.now()
    }

    fn wait_until(&self, deadline: Timestamp, signal: &RunSignal) -> bool {
        self.inner.wait_until(deadline, signal)
    }

    fn describe(&self) -> String {
        let note = self.note.lock().unwrap_or_else(PoisonError::into_inner).clone();
        match note {
            Some(note) => format!(
                "{}; STARTED WITH CLOCKS NOT LOCKED: {note}",
                self.inner.describe()
            ),
            None => self.inner.describe(),
        }
    }

    fn take_reference(&self, source: &str, measured_at: Timestamp, reference: Timestamp) -> bool {
        self.inner.take_reference(source, measured_at, reference)
    }

    fn forbid_steps(&self) {
        self.inner.forbid_steps();
    }

    fn status(&self) -> Option<ClockStatus> {
        self.inner.status()
    }
}

//! Synchronised clocks between `kairos serve` instances (paper §2.3.1: a master and N slaves, "similar to
//! NTP"). A master answers on a UDP port of its own; a slave asks it every 250 ms (every 50 ms until it
//! has locked) with the four-timestamp exchange:
//!
//! t1 the slave sends, t2 the master receives, t3 the master answers, t4 the slave receives.
//! offset = ((t2 − t1) + (t3 − t4)) / 2, round-trip delay = (t4 − t1) − (t3 − t2).
//!
//! Both receptions are stamped by the kernel (`SO_TIMESTAMPNS`), and so are both departures where the kernel
//! offers software transmit stamps (`SO_TIMESTAMPING`, read back from the socket's error queue): the
//! slave's t1 is then the moment its request left, and the master, which learns t3 only after its answer
//! has left, sends it in a follow-up packet (PTP's two-step). Neither side's scheduling or system calls
//! then count; without transmit stamps the times read just before sending stand in.
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

use kairos_sdk_core::{Clock, ClockState, ClockStatus, DisciplinedClock, RunSignal, Timestamp};
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

/// The first bytes of the master's follow-up, which carries the kernel's stamp of its answer's departure.
const FOLLOW_UP_MAGIC: &[u8; 4] = b"KCF1";
/// How long a slave waits for a follow-up its master announced.
const FOLLOW_UP_WAIT: Duration = Duration::from_millis(20);
/// Bytes for the control messages of one received packet: every form of stamp the kernel may attach, and
/// the error record a transmit stamp comes in (a truncated set is refused whole).
const CONTROL_SPACE: usize = 256;
/// How long after a send its kernel transmit stamp may take to appear in the error queue.
const DEPARTURE_WAIT: Duration = Duration::from_millis(1);

fn nanos_of(time: &nix::sys::time::TimeSpec) -> i64 {
    time.tv_sec() * 1_000_000_000 + time.tv_nsec()
}

/// Receives one packet into `buffer`: its length, sender and kernel reception time (wall clock, ns).
fn receive_stamped(socket: &UdpSocket, buffer: &mut [u8]) -> std::io::Result<(usize, SocketAddr, i64)> {
    // Room for both forms of the stamp: with transmit stamps on, the kernel may report receptions in
    // `SO_TIMESTAMPING`'s form as well.
    let mut space = vec![0_u8; CONTROL_SPACE];
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
        match control {
            ControlMessageOwned::ScmTimestampns(time) => stamped = Some(nanos_of(&time)),
            ControlMessageOwned::ScmTimestampsns(times) if stamped.is_none() && times.system.tv_sec() > 0 => {
                stamped = Some(nanos_of(&times.system));
            }
            _ => {}
        }
    }
    let from = message
        .address
        .and_then(|a| a.as_sockaddr_in().map(|v4| SocketAddr::V4((*v4).into())))
        .ok_or_else(|| std::io::Error::other("a clock packet from no IPv4 address"))?;
    // Without a kernel stamp (never seen on Linux), the time of reading is the next best.
    Ok((message.bytes, from, stamped.unwrap_or_else(wall_now)))
}

/// A UDP socket whose receptions, and where the kernel can, departures, are stamped; whether departures
/// are.
fn stamped_socket(bind: &str) -> std::io::Result<(UdpSocket, bool)> {
    use nix::sys::socket::TimestampingFlag as Flag;
    let socket = UdpSocket::bind(bind)?;
    setsockopt(&socket, sockopt::ReceiveTimestampns, &true).map_err(std::io::Error::from)?;
    // Transmit stamps only refine the exchange: a kernel without them leaves the times read before sending.
    let departures = Flag::SOF_TIMESTAMPING_SOFTWARE
        | Flag::SOF_TIMESTAMPING_TX_SOFTWARE
        | Flag::SOF_TIMESTAMPING_OPT_TSONLY;
    let stamped = setsockopt(&socket, sockopt::Timestamping, &departures).is_ok();
    Ok((socket, stamped))
}

/// The next transmit stamp in `socket`'s error queue (wall clock, ns): `Err` when the queue is empty,
/// `Ok(None)` for an entry that holds none.
fn next_departure(socket: &UdpSocket) -> Result<Option<i64>, ()> {
    // The stamp, the error record that carries it, and the reception-style stamp of the same packet.
    let mut space = vec![0_u8; CONTROL_SPACE];
    let mut buffer = [0_u8; 64];
    let mut slices = [IoSliceMut::new(&mut buffer)];
    let message = recvmsg::<SockaddrStorage>(
        socket.as_raw_fd(),
        &mut slices,
        Some(&mut space),
        MsgFlags::MSG_ERRQUEUE | MsgFlags::MSG_DONTWAIT,
    )
    .map_err(|_| ())?;
    let mut cmsgs = message.cmsgs().map_err(|_| ())?;
    let stamp = cmsgs.find_map(|control| match control {
        ControlMessageOwned::ScmTimestampsns(times) if times.system.tv_sec() > 0 => {
            Some(nanos_of(&times.system))
        }
        _ => None,
    });
    Ok(stamp)
}

/// Forgets the transmit stamps of earlier sends, so the next one read is the next send's.
fn forget_departures(socket: &UdpSocket) {
    while next_departure(socket).is_ok() {}
}

/// The kernel's stamp of the departure of the packet just sent, which `sent_after` (read before sending)
/// precedes; `None` when there is none within [`DEPARTURE_WAIT`].
fn departure_of_last_send(socket: &UdpSocket, sent_after: i64) -> Option<i64> {
    let deadline = Instant::now() + DEPARTURE_WAIT;
    loop {
        match next_departure(socket) {
            // An earlier send's stamp, left over: passed by.
            Ok(Some(stamp)) if stamp < sent_after => {}
            Ok(Some(stamp)) => return (stamp - sent_after < 1_000_000_000).then_some(stamp),
            Ok(None) => {}
            Err(()) if Instant::now() < deadline => std::thread::sleep(Duration::from_micros(20)),
            Err(()) => return None,
        }
    }
}

fn read_i64(bytes: &[u8], at: usize) -> Option<i64> {
    bytes.get(at..at + 8)?.try_into().ok().map(i64::from_le_bytes)
}

/// Answers slaves on `bind` (`0.0.0.0:7401`) until the process ends.
pub fn run_master(bind: &str) -> std::io::Result<SocketAddr> {
    let (socket, departures_stamped) = stamped_socket(bind)?;
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
                if departures_stamped {
                    forget_departures(&socket);
                }
                let t3 = wall_now();
                let mut answer = Vec::with_capacity(29);
                answer.extend_from_slice(MAGIC);
                answer.extend_from_slice(&t1.to_le_bytes());
                answer.extend_from_slice(&received.to_le_bytes());
                answer.extend_from_slice(&t3.to_le_bytes());
                // Announces a follow-up with the answer's kernel departure stamp.
                answer.push(u8::from(departures_stamped));
                if socket.send_to(&answer, from).is_err() || !departures_stamped {
                    continue;
                }
                if let Some(departed) = departure_of_last_send(&socket, t3) {
                    let mut follow_up = Vec::with_capacity(20);
                    follow_up.extend_from_slice(FOLLOW_UP_MAGIC);
                    follow_up.extend_from_slice(&t1.to_le_bytes());
                    follow_up.extend_from_slice(&departed.to_le_bytes());
                    let _ = socket.send_to(&follow_up, from);
                }
            }
        })?;
    Ok(address)
}

/// One exchange as the slave saw it, every time on the wall clock (ns): t1 its request left, t2 the
/// master received it, t3 the master's answer left, t4 the answer arrived.
#[derive(Debug, Clone, Copy)]
struct Stamps {
    t1: i64,
    t2: i64,
    t3: i64,
    t4: i64,
    /// Whether the kernel stamped both departures (else a time read before sending stands in).
    kernel_departures: bool,
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

/// One exchange with the master: its four times, or `None` (warned about, at most once a second) when it
/// does not answer within the socket's timeout or answers something else.
fn ask_master(
    socket: &UdpSocket,
    departures_stamped: bool,
    master: SocketAddr,
    warned: &mut kairos_sdk_core::Throttle,
) -> Option<Stamps> {
    if departures_stamped {
        forget_departures(socket);
    }
    // Also what the answer echoes, to tell it from a late answer to an earlier request.
    let asked = wall_now();
    let mut ask = MAGIC.to_vec();
    ask.extend_from_slice(&asked.to_le_bytes());
    if let Err(e) = socket.send_to(&ask, master) {
        warned.warn(|| format!("clock master {master}: {e}"));
        return None;
    }
    let departed = departures_stamped
        .then(|| departure_of_last_send(socket, asked))
        .flatten();
    let answer = match receive_reply(socket, *MAGIC, asked, None) {
        Ok(answer) => answer,
        Err(e) => {
            warned.warn(|| {
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) {
                    format!("clock master {master} does not answer; the clock runs on, in holdover")
                } else {
                    format!("clock master {master}: {e}")
                }
            });
            return None;
        }
    };
    let (packet, t4) = answer;
    let (Some(t2), Some(said_t3)) = (read_i64(&packet, 12), read_i64(&packet, 20)) else {
        return None;
    };
    let follow_up_coming = packet.get(28) == Some(&1);
    // Two-step: the kernel's stamp of the answer's departure, when the master sends it.
    let answer_departed = follow_up_coming
        .then(|| receive_reply(socket, *FOLLOW_UP_MAGIC, asked, Some(FOLLOW_UP_WAIT)).ok())
        .flatten()
        .and_then(|(follow_up, _)| read_i64(&follow_up, 12));
    Some(Stamps {
        t1: departed.unwrap_or(asked),
        t2,
        t3: answer_departed.unwrap_or(said_t3),
        t4,
        kernel_departures: departed.is_some() && answer_departed.is_some(),
    })
}

/// The next packet starting with `magic` and echoing `asked` (others, late or foreign, are passed by),
/// with its kernel arrival stamp; waits at most the socket's timeout, or `within` when given.
fn receive_reply(
    socket: &UdpSocket,
    magic: [u8; 4],
    asked: i64,
    within: Option<Duration>,
) -> std::io::Result<(Vec<u8>, i64)> {
    let timeout = socket.read_timeout()?;
    if within.is_some() {
        socket.set_read_timeout(within)?;
    }
    let deadline = Instant::now() + within.or(timeout).unwrap_or(Duration::from_secs(1));
    let mut buffer = [0_u8; 64];
    let result = loop {
        match receive_stamped(socket, &mut buffer) {
            Ok((read, _, arrived)) => {
                let packet = &buffer[..read];
                if packet.starts_with(&magic) && read_i64(packet, 4) == Some(asked) {
                    break Ok((packet.to_vec(), arrived));
                }
                if Instant::now() >= deadline {
                    break Err(std::io::ErrorKind::TimedOut.into());
                }
            }
            Err(e) => break Err(e),
        }
    };
    if within.is_some() {
        socket.set_read_timeout(timeout)?;
    }
    result
}

fn exchange_socket(master: SocketAddr) -> std::io::Result<(UdpSocket, bool)> {
    let (socket, departures_stamped) = stamped_socket(if master.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" })?;
    socket.set_read_timeout(Some(Duration::from_millis(200)))?;
    Ok((socket, departures_stamped))
}

/// Says once, and again whenever it changes, whether the exchanges' departures are stamped by the kernel.
#[derive(Debug, Default)]
struct HowStamped(Option<bool>);

impl HowStamped {
    fn say(&mut self, kernel_departures: bool, master: SocketAddr) {
        if self.0 == Some(kernel_departures) {
            return;
        }
        if kernel_departures {
            tracing::info!("clock exchanges with {master}: both departures stamped by the kernel");
        } else {
            tracing::warn!(
                "clock exchanges with {master}: departures read before sending, not stamped by the kernel (the \
                 master runs an older kairos, or a kernel without software transmit stamps): expect the offset \
                 to be a few microseconds off"
            );
        }
        self.0 = Some(kernel_departures);
    }
}

/// The slave clock's reading minus the wall clock's, now: what turns the exchange's wall-clock stamps
/// into times on the slave's clock.
fn clock_minus_wall(clock: &DisciplinedClock) -> i64 {
    let before = wall_now();
    let now = clock.now().as_nanos();
    let after = wall_now();
    now - i64::midpoint(before, after)
}

/// Follows the master at `master` (`HOST:PORT`) with `clock`, until the process ends.
pub fn run_slave(master: SocketAddr, clock: Arc<DisciplinedClock>) -> std::io::Result<()> {
    let (socket, departures_stamped) = exchange_socket(master)?;
    std::thread::Builder::new()
        .name("k:clock".to_owned())
        .spawn(move || {
            let mut recent: VecDeque<Exchange> = VecDeque::with_capacity(WINDOW);
            let mut warned = kairos_sdk_core::Throttle::default();
            let mut said_how_stamped = HowStamped::default();
            loop {
                if let Some(stamps) = ask_master(&socket, departures_stamped, master, &mut warned) {
                    said_how_stamped.say(stamps.kernel_departures, master);
                    // The kernel's stamps are wall-clock times: on this clock they were as long ago as on
                    // that one.
                    let shift = clock_minus_wall(&clock);
                    let (t1, t2, t3, t4) = (stamps.t1 + shift, stamps.t2, stamps.t3, stamps.t4 + shift);
                    let now = clock.now().as_nanos();
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
        kairos_sdk_core::wait_in_real_time(self, deadline, signal)
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
    let (socket, departures_stamped) = exchange_socket(master)?;
    std::thread::Builder::new()
        .name("k:clock".to_owned())
        .spawn(move || {
            let mut recent: VecDeque<(i64, i64)> = VecDeque::with_capacity(WINDOW);
            let mut warned = kairos_sdk_core::Throttle::default();
            let mut said_how_stamped = HowStamped::default();
            loop {
                if let Some(Stamps {
                    t1,
                    t2,
                    t3,
                    t4,
                    kernel_departures,
                }) = ask_master(&socket, departures_stamped, master, &mut warned)
                {
                    said_how_stamped.say(kernel_departures, master);
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
    /// This runtime is the rig's clock master: a clock that follows nothing else says so.
    master: bool,
}

impl NotedClock {
    /// `inner`, described with `note`.
    pub fn new(inner: Arc<dyn Clock>, note: StartNote) -> Self {
        NotedClock {
            inner,
            note,
            master: false,
        }
    }

    /// The same clock on the rig's clock master: where it follows no source of its own (a GNSS
    /// receiver), its status says it is the reference, so recordings made on it merge with those of
    /// the hosts locked to it.
    #[must_use]
    pub fn of_the_master(mut self) -> Self {
        self.master = true;
        self
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

    fn jumps(&self) -> bool {
        self.inner.jumps()
    }

    fn hold(&self, held: bool) {
        self.inner.hold(held);
    }

    fn status(&self) -> Option<ClockStatus> {
        self.inner.status().or_else(|| {
            self.master.then(|| ClockStatus {
                source: "this machine (the clock master)".to_owned(),
                state: ClockState::Master,
                error_ns: 0,
                offset_ns: 0,
                step_ns: 0,
                references: 0,
                since_reference_s: None,
                error_bound_ns: Some(0),
                rate_ppm: None,
            })
        })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "a failed unwrap is a failed test")]

    use super::{ask_master, exchange_socket, run_master};

    #[test]
    fn an_exchange_takes_both_departures_from_the_kernel() {
        let master = run_master("127.0.0.1:0").unwrap();
        let (socket, departures_stamped) = exchange_socket(master).unwrap();
        assert!(departures_stamped, "Linux stamps departures on loopback");
        let mut warned = kairos_sdk_core::Throttle::default();
        let stamps = ask_master(&socket, true, master, &mut warned).unwrap();
        eprintln!("{stamps:?}");
        assert!(stamps.kernel_departures, "{stamps:?}");
        assert!(
            stamps.t1 < stamps.t2 && stamps.t2 <= stamps.t3 && stamps.t3 < stamps.t4,
            "{stamps:?}"
        );
    }
}

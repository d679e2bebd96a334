//! Links between the hosts of one diagram, over Zenoh.
//!
//! `kairos deploy` turns each connection between two hosts into a pair of components: a `link.sender` on
//! the producer's host, reading the output like any consumer, and a `link.receiver` on the consumer's,
//! writing into a local output the consumer reads with its own policy, so the five reader policies stay
//! local and exact. Every sample travels whole, with both its times, in the binary sample frame,
//! numbered by the sender so the receiver counts what was lost in transit. A consumer that never
//! skips makes its link reliable and blocking (the one case where a consumer may slow its producer); any
//! other drops rather than blocks.
//!
//! A reliable link also rides out a cut: its sender keeps what it put for the last `ride_out_s` seconds
//! (at most `ride_out_mb` of frames) and, when the receiver matches again, asks it for the newest
//! sequence number it received and puts again everything after it, in order. A cut shorter than that
//! loses nothing; beyond it, what was no longer kept shows as a gap the receiver counts. A receiver that
//! started afresh (its host restarted) received nothing yet: it gets what was put since the cut was
//! noticed, never what its former self may have had (at most once: what died with that host was lost).
//!
//! Zenoh saying the receiver matches is not taken as proof that it receives: a reliable sender's
//! heartbeat ([`heartbeat`]) asks the same question every second and says a receiver that stops
//! answering, or receiving.

use std::collections::VecDeque;

mod heartbeat;
pub mod network;

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use kairos_pack_net::encoding::{SAMPLES, SampleReceiver};
use kairos_sample_frame as sample_frame;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, Payload,
    ReaderPolicy, Registry, STATUS_PERIOD, Throttle, TypeFilter, Value, WARNING_PERIOD,
};
use zenoh::Wait as _;
use zenoh::bytes::ZBytes;

/// The sending end's type name.
pub const SENDER: &str = "link.sender";
/// The receiving end's type name.
pub const RECEIVER: &str = "link.receiver";

/// The receiver's output.
pub const SAMPLES_OUTPUT: &str = SAMPLES;

/// The most samples one `core` call of a receiver takes, so stop and control requests get through a flood.
const BURST: usize = 64;

/// How long the receiver is given to say what it received after a cut, and what is allowed beyond it
/// before the samples held meanwhile go anyway.
const ASK_WAIT: Duration = Duration::from_millis(500);
const ASK_SLACK: Duration = Duration::from_millis(200);

/// How long one wait for a sample lasts, so stop and control requests get through.
const RECEIVE_WAIT: Duration = Duration::from_millis(50);

/// Registers the pack "link".
pub fn register(registry: &mut Registry) {
    registry
        .pack("link", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<LinkSender>(sender_descriptor())
        .component_described::<LinkReceiver>(receiver_descriptor(), describe_receiver);
}

fn common(descriptor: Descriptor) -> Descriptor {
    descriptor
        .property(Property::text("key", "").doc("The Zenoh key the samples travel under"))
        .property(
            Property::bool("reliable", false)
                .doc("Reliable and blocking (the consumer never skips); otherwise samples are dropped rather than wait"),
        )
        .property(Property::text("peer", "").doc("The far end, in words, for messages"))
}

/// The descriptor of `link.sender`.
pub fn sender_descriptor() -> ComponentInfo {
    common(Descriptor::new(
        SENDER,
        "across hosts",
        "Sends each sample it reads to another host over Zenoh, whole, with both its times and a sequence \
         number. Placed by `kairos deploy` on a connection between two hosts",
    ))
    .label("Link to another host")
    .input_with_policy("in", TypeFilter::Any, ReaderPolicy::Fifo, "What to send")
    // The receiving end stops at the same agreed instant: what it sent after would be lost.
    .stops_at_once()
    .property(
        Property::f64("ride_out_s", 5.0)
            .range(0.0, 600.0)
            .doc("A reliable link keeps what it sent this long and sends it again after a cut: a cut shorter than this loses nothing"),
    )
    .property(
        Property::f64("ride_out_mb", 256.0)
            .range(0.0, 65_536.0)
            .doc("The most memory what a reliable link keeps for a cut may take (the oldest goes first)"),
    )
    .property(Property::bool("bulk", false).doc(
        "Large samples (images, point clouds): sent at a lower priority than the other links between the two hosts, whose puts then never wait behind a full queue of frames",
    ))
    .build()
}

/// The descriptor of `link.receiver` as listed.
pub fn receiver_descriptor() -> ComponentInfo {
    receiver_base(DataType::F64)
}

/// The descriptor of one `link.receiver`: an output of its `data_type`, whose samples go by the name of
/// the output they come from (`origin`), as in the diagram.
pub fn describe_receiver(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    let text = |name| properties.get(name).and_then(Value::as_text);
    let mut info = receiver_base(DataType::from_name(text("data_type").unwrap_or("f64")));
    if let (Some(origin), Some(output)) = (text("origin").filter(|o| !o.is_empty()), info.outputs.first_mut())
    {
        output.known_as = Some(origin.to_owned());
    }
    Ok(info)
}

fn receiver_base(data_type: DataType) -> ComponentInfo {
    common(Descriptor::new(
        RECEIVER,
        "across hosts",
        "Receives the samples another host's link sends and writes them with both their times, counting \
         those lost in transit. Placed by `kairos deploy` on a connection between two hosts",
    ))
    .label("Link from another host")
    .output(SAMPLES, data_type, "Each sample received, with both its times")
    .property(Property::text("data_type", "f64").doc("The type of the samples the sender sends"))
    .property(
        Property::text("origin", "")
            .doc("The output the samples come from (`camera.image`), which they are known by on this host"),
    )
    .property(
        Property::i64("queue", 64)
            .int_range(1, 65_536)
            .doc("Samples held between the network and this component"),
    )
    .build()
}

/// Whether `type_name` is one end of a link between hosts.
pub fn is_link(type_name: &str) -> bool {
    type_name == SENDER || type_name == RECEIVER
}

/// The end `found` under `key`, or why there is none.
fn declared<T>(found: Option<T>, key: &str) -> Result<T, ComponentError> {
    found.ok_or_else(|| {
        ComponentError::failed(format_args!(
            "no link is declared under {key}: links are placed and declared by `kairos deploy`"
        ))
    })
}

/// `sample` as one frame for Zenoh: the start copied, the payload's bytes shared where the payload holds
/// them (pixels, bytes), so a camera's frames travel without a copy on the sending side. (Public for the
/// benchmark, whose baseline puts the same bytes.)
pub fn frame_of(output: &str, sample: &kairos_sdk::Sample) -> ZBytes {
    let (head, body) = sample_frame::encode(output, sample);
    if body.len() > SHARE_FROM {
        let shared = match &sample.payload {
            Payload::Image(image) => Some(bytes::Bytes::from_owner(image.pixels.clone())),
            Payload::Bytes(data) => Some(bytes::Bytes::from_owner(data.clone())),
            Payload::Custom(custom) => Some(bytes::Bytes::from_owner(custom.data.clone())),
            _ => None,
        };
        if let Some(shared) = shared {
            let mut writer = ZBytes::writer();
            writer.append(ZBytes::from(head));
            writer.append(ZBytes::from(shared));
            return ZBytes::from(writer);
        }
    }
    let mut whole = head;
    whole.extend_from_slice(&body);
    ZBytes::from(whole)
}

/// Payloads larger than this are shared with Zenoh rather than copied into the frame: below it a copy
/// costs less than a second slice.
const SHARE_FROM: usize = 4096;

/// `link.sender`. See [`sender_descriptor`].
#[derive(Debug, Default)]
pub struct LinkSender {
    end: Option<std::sync::Arc<network::SenderEnd>>,
    /// The name the samples travel under: the output feeding this link.
    output: String,
    /// Samples put on the link, and of those, put while no receiver matched (lost with the far end).
    sent: u64,
    unmatched: u64,
    failed: u64,
    /// Whether a receiver matched at the last look (every status period, and whenever Zenoh says the
    /// match changed).
    matched: bool,
    /// The end's count of match changes at the last look.
    seen_matching_changes: u64,
    warned: Throttle,
    /// When the receiver's match was last looked at.
    looked: Throttle,
    /// What a reliable link keeps for a cut.
    kept: Kept,
    /// The receiver's cuts seen so far, and whether one awaits the receiver's return.
    seen_cuts: u64,
    cut: bool,
    /// The first sequence number put after the cut was noticed: a receiver that comes back afresh gets
    /// what was kept from it on.
    noticed_from: u64,
    /// After a cut, the receiver asked what it received: samples are held (kept, not put) until it says,
    /// from `held_from` on, since `held_since` (`None` outside a hold; a receiver that flaps before it
    /// answers is asked again within the same hold, up to the ride-out).
    asking: Option<(network::Answer, Instant)>,
    held_from: u64,
    held_since: Option<Instant>,
    /// Samples put again after cuts.
    put_again: u64,
    /// A reliable link asks its matched receiver what it received, every heartbeat period.
    reliable: bool,
    heartbeat: heartbeat::Heartbeat,
    /// The heartbeat's question out, with what had been sent when it went and when it went.
    beating: Option<(network::Answer, u64, Instant)>,
}

/// The frames a reliable link put lately, the oldest first, within a time and a memory bound.
#[derive(Debug, Default)]
struct Kept {
    frames: VecDeque<(u64, ZBytes, Instant)>,
    bytes: usize,
    for_how_long: Duration,
    most_bytes: usize,
    /// How long puts were stuck in all (each over [`STUCK_FROM`]): a put stuck in a dead session's full
    /// queue (until Zenoh closes it, 5 s) would age what is kept without the link having moved on, so
    /// kept frames age on the link's time, which leaves that out.
    stuck: Duration,
}

/// A put blocked longer than this counts as stuck, its time left out of what kept frames' age.
const STUCK_FROM: Duration = Duration::from_millis(50);

/// What keeping one frame costs beside its bytes (its place in the queue, its handle).
const KEPT_OVERHEAD: usize = 64;

impl Kept {
    /// Whether frames are kept at all (a reliable link with a ride-out and memory for it).
    fn enabled(&self) -> bool {
        !self.for_how_long.is_zero() && self.most_bytes > 0
    }

    fn keep(&mut self, sequence: u64, frame: &ZBytes) {
        if !self.enabled() {
            return;
        }
        // The link's time: now, less the time puts were stuck.
        let now = Instant::now();
        let now = now.checked_sub(self.stuck).unwrap_or(now);
        self.bytes += frame.len() + KEPT_OVERHEAD;
        self.frames.push_back((sequence, frame.clone(), now));
        while let Some((_, oldest, at)) = self.frames.front() {
            // The newest stays whatever its size: it may not have been put yet.
            let within = self.bytes <= self.most_bytes && now.duration_since(*at) <= self.for_how_long;
            if within || self.frames.len() == 1 {
                break;
            }
            self.bytes -= oldest.len() + KEPT_OVERHEAD;
            self.frames.pop_front();
        }
    }
}

impl Component for LinkSender {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let key = ctx.text_property("key")?;
        let end = declared(network::sender(&key), &key)?;
        self.matched = network::matched(&end);
        self.seen_cuts = end.cuts.load(std::sync::atomic::Ordering::Acquire);
        self.seen_matching_changes = end.matching_changes.load(std::sync::atomic::Ordering::Acquire);
        *end.status
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = ctx.status_writer();
        self.end = Some(end);
        self.output = kairos_pack_net::encoding::source_name(ctx);
        self.reliable = ctx.bool_property("reliable")?;
        if self.reliable {
            self.kept = Kept {
                for_how_long: Duration::from_secs_f64(ctx.f64_property("ride_out_s")?.max(0.0)),
                most_bytes: (ctx.f64_property("ride_out_mb")?.max(0.0) * 1024.0 * 1024.0) as usize,
                ..Kept::default()
            };
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let mut sample = ctx.read("in")?;
        let Some(end) = self.end.clone() else {
            return Err(ComponentError::Stopped);
        };
        // Numbered by the link, not by the output: a gap the receiver sees was lost in transit, never a
        // sample this reader's policy skipped (those are counted on the input).
        sample.sequence = self.sent;
        let frame = frame_of(&self.output, &sample);
        self.kept.keep(sample.sequence, &frame);
        if self.ride_out(&end) {
            // Held until the receiver says what it has, then put with what it missed.
            self.sent += 1;
        } else {
            self.put(&end, frame);
            self.beat(ctx, &end);
        }
        let matching_changes = end.matching_changes.load(std::sync::atomic::Ordering::Acquire);
        if matching_changes != self.seen_matching_changes || self.looked.ready(STATUS_PERIOD) {
            self.seen_matching_changes = matching_changes;
            self.look(ctx, &end);
        }
        Ok(())
    }

    /// Its counts and whether a receiver matched.
    fn status(&self) -> Option<serde_json::Value> {
        let peer = self.end.as_ref().map(|end| end.peer.as_str());
        // As Zenoh says it now, which its listener also writes while `core` is stuck in a put.
        let matched = self.end.as_ref().map_or(self.matched, |end| {
            end.matching.load(std::sync::atomic::Ordering::Acquire)
        });
        Some(serde_json::json!({
            "kind": "link", "to": peer, "sent": self.sent, "sent_unmatched": self.unmatched,
            "failed": self.failed, "matched": matched, "put_again": self.put_again,
            "kept": self.kept.frames.len(), "answering": self.heartbeat.answering(),
            "silent_s": self.heartbeat.silent_for(Instant::now()).map(|silent| silent.as_secs_f64()),
        }))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Err(ComponentError::failed(format_args!(
            "{name} of a link is set by `kairos deploy`; deploy again to change it"
        )))
    }
}

impl LinkSender {
    /// Puts a new sample's frame.
    fn put(&mut self, end: &network::SenderEnd, frame: ZBytes) {
        // Timed only where frames are kept: the clock stays off every other link's path.
        let started = self.kept.enabled().then(Instant::now);
        let put = end.publisher.put(frame).wait();
        if let Some(took) = started.map(|at| at.elapsed())
            && took > STUCK_FROM
        {
            self.kept.stuck += took;
        }
        match put {
            Ok(()) => {
                self.sent += 1;
                if !self.matched {
                    self.unmatched += 1;
                }
            }
            Err(e) => {
                self.failed += 1;
                // Kept, it goes again after the cut under its own number: the next sample must not take it.
                if self.kept.enabled() {
                    self.sent += 1;
                }
                if self.warned.ready(WARNING_PERIOD) {
                    tracing::warn!("link to {}: cannot send: {e} ({} in all)", end.peer, self.failed);
                }
            }
        }
    }

    /// Every status period: whether the receiver matches, said (and published) when it changes.
    fn look(&mut self, ctx: &Context, end: &network::SenderEnd) {
        let matched = network::matched(end);
        if matched != self.matched {
            if matched {
                tracing::info!("link to {}: matched again", end.peer);
            } else if !self.kept.enabled() {
                tracing::warn!(
                    "link to {}: no receiver any more; samples are dropped until it returns",
                    end.peer
                );
            } else {
                tracing::warn!(
                    "link to {}: no receiver any more; what is sent is kept for {:.1} s and sent again \
                     when it returns",
                    end.peer,
                    self.kept.for_how_long.as_secs_f64()
                );
            }
            self.matched = matched;
            ctx.publish_status(self);
        }
    }

    /// The heartbeat of a reliable link whose receiver matches (outside a cut's ride-out, which asks on
    /// its own): takes the answer to the last question, asks the next when due, and says what it learns.
    fn beat(&mut self, ctx: &Context, end: &network::SenderEnd) {
        if !self.reliable || self.cut || self.asking.is_some() {
            return;
        }
        let now = Instant::now();
        if let Some((answer, sent_then, asked)) = &self.beating {
            match answer.try_recv() {
                Err(std::sync::mpsc::TryRecvError::Empty) if asked.elapsed() < ASK_WAIT + ASK_SLACK => {}
                Ok(Ok(newest)) => {
                    let received = newest.map_or(0, |newest| newest + 1);
                    self.heartbeat.answered(received, *sent_then, now);
                    self.beating = None;
                }
                Ok(Err(_)) | Err(_) => {
                    self.heartbeat.unanswered();
                    self.beating = None;
                }
            }
        }
        if self.beating.is_none() && self.heartbeat.due(now) && network::matched(end) {
            self.heartbeat.asked(now);
            self.beating = Some((end.ask_receiver_newest(ASK_WAIT), self.sent, now));
        }
        let Some(news) = self.heartbeat.news(now) else {
            return;
        };
        let peer = &end.peer;
        match news {
            heartbeat::News::Unanswering => tracing::warn!(
                "link to {peer}: the receiver still matches but has not answered for {} s: either its consumer \
                 is slower than this link (it never skips, so this producer waits for it) or the path is \
                 dead whatever the network layer says",
                heartbeat::UNANSWERED_SAID
            ),
            heartbeat::News::Answering => tracing::info!("link to {peer}: the receiver answers again"),
            heartbeat::News::Silent(silent) => tracing::warn!(
                "link to {peer}: the receiver answers but has received nothing for {:.0} s while samples \
                 were on their way: its consumer is stalled, or the network path is",
                silent.as_secs_f64()
            ),
            heartbeat::News::Receiving => tracing::info!("link to {peer}: the receiver receives again"),
        }
        ctx.publish_status(self);
    }

    /// Rides out a cut, the newest sample already kept: once the receiver matches again after it stopped,
    /// asks it for the newest sequence number it received and holds new samples until it says; then puts
    /// again, in order, every kept frame after that one. Whether this sample was held or put here.
    fn ride_out(&mut self, end: &network::SenderEnd) -> bool {
        // Nothing kept, nothing to hold: a sample held would be lost.
        if !self.kept.enabled() {
            return false;
        }
        let cuts = end.cuts.load(std::sync::atomic::Ordering::Acquire);
        if cuts != self.seen_cuts {
            self.seen_cuts = cuts;
            if !self.cut {
                self.noticed_from = self.sent;
            }
            self.cut = true;
        }
        if let Some((asking, since)) = &self.asking {
            let answer = match asking.try_recv() {
                // Held no longer than the question may take, whatever Zenoh does with it.
                Err(std::sync::mpsc::TryRecvError::Empty) if since.elapsed() < ASK_WAIT + ASK_SLACK => {
                    return true;
                }
                Err(_) => Err(network::AskError::Unanswered(ASK_WAIT)),
                Ok(answer) => answer,
            };
            // Unanswered (the far end flapping as it comes back), while the samples held meanwhile are
            // still kept: asked again, or, gone again before it answered, held on until it matches again.
            if answer.is_err()
                && self
                    .held_since
                    .is_some_and(|at| at.elapsed() < self.kept.for_how_long)
            {
                if network::matched(end) {
                    self.asking = Some((end.ask_receiver_newest(ASK_WAIT), Instant::now()));
                } else {
                    self.asking = None;
                    self.cut = true;
                }
                return true;
            }
            self.asking = None;
            self.put_again_after(end, &answer);
            self.held_since = None;
            return true;
        }
        if self.cut && network::matched(end) {
            self.cut = false;
            // Matched again within one hold (it flapped before answering): held from where it began.
            if self.held_since.is_none() {
                self.held_from = self.sent;
                self.held_since = Some(Instant::now());
            }
            self.asking = Some((end.ask_receiver_newest(ASK_WAIT), Instant::now()));
            return true;
        }
        // Held while the receiver is gone: the path can come back before Zenoh says it matches, and a
        // sample put then would reach the receiver ahead of those it missed, which it would count lost
        // and, asked, say it had everything up to this one.
        self.cut
    }

    /// Puts again every kept frame after the newest the receiver received (without its answer, those held
    /// while asking), and says how the cut went.
    fn put_again_after(&mut self, end: &network::SenderEnd, newest: &Result<Option<u64>, network::AskError>) {
        let first = match newest {
            Ok(Some(newest)) => newest + 1,
            Ok(None) => {
                tracing::warn!(
                    "link to {}: the receiver started afresh (its host restarted): what it had received \
                     is gone with it; it gets what was sent since the cut was noticed",
                    end.peer
                );
                self.noticed_from
            }
            Err(reason) => {
                tracing::warn!(
                    "link to {}: matched again, but the receiver did not say what it received ({reason}): \
                     what it missed during the cut is counted as lost",
                    end.peer
                );
                self.held_from
            }
        };
        let mut again = 0_u64;
        for (sequence, frame, _) in &self.kept.frames {
            if *sequence >= first && end.publisher.put(frame.clone()).wait().is_ok() {
                again += 1;
            }
        }
        // The newest sample, kept and not yet counted as sent, is `self.sent`.
        let missed = (self.sent + 1).saturating_sub(first);
        // What was held while asking was never put: only the rest is put again.
        self.put_again += again.saturating_sub(self.sent + 1 - self.held_from);
        if newest.is_ok() {
            tracing::info!(
                "link to {}: matched again; {again} of the {missed} samples it had not received were sent{}",
                end.peer,
                if again < missed {
                    ", the others were no longer kept (counted as lost)"
                } else {
                    ""
                }
            );
        }
    }
}

/// The shortest quiet a receiver calls unusual, however fast its link: a status read, a scheduling
/// hiccup and a burst's batching stay well under it.
const QUIET_FLOOR: Duration = Duration::from_millis(400);

/// How long a receiver remembers the longest wait between its arrivals.
const RHYTHM_WINDOW: Duration = Duration::from_secs(5);

/// How long a receiver usually waits between arrivals, and so when a quiet is unusual: twice the longest
/// wait of the last window or two, at least [`QUIET_FLOOR`]. A wait beyond that is learnt only when the
/// next one is too (the source slowed down): an outage that ends does not teach that outages are usual.
#[derive(Debug, Default)]
struct Rhythm {
    /// The longest wait in this window and the one before.
    longest: [Option<Duration>; 2],
    window_from: Option<Instant>,
    /// An unusual wait not learnt yet.
    unusual: Option<Duration>,
}

impl Rhythm {
    /// How long a quiet is before it is unusual; `None` until a wait was learnt.
    fn quiet_after(&self) -> Option<Duration> {
        let longest = self.longest.iter().flatten().max()?;
        Some((*longest * 2).max(QUIET_FLOOR))
    }

    /// A sample came `wait` after the one before.
    fn arrived(&mut self, wait: Duration, now: Instant) {
        let window_from = *self.window_from.get_or_insert(now);
        if now.duration_since(window_from) >= RHYTHM_WINDOW {
            self.longest = [None, self.longest[0]];
            self.window_from = Some(now);
        }
        if self.quiet_after().is_some_and(|after| wait > after) {
            let Some(before) = self.unusual.replace(wait) else {
                return;
            };
            self.learn(before);
        }
        self.unusual = None;
        self.learn(wait);
    }

    fn learn(&mut self, wait: Duration) {
        self.longest[0] = Some(self.longest[0].map_or(wait, |longest| longest.max(wait)));
    }
}

/// `link.receiver`. See [`receiver_descriptor`].
#[derive(Debug, Default)]
pub struct LinkReceiver {
    end: Option<std::sync::Arc<network::ReceiverEnd>>,
    samples: SampleReceiver,
    last: Option<Instant>,
    rhythm: Rhythm,
    /// Whether the quiet now is unusual, as its status said: the status goes out the moment it becomes
    /// so and the moment it ends, so the coordinator need not wait for the next status period.
    quiet: bool,
}

impl LinkReceiver {
    /// One sample from Zenoh: a frame in one piece as it is, a fragmented one piece by piece.
    fn take(&mut self, sample: &zenoh::sample::Sample, peer: &str, ctx: &mut Context) -> ComponentResult {
        let payload = sample.payload();
        if payload.slices().nth(1).is_some() {
            let pieces: Vec<&[u8]> = payload.slices().collect();
            self.samples.take_pieces(&pieces, peer, ctx)?;
        } else {
            self.samples.take(&payload.to_bytes(), peer, ctx)?;
        }
        if let (Some(newest), Some(end)) = (self.samples.newest(), &self.end) {
            end.received(newest);
        }
        Ok(())
    }
}

impl Component for LinkReceiver {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let key = ctx.text_property("key")?;
        self.end = Some(declared(network::receiver(&key), &key)?);
        self.samples = SampleReceiver::expecting(DataType::from_name(&ctx.text_property("data_type")?));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(end) = self.end.clone() else {
            return Err(ComponentError::Stopped);
        };
        match end.incoming.recv_timeout(RECEIVE_WAIT) {
            Ok(Some(sample)) => {
                let now = Instant::now();
                if let Some(last) = self.last.replace(now) {
                    self.rhythm.arrived(now.duration_since(last), now);
                }
                self.take(&sample, &end.peer, ctx)?;
                // What has arrived meanwhile goes in the same call: one wake-up for a burst.
                for _ in 1..BURST {
                    let Ok(Some(sample)) = end.incoming.try_recv() else {
                        break;
                    };
                    self.take(&sample, &end.peer, ctx)?;
                }
                if std::mem::take(&mut self.quiet) {
                    ctx.publish_status(self);
                }
            }
            Ok(None) => {
                let quiet_after = self.rhythm.quiet_after();
                if !self.quiet
                    && let (Some(last), Some(after)) = (self.last, quiet_after)
                    && last.elapsed() >= after
                {
                    self.quiet = true;
                    ctx.publish_status(self);
                }
            }
            Err(e) => {
                return Err(ComponentError::failed(format_args!(
                    "the link from {} closed: {e}",
                    end.peer
                )));
            }
        }
        Ok(())
    }

    /// Its counts and how long ago the last sample came.
    fn status(&self) -> Option<serde_json::Value> {
        let status = serde_json::json!({
            "kind": "link", "from": self.end.as_ref().map(|end| end.peer.as_str()),
            "last_sample_age_ms": self.last.map(|at| at.elapsed().as_millis()),
            "quiet_after_ms": self.rhythm.quiet_after().map(|after| after.as_millis()),
        });
        Some(kairos_pack_net::encoding::status_with(
            status,
            Some(&self.samples),
        ))
    }

    fn property_changed(&mut self, name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Err(ComponentError::failed(format_args!(
            "{name} of a link is set by `kairos deploy`; deploy again to change it"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::{QUIET_FLOOR, Rhythm};
    use std::time::{Duration, Instant};

    /// Feeds `waits` (ms) one after the other from `start`; the instant after the last.
    fn feed(rhythm: &mut Rhythm, start: Instant, waits: &[u64]) -> Instant {
        waits.iter().fold(start, |now, wait| {
            let now = now + Duration::from_millis(*wait);
            rhythm.arrived(Duration::from_millis(*wait), now);
            now
        })
    }

    #[test]
    fn a_quiet_is_unusual_after_twice_the_longest_recent_wait_and_an_outage_teaches_nothing() {
        let mut rhythm = Rhythm::default();
        assert_eq!(rhythm.quiet_after(), None, "nothing learnt yet");
        let now = feed(&mut rhythm, Instant::now(), &[10; 100]);
        assert_eq!(rhythm.quiet_after(), Some(QUIET_FLOOR), "a fast link: the floor");
        // A 3 s cut that ends is not learnt; the link at 100 Hz again keeps its 400 ms.
        let now = feed(&mut rhythm, now, &[3000, 10, 10]);
        assert_eq!(rhythm.quiet_after(), Some(QUIET_FLOOR));
        // The source slowed to 1 Hz: two long waits in a row are its new rhythm.
        let now = feed(&mut rhythm, now, &[1000, 1000]);
        assert_eq!(rhythm.quiet_after(), Some(Duration::from_secs(2)));
        // Two windows later at 100 Hz, the slow waits are forgotten.
        feed(&mut rhythm, now, &[10; 1100]);
        assert_eq!(rhythm.quiet_after(), Some(QUIET_FLOOR));
    }
}

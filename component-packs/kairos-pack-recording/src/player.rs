//! `recording.player`: replays one or more recordings on the runtime clock, one output per recorded
//! channel, typed from the channel's schema.
//!
//! The recordings' messages form one timeline, ordered by log time (when each sample was issued, so
//! replay reproduces when data became available). In real time, the message at timeline time `t` is
//! emitted at `anchor.wall + (t − anchor.t) / speed`; the anchor moves on every start, resume, seek and
//! speed change. As fast as possible, nothing waits: a NeverSkipping input downstream then receives every
//! sample, and two replays give identical outputs.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::Path;
use std::sync::Arc;

use kairos_sdk::descriptor::{DEFAULT_BUFFER_SIZE, Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, OutputInfo,
    Timestamp, Value,
};

use crate::decode::{ChannelDecoder, data_type_of};
use crate::timeline::{RawMessage, RecordingIndex, seconds_to_nanos};

/// The properties naming the recordings, in the order their channels become outputs.
pub const FILE_PROPERTIES: [&str; 4] = ["path", "path2", "path3", "path4"];

/// Behind schedule by more than this, the player re-anchors instead of rushing to catch up (after the
/// diagram was paused, or downstream held it up).
const MAX_LATENESS_NANOS: i64 = 250_000_000;

/// The least time between two status updates while playing.
const STATUS_EVERY: std::time::Duration = std::time::Duration::from_millis(100);

/// How often a paused player looks up when nothing wakes it.
const PAUSED_RECHECK: std::time::Duration = std::time::Duration::from_millis(100);

/// How far back a seek looks for each channel's last sample before the target, in blocks.
const RESTORE_BLOCKS: usize = 256;
/// "Previous marker" skips a marker this close behind the replay (the one it stands on), so pressing it
/// again moves on to the one before.
const MARKER_BACK_NANOS: i64 = 1_000_000;

/// One output to be: a channel of one of the recordings.
struct PlannedOutput {
    file: usize,
    channel: u16,
    name: String,
    data_type: DataType,
    doc: String,
}

/// The outputs for these recordings, in a deterministic order: files as given, channels by topic. Port
/// names come from topics (`camera.image` → `camera_image`); a repeated name gets `_2`, `_3`, ...
fn plan(files: &[Arc<RecordingIndex>]) -> Vec<PlannedOutput> {
    let mut taken = BTreeSet::new();
    let mut planned = Vec::new();
    for (file, index) in files.iter().enumerate() {
        let file_name = index
            .path()
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        for channel in index.channels() {
            let base = kairos_sdk::port_name_for_topic(&channel.topic);
            let mut name = base.clone();
            let mut n = 2;
            while !taken.insert(name.clone()) {
                name = format!("{base}_{n}");
                n += 1;
            }
            planned.push(PlannedOutput {
                file,
                channel: channel.id,
                name,
                data_type: index.channel_definition(channel.id).map_or_else(
                    || data_type_of(&channel.schema),
                    |c| ChannelDecoder::of(c).data_type(),
                ),
                doc: format!(
                    "'{}' of {file_name} ({}, {} messages)",
                    channel.topic,
                    if channel.schema.is_empty() {
                        "no schema"
                    } else {
                        &channel.schema
                    },
                    channel.messages
                ),
            });
        }
    }
    planned
}

fn open_files(properties: &BTreeMap<String, Value>) -> Result<Vec<Arc<RecordingIndex>>, DescribeError> {
    let mut files = Vec::new();
    for property in FILE_PROPERTIES {
        let path = properties.get(property).and_then(Value::as_text).unwrap_or("");
        if path.is_empty() {
            if property == "path" {
                return Err(
                    DescribeError::property(property, "no recording to replay").with_suggestion(
                        "set 'path' to an MCAP file (from recording.recorder or any MCAP writer)",
                    ),
                );
            }
            continue;
        }
        let file = crate::timeline::recording_file(Path::new(path))
            .map_err(|e| DescribeError::property(property, format!("{path}: {e}")))?;
        let index =
            RecordingIndex::open(&file).map_err(|e| DescribeError::property(property, e.to_string()))?;
        if index.channels().is_empty() {
            let why = index.damage().map_or_else(String::new, |d| format!(" ({d})"));
            return Err(DescribeError::property(
                property,
                format!("{path} holds no intact message to replay{why}"),
            ));
        }
        files.push(index);
    }
    Ok(files)
}

/// Where the timeline is anchored to the runtime clock.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    timeline: i64,
    wall: Timestamp,
}

/// One recording being replayed.
struct Source {
    index: Arc<RecordingIndex>,
    /// Added to the file's log times to place them on the timeline.
    shift: i64,
    /// Channel id → (output index, how its messages decode).
    routes: BTreeMap<u16, (usize, ChannelDecoder)>,
    next_block: usize,
    pending: VecDeque<RawMessage>,
}

impl Source {
    /// The timeline time of this source's next message, loading blocks as needed.
    fn peek(&mut self) -> Result<Option<i64>, ComponentError> {
        while self.pending.is_empty() {
            if self.next_block >= self.index.block_count() {
                return Ok(None);
            }
            let messages = self
                .index
                .read_block(self.next_block)
                .map_err(ComponentError::failed)?;
            self.next_block += 1;
            self.pending.extend(
                messages
                    .into_iter()
                    .filter(|m| self.routes.contains_key(&m.channel)),
            );
        }
        Ok(self.pending.front().map(|m| to_timeline(m.log_time, self.shift)))
    }
}

fn to_timeline(log_time: u64, shift: i64) -> i64 {
    i64::try_from(log_time).unwrap_or(i64::MAX).saturating_add(shift)
}

/// Whether the player runs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum Transport {
    #[default]
    Playing,
    Paused,
    /// Paused, with one sample to emit.
    Stepping,
}

/// The player component. See [`Player::info`].
#[derive(Default)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent settings of a replay, and whether it ended"
)]
pub struct Player {
    sources: Vec<Source>,
    /// The timeline's first and last message times.
    timeline: (i64, i64),
    /// The part replayed: `start_s` to `end_s`.
    range: (i64, i64),
    anchor: Option<Anchor>,
    speed: f64,
    real_time: bool,
    recorded_times: bool,
    looping: bool,
    transport: Transport,
    /// Samples to emit at once after a seek: each channel's last one before the target.
    restore: VecDeque<(usize, RawMessage)>,
    undecodable: BTreeMap<usize, u64>,
    /// The timeline time of the last sample emitted: where the replay stands.
    reached: i64,
    /// One per output: its name, the recording it comes from and its message count (the status's tracks).
    tracks: Vec<(String, usize, u64)>,
    /// The recordings' markers on the timeline, in time order.
    markers: Vec<(i64, String)>,
    /// When the status was last published, and whether the replay reached its end.
    published: Option<std::time::Instant>,
    ended: bool,
    /// At the end with `at_end` hold: waiting there for a seek, a rewind or play.
    held: bool,
    hold_at_end: bool,
}

impl std::fmt::Debug for Player {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Player")
            .field("files", &self.sources.len())
            .field("transport", &self.transport)
            .field("speed", &self.speed)
            .finish_non_exhaustive()
    }
}

impl Player {
    /// The descriptor of the type; an instance's outputs come from its recordings ([`Player::describe`]).
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "recording.player",
            "recording",
            "Replays MCAP recordings as if the sensors were live: one output per recorded channel",
        )
        .label("MCAP player")
        .property(Property::path("path", "recording.mcap").doc("The recording to replay"))
        .property(Property::path("path2", "").doc("A second recording on the same timeline (optional)"))
        .property(Property::path("path3", "").doc("A third recording (optional)"))
        .property(Property::path("path4", "").doc("A fourth recording (optional)"))
        .property(
            Property::choice("align", &["clock", "start"], "clock").doc(
                "clock: the recordings' times are kept (machines with synchronised clocks); start: each recording's first message at the same instant",
            ),
        )
        .property(
            Property::choice("mode", &["real_time", "as_fast_as_possible"], "real_time").doc(
                "real_time: original timing times speed; as_fast_as_possible: no waiting (NeverSkipping inputs downstream get every sample)",
            ),
        )
        .property(
            Property::f64("speed", 1.0).unit("x real time")
                .range(0.1, 100.0)
                .live()
                .doc("Replay speed in real time: 2 replays twice as fast"),
        )
        .property(Property::bool("loop", false).live().doc("Start again at the end"))
        .property(
            Property::choice("at_end", &["stop", "hold"], "stop")
                .live()
                .doc("stop: the replay ends there, and what it feeds ends after it (kairos run then exits); hold: it waits at its last sample, where a seek, a rewind or play replays again"),
        )
        .property(
            Property::f64("start_s", 0.0).unit("s")
                .range(0.0, 1e9)
                .doc("Start this long after the first message"),
        )
        .property(
            Property::f64("end_s", 0.0).unit("s")
                .range(0.0, 1e9)
                .doc("End this long after the first message (0: at the last message)"),
        )
        .property(
            Property::choice("times", &["recorded", "replay"], "recorded").doc(
                "recorded: samples keep their recorded timestamp and time of issue; replay: both move onto the runtime clock (time of issue = now), latency kept",
            ),
        )
        .property(Property::bool("start_paused", false).doc("Wait for the play action before the first sample"))
        .property(
            Property::f64("seek_s", -1.0).unit("s")
                .range(-1.0, 1e9)
                .live()
                .doc("Setting it jumps to this time after the first message; every output first re-emits its last sample before it (-1: no jump)"),
        )
        .action("play", "Play (resume after pause or step)")
        .action("pause", "Pause")
        .action("step", "Emit the next sample, then pause")
        .action("rewind", "Jump back to the start")
        .action("next_marker", "Jump to the next marker after where the replay stands")
        .action("previous_marker", "Jump to the marker before where the replay stands")
        .build()
    }

    /// The descriptor of one player: the type's, with one output per channel of its recordings.
    pub fn describe(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
        let files = open_files(properties)?;
        let mut info = Self::info();
        info.outputs = plan(&files)
            .into_iter()
            .map(|planned| OutputInfo {
                name: planned.name,
                data_type: planned.data_type,
                follows_input: None,
                default_buffer_size: DEFAULT_BUFFER_SIZE,
                doc: planned.doc,
                known_as: None,
            })
            .collect();
        Ok(info)
    }

    /// Jumps to timeline time `target`: later messages play from there, and every output first gets its
    /// last sample before `target` so downstream state is what it was at that time.
    fn seek(&mut self, target: i64) -> Result<(), ComponentError> {
        let target = target.clamp(self.range.0, self.range.1);
        // Held at the end: a seek replays from its target.
        self.held = false;
        self.restore.clear();
        self.anchor = None;
        let mut restore: Vec<(i64, usize, RawMessage)> = Vec::new();
        for (source_index, source) in self.sources.iter_mut().enumerate() {
            let log_target = u64::try_from(target.saturating_sub(source.shift)).unwrap_or(0);
            let first = source.index.block_at(log_target);
            source.next_block = first;
            source.pending.clear();
            // Each channel's last message before the target, looking back block by block.
            let mut last: BTreeMap<u16, RawMessage> = BTreeMap::new();
            let mut block = first.min(source.index.block_count());
            let mut looked = 0;
            loop {
                let messages = source.index.read_block(block).map_err(ComponentError::failed)?;
                for message in messages {
                    if !source.routes.contains_key(&message.channel) {
                        continue;
                    }
                    let at = to_timeline(message.log_time, source.shift);
                    if at < target && at >= self.timeline.0 {
                        let newer = last
                            .get(&message.channel)
                            .is_none_or(|m| m.log_time <= message.log_time);
                        if newer {
                            last.insert(message.channel, message);
                        }
                    }
                }
                looked += 1;
                if last.len() == source.routes.len() || block == 0 || looked >= RESTORE_BLOCKS {
                    break;
                }
                block -= 1;
            }
            restore.extend(
                last.into_values()
                    .map(|m| (to_timeline(m.log_time, source.shift), source_index, m)),
            );
            // The block holding the target may start before it.
            source.peek()?;
            while let Some(front) = source.pending.front() {
                if to_timeline(front.log_time, source.shift) >= target {
                    break;
                }
                source.pending.pop_front();
                if source.pending.is_empty() {
                    source.peek()?;
                }
            }
        }
        restore.sort_by_key(|(at, _, _)| *at);
        self.restore = restore.into_iter().map(|(_, s, m)| (s, m)).collect();
        Ok(())
    }

    /// The source whose next message comes first on the timeline, with that message's time.
    fn next_source(&mut self) -> Result<Option<(usize, i64)>, ComponentError> {
        let mut best: Option<(usize, i64)> = None;
        for (index, source) in self.sources.iter_mut().enumerate() {
            if let Some(at) = source.peek()?
                && best.is_none_or(|(_, t)| at < t)
            {
                best = Some((index, at));
            }
        }
        Ok(best)
    }

    fn emit(&mut self, ctx: &mut Context, source: usize, message: &RawMessage) -> ComponentResult {
        let Some((output, decoder)) = self
            .sources
            .get(source)
            .and_then(|s| s.routes.get(&message.channel))
        else {
            return Ok(());
        };
        let output = *output;
        let (payload, stamp) = match decoder.decode(&message.data) {
            Ok(payload_and_stamp) => payload_and_stamp,
            Err(error) => {
                let count = self.undecodable.entry(output).or_insert(0);
                if *count == 0 {
                    let name = ctx.outputs().get(output).map_or("?", |o| o.name());
                    tracing::warn!(
                        "{}: a message for output '{name}' (log time {}) cannot be decoded: {error}; such messages are skipped",
                        ctx.id(),
                        message.log_time
                    );
                }
                *count += 1;
                return Ok(());
            }
        };
        // A ROS message's header stamp is its timestamp; otherwise the publish time is.
        let publish = stamp.map_or_else(
            || i64::try_from(message.publish_time).unwrap_or(i64::MAX),
            |t| t.0,
        );
        let log = i64::try_from(message.log_time).unwrap_or(i64::MAX);
        if let Some(source) = self.sources.get(source) {
            self.reached = to_timeline(message.log_time, source.shift);
        }
        if self.recorded_times {
            ctx.write_replayed(output, payload, Timestamp(publish), Timestamp(log))
        } else {
            let now = ctx.now();
            let latency = log.saturating_sub(publish);
            ctx.write_replayed(
                output,
                payload,
                Timestamp(now.as_nanos().saturating_sub(latency)),
                now,
            )
        }
    }

    /// Publishes where the replay stands (for the studio's timeline): at most ten times a second, or at once
    /// with `now`.
    fn publish_status(&mut self, ctx: &Context, now: bool) {
        if !now && self.published.is_some_and(|at| at.elapsed() < STATUS_EVERY) {
            return;
        }
        self.published = Some(std::time::Instant::now());
        let seconds = |t: i64| t.saturating_sub(self.timeline.0) as f64 * 1e-9;
        let files: Vec<serde_json::Value> = self
            .sources
            .iter()
            .map(|s| {
                let first = s.index.first_log_time().map_or(0, |t| to_timeline(t, s.shift));
                let last = s.index.last_log_time().map_or(0, |t| to_timeline(t, s.shift));
                serde_json::json!({
                    "path": s.index.path().display().to_string(),
                    "start_s": seconds(first),
                    "end_s": seconds(last),
                })
            })
            .collect();
        let tracks: Vec<serde_json::Value> = self
            .tracks
            .iter()
            .map(|(output, file, messages)| serde_json::json!({"output": output, "file": file, "messages": messages}))
            .collect();
        ctx.set_status(serde_json::json!({
            "kind": "player",
            "position_s": seconds(self.reached.max(self.timeline.0)),
            "duration_s": seconds(self.timeline.1),
            "range_s": [seconds(self.range.0), seconds(self.range.1)],
            "playing": self.transport == Transport::Playing && !self.ended && !self.held,
            "ended": self.ended,
            "held_at_end": self.held,
            "speed": self.speed,
            "loop": self.looping,
            "files": files,
            "tracks": tracks,
            "markers": self
                .markers
                .iter()
                .map(|(at, text)| serde_json::json!({"t_s": seconds(*at), "text": text}))
                .collect::<Vec<_>>(),
        }));
    }

    /// The timeline time the replay has reached, when running in real time.
    fn position(&self, now: Timestamp) -> Option<i64> {
        let anchor = self.anchor?;
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_precision_loss,
            reason = "nanoseconds over hours fit"
        )]
        let advanced = (now.nanos_since(anchor.wall) as f64 * self.speed) as i64;
        Some(anchor.timeline.saturating_add(advanced))
    }
}

/// Says so when `file` comes from a host that followed a clock master and was recorded while that clock
/// was not locked: its times may not line up with the other hosts'.
fn warn_if_unlocked(ctx: &Context, file: &RecordingIndex) {
    if let Some(warning) = file.clock().and_then(crate::inspect::unlocked_clock) {
        tracing::warn!("{}: {} was {warning}", ctx.id(), file.path().display());
    }
}

/// Every recording's markers on the common timeline, in time order.
fn markers_of(sources: &[Source]) -> Vec<(i64, String)> {
    let mut markers: Vec<(i64, String)> = sources
        .iter()
        .flat_map(|s| {
            s.index
                .markers()
                .iter()
                .map(|(at, text)| (to_timeline(*at, s.shift), text.clone()))
        })
        .collect();
    markers.sort_by_key(|(at, _)| *at);
    markers
}

impl Component for Player {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let files = open_files(ctx.properties()).map_err(|e| ComponentError::failed(e.message))?;
        for file in &files {
            warn_if_unlocked(ctx, file);
            if let Some(damage) = file.damage() {
                tracing::warn!(
                    "{}: {} is damaged: {damage}; replaying its {} intact blocks",
                    ctx.id(),
                    file.path().display(),
                    file.block_count()
                );
            }
        }
        let starts: Vec<i64> = files
            .iter()
            .map(|f| to_timeline(f.first_log_time().unwrap_or(0), 0))
            .collect();
        let common_start = starts.iter().copied().min().unwrap_or(0);
        let align_starts = ctx.text_property("align")? == "start";
        if files.len() > 1 && !align_starts {
            let apart =
                crate::merge::unsynchronised(files.iter().map(|f| (f.path().display().to_string(), &**f)));
            if !apart.is_empty() {
                tracing::warn!(
                    "{}: these recordings were not made on synchronised clocks, so on one timeline their \
                     times may not line up (kairos merge refuses them): {}. With align: start each one's \
                     start is put at the same instant instead",
                    ctx.id(),
                    apart.join("; ")
                );
            }
        }
        let planned = plan(&files);
        self.sources = files
            .into_iter()
            .zip(&starts)
            .map(|(index, start)| Source {
                index,
                shift: if align_starts { common_start - start } else { 0 },
                routes: BTreeMap::new(),
                next_block: 0,
                pending: VecDeque::new(),
            })
            .collect();
        for output in planned {
            let Some(port) = ctx.outputs().iter().position(|o| o.name() == output.name) else {
                continue;
            };
            let Some(source) = self.sources.get_mut(output.file) else {
                continue;
            };
            let decoder = source.index.channel_definition(output.channel).map_or_else(
                || {
                    let schema = source
                        .index
                        .channels()
                        .iter()
                        .find(|c| c.id == output.channel)
                        .map_or_else(String::new, |c| c.schema.clone());
                    ChannelDecoder::Named(schema)
                },
                |channel| ChannelDecoder::of(channel),
            );
            let messages = source
                .index
                .channels()
                .iter()
                .find(|c| c.id == output.channel)
                .map_or(0, |c| c.messages);
            self.tracks.push((output.name.clone(), output.file, messages));
            source.routes.insert(output.channel, (port, decoder));
        }
        let first = self
            .sources
            .iter()
            .filter_map(|s| s.index.first_log_time().map(|t| to_timeline(t, s.shift)))
            .min()
            .unwrap_or(0);
        let last = self
            .sources
            .iter()
            .filter_map(|s| s.index.last_log_time().map(|t| to_timeline(t, s.shift)))
            .max()
            .unwrap_or(0);
        self.timeline = (first, last);
        self.markers = markers_of(&self.sources);
        let start = first.saturating_add(seconds_to_nanos(ctx.f64_property("start_s")?));
        let end_s = ctx.f64_property("end_s")?;
        let end = if end_s > 0.0 {
            first.saturating_add(seconds_to_nanos(end_s)).min(last)
        } else {
            last
        };
        if start > end {
            return Err(ComponentError::failed(format_args!(
                "start_s is past the end of the recordings ({:.3} s long)",
                (last - first) as f64 * 1e-9
            )));
        }
        self.range = (start, end);
        self.speed = ctx.f64_property("speed")?;
        self.real_time = ctx.text_property("mode")? == "real_time";
        self.recorded_times = ctx.text_property("times")? == "recorded";
        self.looping = ctx.bool_property("loop")?;
        self.hold_at_end = ctx.text_property("at_end")? == "hold";
        if ctx.bool_property("start_paused")? {
            self.transport = Transport::Paused;
        }
        let seek_s = ctx.f64_property("seek_s")?;
        let target = if seek_s >= 0.0 {
            first.saturating_add(seconds_to_nanos(seek_s))
        } else {
            start
        };
        self.seek(target)?;
        self.reached = target;
        self.publish_status(ctx, true);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let result = self.cycle(ctx);
        let finished = matches!(result, Err(ComponentError::EndOfStream));
        self.ended |= finished;
        self.publish_status(ctx, finished);
        result
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        self.change_property(name, value, ctx)?;
        self.publish_status(ctx, true);
        Ok(())
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        self.act(name)?;
        self.publish_status(ctx, true);
        Ok(())
    }
}

impl Player {
    fn cycle(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.transport == Transport::Paused || self.held {
            // Not a wait on the clock: a manual clock (the offline harness) would jump to the deadline.
            ctx.sleep(PAUSED_RECHECK)?;
            return Err(ComponentError::NoData);
        }
        let stepping = self.transport == Transport::Stepping;
        if stepping {
            self.transport = Transport::Paused;
            self.anchor = None;
        }
        if let Some((source, message)) = self.restore.pop_front() {
            // Restored samples come from before the seek target, which is where the replay stands.
            let reached = self.reached;
            let result = self.emit(ctx, source, &message);
            self.reached = reached;
            return result;
        }
        let next = self.next_source()?;
        let Some((source, at)) = next.filter(|(_, at)| *at <= self.range.1) else {
            if self.looping {
                self.seek(self.range.0)?;
                return Ok(());
            }
            if self.hold_at_end {
                self.held = true;
                self.reached = self.range.1;
                self.publish_status(ctx, true);
                return Err(ComponentError::NoData);
            }
            return Err(ComponentError::EndOfStream);
        };
        if self.real_time && !stepping {
            let now = ctx.now();
            let anchor = *self.anchor.get_or_insert(Anchor {
                timeline: at,
                wall: now,
            });
            #[allow(
                clippy::cast_possible_truncation,
                clippy::cast_precision_loss,
                reason = "nanoseconds over hours fit"
            )]
            let wait = ((at - anchor.timeline) as f64 / self.speed) as i64;
            let deadline = Timestamp(anchor.wall.as_nanos().saturating_add(wait));
            if now.nanos_since(deadline) > MAX_LATENESS_NANOS {
                self.anchor = Some(Anchor {
                    timeline: at,
                    wall: now,
                });
            } else {
                ctx.wait_until(deadline)?;
            }
        }
        let Some(message) = self.sources.get_mut(source).and_then(|s| s.pending.pop_front()) else {
            return Ok(());
        };
        self.emit(ctx, source, &message)
    }

    fn change_property(&mut self, name: &str, value: &Value, ctx: &Context) -> ComponentResult {
        match name {
            "speed" => {
                let speed = value.as_f64().unwrap_or(1.0);
                if let Some(position) = self.position(ctx.now()) {
                    self.anchor = Some(Anchor {
                        timeline: position,
                        wall: ctx.now(),
                    });
                }
                self.speed = speed;
            }
            "loop" => self.looping = value.as_bool().unwrap_or(false),
            "at_end" => {
                self.hold_at_end = value.as_text() == Some("hold");
                // Held and told to stop now: the end it was waiting at comes on the next cycle.
                self.held &= self.hold_at_end;
            }
            "seek_s" => {
                let seconds = value.as_f64().unwrap_or(-1.0);
                if seconds >= 0.0 {
                    let target = self.timeline.0.saturating_add(seconds_to_nanos(seconds));
                    self.seek(target)?;
                    self.reached = target.clamp(self.range.0, self.range.1);
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn act(&mut self, name: &str) -> ComponentResult {
        match name {
            "play" => {
                // At the end, play starts again from the start, as a media player does.
                if self.held {
                    self.seek(self.range.0)?;
                    self.reached = self.range.0;
                }
                self.transport = Transport::Playing;
                self.anchor = None;
            }
            "pause" => {
                self.transport = Transport::Paused;
                self.anchor = None;
            }
            "step" => self.transport = Transport::Stepping,
            "rewind" => {
                self.seek(self.range.0)?;
                self.reached = self.range.0;
            }
            "next_marker" | "previous_marker" => {
                // Back: to the marker behind the replay; standing on one, to the one before it.
                let target = if name == "next_marker" {
                    self.markers
                        .iter()
                        .map(|(at, _)| *at)
                        .find(|at| *at > self.reached)
                } else {
                    self.markers
                        .iter()
                        .rev()
                        .map(|(at, _)| *at)
                        .find(|at| *at < self.reached.saturating_sub(MARKER_BACK_NANOS))
                };
                if let Some(target) = target {
                    self.seek(target)?;
                    self.reached = target.clamp(self.range.0, self.range.1);
                }
            }
            other => return Err(ComponentError::failed(format_args!("no action named '{other}'"))),
        }
        Ok(())
    }
}

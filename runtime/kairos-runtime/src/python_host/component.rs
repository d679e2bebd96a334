//! The runtime's half of a Python component: a [`Component`] in the component's thread that starts the
//! worker, sends it `birth`, `core`, `death`, property changes and actions, and answers its requests with
//! this thread's own context, so reads follow the connection's policy and writes go into the output's
//! buffer exactly as a built-in component's do.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_sdk_core::host::ContextHost;
use kairos_sdk_core::pixels::SHARED_FROM_BYTES;
use kairos_sdk_core::{
    Component, ComponentError, ComponentResult, Context, Image, Payload, Pixels, PixelsMut, STATUS_PERIOD,
    Sample, Synchronizer, Throttle, Timestamp, Value,
};

use super::ComponentSpec;
use super::wire::{self, Connection, Fields, ImagePixels, SentPixels, WireError, Written};
use super::worker::Worker;

/// How long a component that was asked to stop may take to leave Python before its process is ended.
const STOP_GRACE: Duration = Duration::from_secs(2);
/// How often a thread waiting for its worker looks whether it was asked to stop.
const POLL_SLICE: Duration = Duration::from_millis(50);
/// Buffers allocated for a worker and not yet written; beyond it the oldest is dropped (a worker that
/// asks for images and never writes them must not hold memory without bound).
const ALLOCATED_KEPT: usize = 16;

/// A component whose code is a Python class.
pub(crate) struct PythonComponent {
    spec: Arc<ComponentSpec>,
    session: Option<Session>,
    stats: ImageStats,
    python_status: Option<serde_json::Value>,
    status_throttle: Throttle,
    /// Why the file as edited last does not load, while the previous code keeps running.
    reload_error: Option<String>,
}

impl std::fmt::Debug for PythonComponent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PythonComponent")
            .field("class", &self.spec.class)
            .field("running", &self.session.is_some())
            .finish_non_exhaustive()
    }
}

/// Images through the worker and the pixel bytes copied on their way (zero when shared memory carries
/// them both ways).
#[derive(Debug, Default, Clone, Copy)]
struct ImageStats {
    images: u64,
    copied_bytes: u64,
}

impl PythonComponent {
    pub(crate) fn new(spec: Arc<ComponentSpec>) -> Self {
        PythonComponent {
            spec,
            session: None,
            stats: ImageStats::default(),
            python_status: None,
            status_throttle: Throttle::default(),
            reload_error: None,
        }
    }

    /// Sends a command to the worker and serves its requests until it answers.
    fn command(&mut self, ctx: &mut Context, phase: Phase, body: &[u8]) -> ComponentResult {
        let Some(session) = self.session.as_mut() else {
            return Err(ComponentError::failed(format!(
                "the Python process of '{}' is not running (it failed earlier)",
                ctx.id()
            )));
        };
        let outcome = session.command(
            ctx,
            phase,
            body,
            &mut Served {
                stats: &mut self.stats,
                python_status: &mut self.python_status,
            },
        );
        if session.dead {
            self.session = None;
        }
        self.publish_status(ctx, false);
        outcome
    }

    fn publish_status(&mut self, ctx: &Context, now: bool) {
        if !now && !self.status_throttle.ready(STATUS_PERIOD) {
            return;
        }
        let python = serde_json::json!({
            "pid": self.session.as_ref().map(|s| s.worker.pid),
            "images": self.stats.images,
            "pixels_copied_bytes": self.stats.copied_bytes,
            "reload_error": self.reload_error,
        });
        let status = match self.python_status.clone() {
            Some(serde_json::Value::Object(mut fields)) => {
                fields.insert("python".to_owned(), python);
                serde_json::Value::Object(fields)
            }
            Some(other) => serde_json::json!({ "status": other, "python": python }),
            None => serde_json::json!({ "python": python }),
        };
        ctx.set_status(status);
    }

    /// Starts a worker for `ctx`'s component and waits until it has imported the class.
    fn start_session(&self, ctx: &Context) -> Result<Session, ComponentError> {
        let worker = Worker::start(&self.spec, ctx.id(), Arc::clone(ContextHost::signal(ctx)))
            .map_err(ComponentError::failed)?;
        let mut session = Session::new(worker, self.spec.file.clone());
        let hello = serde_json::json!({
            "protocol": wire::PROTOCOL_VERSION,
            "pid": std::process::id(),
            "pack": self.spec.pack,
            "module": self.spec.file,
            "class": self.spec.class,
            "id": ctx.id(),
            "inputs": ctx.inputs().iter().map(|i| serde_json::json!({"name": i.name(), "connected": i.is_connected()})).collect::<Vec<_>>(),
            "properties": ctx.properties(),
        });
        session.worker.connection.send(b'H', hello.to_string().as_bytes());
        session.flush()?;
        let mut body = Vec::new();
        match session.next_message(ctx, &mut body)? {
            b'R' => Ok(session),
            b'E' => Err(python_failure(Phase::Load, &body, &self.spec.file)),
            other => Err(ComponentError::failed(format!(
                "the Python worker answered its hello with '{}'",
                char::from(other)
            ))),
        }
    }

    /// Replaces the worker by one running the pack's code as it is now: the new one must import before
    /// the old one is ended, so code that does not load leaves the old one running.
    fn reload(&mut self, ctx: &mut Context) -> ComponentResult {
        let file = self.spec.file.display().to_string();
        let fresh = match self.start_session(ctx) {
            Ok(fresh) => fresh,
            Err(ComponentError::Failed(reason)) => {
                tracing::warn!(
                    "{}: {file} changed but does not load; the previous code keeps running. {reason}",
                    ctx.id()
                );
                self.reload_error = reason.lines().next().map(str::to_owned);
                self.publish_status(ctx, true);
                return Ok(());
            }
            Err(flow) => return Err(flow),
        };
        if let Some(old) = self.session.replace(fresh) {
            self.retire(ctx, old);
        }
        tracing::info!("{}: reloaded from {file}", ctx.id());
        self.reload_error = None;
        self.publish_status(ctx, true);
        self.command(ctx, Phase::Birth, &[])
    }

    /// Runs `death` in an old worker and ends it.
    fn retire(&mut self, ctx: &mut Context, old: Session) {
        let current = self.session.replace(old);
        if let Err(ComponentError::Failed(reason)) = self.command(ctx, Phase::Death, &[]) {
            tracing::warn!("{}: death of the previous code failed: {reason}", ctx.id());
        }
        if let Some(mut old) = std::mem::replace(&mut self.session, current) {
            old.quit();
        }
    }
}

impl Component for PythonComponent {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.session = Some(self.start_session(ctx)?);
        self.publish_status(ctx, true);
        self.command(ctx, Phase::Birth, &[])
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self
            .session
            .as_ref()
            .is_some_and(|s| s.worker.watch.take_changed())
        {
            self.reload(ctx)?;
        }
        self.command(ctx, Phase::Core, &[])
    }

    fn death(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.session.is_none() {
            return Ok(());
        }
        let outcome = self.command(ctx, Phase::Death, &[]);
        if let Some(mut session) = self.session.take() {
            session.quit();
        }
        match outcome {
            Err(ComponentError::Stopped | ComponentError::Interrupted) => Ok(()),
            other => other,
        }
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        let body = serde_json::json!({ "name": name, "value": value }).to_string();
        self.command(ctx, Phase::Property, body.as_bytes())
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        let body = serde_json::json!({ "name": name }).to_string();
        self.command(ctx, Phase::Action, body.as_bytes())
    }
}

/// What the worker is asked to run.
#[derive(Debug, Clone, Copy)]
enum Phase {
    Load,
    Birth,
    Core,
    Death,
    Property,
    Action,
}

impl Phase {
    fn kind(self) -> u8 {
        match self {
            Phase::Load => b'H',
            Phase::Birth => b'B',
            Phase::Core => b'C',
            Phase::Death => b'X',
            Phase::Property => b'P',
            Phase::Action => b'A',
        }
    }

    fn name(self) -> &'static str {
        match self {
            Phase::Load => "loading the class",
            Phase::Birth => "birth",
            Phase::Core => "core",
            Phase::Death => "death",
            Phase::Property => "property_changed",
            Phase::Action => "action",
        }
    }
}

/// The failure a worker reported, with its Python traceback.
fn python_failure(phase: Phase, body: &[u8], file: &std::path::Path) -> ComponentError {
    let report: serde_json::Value = serde_json::from_slice(body).unwrap_or_default();
    let message = report["message"].as_str().unwrap_or("an exception");
    let traceback = report["traceback"].as_str().unwrap_or_default();
    // The worker names the file when the fault is in another module of the pack, or in a file that
    // does not compile.
    let file = report["file"]
        .as_str()
        .map_or_else(|| file.display().to_string(), str::to_owned);
    let place = report["line"]
        .as_u64()
        .map_or_else(String::new, |line| format!(" ({file}:{line})"));
    if traceback.is_empty() {
        ComponentError::failed(format!("Python {}{place}: {message}", phase.name()))
    } else {
        ComponentError::failed(format!("Python {}{place}: {message}\n{traceback}", phase.name()))
    }
}

/// What serving a command updates beside the session.
struct Served<'a> {
    stats: &'a mut ImageStats,
    python_status: &'a mut Option<serde_json::Value>,
}

/// One worker process and what the runtime holds for it.
struct Session {
    worker: Worker,
    /// The component's file, to place a traceback's line.
    file: std::path::PathBuf,
    /// Input samples with shared pixels the worker maps, until it releases them.
    held: HashMap<u64, Sample>,
    /// Shared buffers the worker is drawing into.
    allocated: VecDeque<(u64, PixelsMut)>,
    next_handle: u64,
    /// One synchroniser per set of inputs the worker reads together, keeping what it has not matched yet.
    synchronised: Vec<(Vec<usize>, Synchronizer)>,
    any_rotation: usize,
    /// A write the runtime refused: answered at the worker's next request and at the command's end.
    refused_write: Option<ComponentError>,
    /// The worker ended or broke the protocol: the session is dropped after this command.
    dead: bool,
}

impl Session {
    fn new(worker: Worker, file: std::path::PathBuf) -> Self {
        Session {
            worker,
            file,
            held: HashMap::new(),
            allocated: VecDeque::new(),
            next_handle: 1,
            synchronised: Vec::new(),
            any_rotation: 0,
            refused_write: None,
            dead: false,
        }
    }

    fn connection(&mut self) -> &mut Connection {
        &mut self.worker.connection
    }

    fn flush(&mut self) -> ComponentResult {
        self.worker.connection.flush().map_err(|error| {
            self.dead = true;
            ComponentError::failed(format!(
                "the Python process {} (writing to it: {error})",
                self.worker.ending()
            ))
        })
    }

    fn command(
        &mut self,
        ctx: &mut Context,
        phase: Phase,
        body: &[u8],
        served: &mut Served<'_>,
    ) -> ComponentResult {
        self.connection().send(phase.kind(), body);
        self.flush()?;
        let mut message = Vec::new();
        loop {
            let kind = self.next_message(ctx, &mut message)?;
            match kind {
                b'D' => return self.refused_write.take().map_or(Ok(()), Err),
                b'S' => return Err(ComponentError::Stopped),
                b'I' => return Err(ComponentError::Interrupted),
                b'O' => return Err(ComponentError::EndOfStream),
                b'E' => {
                    self.refused_write = None;
                    return Err(python_failure(phase, &message, &self.file));
                }
                request => {
                    if let Err(reason) = self.answer(ctx, request, &message, served) {
                        self.dead = true;
                        return Err(ComponentError::failed(format!(
                            "the Python worker broke the worker protocol: {reason}"
                        )));
                    }
                    self.flush()?;
                }
            }
        }
    }

    /// The worker's next frame. While it runs Python, the thread looks every `POLL_SLICE` whether a stop
    /// was asked; past `STOP_GRACE` after one, the process is ended.
    fn next_message(&mut self, ctx: &Context, body: &mut Vec<u8>) -> Result<u8, ComponentError> {
        let mut stop_seen: Option<Instant> = None;
        loop {
            match self.worker.connection.readable(POLL_SLICE) {
                Ok(true) => {
                    return self.worker.connection.read_frame(body).map_err(|error| {
                        self.dead = true;
                        if error.kind() == std::io::ErrorKind::InvalidData {
                            self.worker.kill();
                            ComponentError::failed(format!(
                                "the Python worker broke the worker protocol: {error}"
                            ))
                        } else {
                            ComponentError::failed(format!("the Python process {}", self.worker.ending()))
                        }
                    });
                }
                Ok(false) => {}
                Err(error) => {
                    self.dead = true;
                    return Err(ComponentError::failed(format!(
                        "cannot read from the Python process: {error}"
                    )));
                }
            }
            if ctx.stop_requested() {
                let since = *stop_seen.get_or_insert_with(Instant::now);
                if since.elapsed() >= STOP_GRACE {
                    self.worker.kill();
                    self.dead = true;
                    tracing::warn!(
                        "{}: the Python code did not return within {} s of the stop (a loop that never reads, \
                         sleeps or checks ctx.stop_requested()); its process was ended",
                        ctx.id(),
                        STOP_GRACE.as_secs()
                    );
                    return Err(ComponentError::Stopped);
                }
            }
        }
    }

    /// Ends the worker politely: it exits when told, or is killed a second later.
    fn quit(&mut self) {
        self.connection().send(b'Q', &[]);
        let _ = self.worker.connection.flush();
        if self.worker.wait_exit(Duration::from_secs(1)).is_none() {
            self.worker.kill();
        }
    }

    /// Answers one request; `Err` when the request itself is malformed.
    fn answer(
        &mut self,
        ctx: &mut Context,
        request: u8,
        body: &[u8],
        served: &mut Served<'_>,
    ) -> Result<(), WireError> {
        let mut fields = Fields::new(body);
        // Requests that want an answer get the refused write's error instead, so the Python code stops there.
        if matches!(request, b'r' | b'y' | b'z' | b'a' | b'u' | b'p')
            && let Some(refused) = self.refused_write.clone()
        {
            self.reply_error(&refused);
            return Ok(());
        }
        match request {
            b'l' => {
                let count = fields.u32("a release")?;
                for _ in 0..count {
                    self.held.remove(&fields.u64("a release")?);
                }
            }
            b'r' | b'y' | b'z' => self.answer_read(ctx, request, &mut fields, served.stats)?,
            b'w' => {
                let output = usize::from(fields.u16("a write")?);
                let has_timestamp = fields.u8("a write")? != 0;
                let timestamp = fields.i64("a write")?;
                let payload = self.written_payload(&mut fields, served.stats)?;
                if self.refused_write.is_none() {
                    let written = match payload {
                        Ok(payload) if has_timestamp => ctx.write_at(output, payload, Timestamp(timestamp)),
                        Ok(payload) => ctx.write(output, payload),
                        Err(unusable) => Err(ComponentError::failed(unusable)),
                    };
                    if let Err(error) = written {
                        let name = ctx.outputs().get(output).map_or("?", |o| o.name());
                        self.refused_write = Some(match error {
                            ComponentError::Failed(reason) => {
                                ComponentError::failed(format!("output '{name}' refused the write: {reason}"))
                            }
                            flow => flow,
                        });
                    }
                }
            }
            b'a' => {
                let length = fields.u64("an allocation")? as usize;
                self.allocate(length);
            }
            b't' => {
                let now = ctx.now().as_nanos();
                self.connection().send(b'T', &now.to_le_bytes());
            }
            b'u' => {
                let deadline = Timestamp(fields.i64("a wait")?);
                let outcome = ctx.wait_until(deadline);
                self.reply_ok_or(&outcome);
            }
            b'p' => {
                let nanos = fields.i64("a sleep")?.max(0) as u64;
                let outcome = ctx.sleep(Duration::from_nanos(nanos));
                self.reply_ok_or(&outcome);
            }
            b'q' => {
                let nanos = fields.i64("a period")?.max(1) as u64;
                ctx.set_period(Duration::from_nanos(nanos));
            }
            b'h' => {
                let stop = u8::from(ctx.stop_requested());
                self.connection().send(b'v', &[stop]);
            }
            b'g' => {
                *served.python_status = Some(serde_json::from_slice(body).map_err(WireError::StatusNotJson)?);
            }
            other => return Err(WireError::UnknownRequest(other)),
        }
        Ok(())
    }

    /// Answers the reads: one input, any of several, several synchronised.
    fn answer_read(
        &mut self,
        ctx: &mut Context,
        request: u8,
        fields: &mut Fields<'_>,
        stats: &mut ImageStats,
    ) -> Result<(), WireError> {
        match request {
            b'r' => {
                let blocking = fields.u8("a read")? == 0;
                let input = usize::from(fields.u16("a read")?);
                let read = if blocking {
                    self.read_blocking(ctx, input).map(Some)
                } else {
                    ctx.try_read(input)
                };
                match read {
                    Ok(Some(sample)) => self.send_sample(b's', Some(0), &sample, stats),
                    Ok(None) => self.connection().send(b'n', &[]),
                    Err(error) => self.reply_error(&error),
                }
            }
            b'y' => {
                let inputs = indices(fields)?;
                match self.read_any(ctx, &inputs) {
                    Ok((position, sample)) => {
                        self.send_sample(b's', Some(position as u16), &sample, stats);
                    }
                    Err(error) => self.reply_error(&error),
                }
            }
            b'z' => {
                let tolerance = fields.i64("a synchronised read")?;
                let inputs = indices(fields)?;
                match self.read_synchronised(ctx, inputs, tolerance) {
                    Ok(samples) => {
                        let start = self.connection().begin_frame(b'm');
                        self.connection()
                            .body()
                            .extend_from_slice(&(samples.len() as u16).to_le_bytes());
                        for sample in &samples {
                            self.append_sample(None, sample, stats);
                        }
                        self.connection().end_frame(start);
                    }
                    Err(error) => self.reply_error(&error),
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn reply_ok_or(&mut self, outcome: &ComponentResult) {
        match outcome {
            Ok(()) => self.connection().send(b'k', &[]),
            Err(error) => self.reply_error(error),
        }
    }

    fn reply_error(&mut self, error: &ComponentError) {
        match error {
            ComponentError::Stopped => self.connection().send(b'x', &[]),
            ComponentError::Interrupted => self.connection().send(b'i', &[]),
            ComponentError::EndOfStream => self.connection().send(b'e', &[]),
            ComponentError::NoData => self.connection().send(b'n', &[]),
            other => {
                let text = other.to_string();
                self.connection().send(b'f', text.as_bytes());
            }
        }
    }

    /// Sleeps until new data, a stop or control request, or the monitor (the worker hung up, the code
    /// changed). Those last two interrupt the worker's read: the command then ends and the next `core`
    /// reloads, or the hang-up is read as the process's end.
    fn wait(&self, ctx: &Context) -> ComponentResult {
        if self.worker.watch.hung_up() || self.worker.watch.changed() {
            return Err(ComponentError::Interrupted);
        }
        ContextHost::wait_from_pack(ctx, true)
    }

    fn read_blocking(&self, ctx: &mut Context, input: usize) -> Result<Sample, ComponentError> {
        loop {
            if let Some(sample) = ctx.try_read(input)? {
                return Ok(sample);
            }
            if ContextHost::is_input_exhausted(ctx, input) {
                return Err(ComponentError::EndOfStream);
            }
            self.wait(ctx)?;
        }
    }

    fn read_any(&mut self, ctx: &mut Context, inputs: &[usize]) -> Result<(usize, Sample), ComponentError> {
        let count = inputs.len();
        if count == 0 {
            return Err(ComponentError::failed("read_any of no input"));
        }
        loop {
            // Start after the input served last time, so a busy input cannot starve the others.
            for step in 0..count {
                let position = (self.any_rotation + step) % count;
                if let Some(sample) = ctx.try_read(inputs[position])? {
                    self.any_rotation = position + 1;
                    return Ok((position, sample));
                }
            }
            let connected: Vec<&usize> = inputs.iter().filter(|i| ctx.is_connected(**i)).collect();
            if !connected.is_empty()
                && connected
                    .iter()
                    .all(|i| ContextHost::is_input_exhausted(ctx, **i))
            {
                return Err(ComponentError::EndOfStream);
            }
            self.wait(ctx)?;
        }
    }

    fn read_synchronised(
        &mut self,
        ctx: &mut Context,
        inputs: Vec<usize>,
        tolerance: i64,
    ) -> Result<Vec<Sample>, ComponentError> {
        let at = if let Some(at) = self.synchronised.iter().position(|(read, _)| *read == inputs) {
            at
        } else {
            let synchronizer = Synchronizer::new(inputs.clone(), Duration::ZERO);
            self.synchronised.push((inputs, synchronizer));
            self.synchronised.len() - 1
        };
        loop {
            let synchronizer = &mut self.synchronised[at].1;
            synchronizer.set_tolerance(Duration::from_nanos(tolerance.max(0) as u64));
            // The SDK's matching, with this session's waiting, which the monitor can interrupt.
            if let Some(samples) = synchronizer.try_read(ctx)? {
                return Ok(samples);
            }
            self.wait(ctx)?;
        }
    }

    /// Appends a sample; its shared pixels are held for the worker under a new handle.
    fn append_sample(&mut self, position: Option<u16>, sample: &Sample, stats: &mut ImageStats) {
        let mut pixels = SentPixels::Inline;
        let mut handle = 0;
        if let Payload::Image(image) = &sample.payload {
            stats.images += 1;
            match image.pixels.shared_reference() {
                Some(reference) => {
                    handle = self.next_handle;
                    self.next_handle += 1;
                    self.held.insert(handle, sample.clone());
                    pixels = SentPixels::Shared {
                        fd: reference.fd,
                        id: reference.id,
                        len: reference.len,
                    };
                }
                None => stats.copied_bytes += image.pixels.len() as u64,
            }
        }
        let out = self.connection().body();
        if let Some(position) = position {
            out.extend_from_slice(&position.to_le_bytes());
        }
        out.extend_from_slice(&sample.timestamp.as_nanos().to_le_bytes());
        out.extend_from_slice(&sample.time_of_issue.as_nanos().to_le_bytes());
        out.extend_from_slice(&sample.sequence.to_le_bytes());
        out.extend_from_slice(&handle.to_le_bytes());
        wire::encode_payload(out, &sample.payload, &pixels);
    }

    fn send_sample(&mut self, kind: u8, position: Option<u16>, sample: &Sample, stats: &mut ImageStats) {
        let start = self.connection().begin_frame(kind);
        self.append_sample(position, sample, stats);
        self.connection().end_frame(start);
    }

    /// A buffer in shared memory for the worker to draw an image into; `fd` -1 when there is none (small
    /// images, or no shared memory): the worker then sends the pixels in its write.
    fn allocate(&mut self, length: usize) {
        let mut answer = [0_u8; 28];
        answer[8..12].copy_from_slice(&(-1_i32).to_le_bytes());
        if length >= SHARED_FROM_BYTES {
            let pixels = PixelsMut::new(length);
            if let Some(reference) = pixels.shared_reference() {
                let handle = self.next_handle;
                self.next_handle += 1;
                answer[0..8].copy_from_slice(&handle.to_le_bytes());
                answer[8..12].copy_from_slice(&reference.fd.to_le_bytes());
                answer[12..20].copy_from_slice(&reference.id.to_le_bytes());
                answer[20..28].copy_from_slice(&reference.len.to_le_bytes());
                if self.allocated.len() == ALLOCATED_KEPT {
                    self.allocated.pop_front();
                }
                self.allocated.push_back((handle, pixels));
            }
        }
        self.connection().send(b'b', &answer);
    }

    /// The payload of a write: `Err` outside when the frame is malformed, `Ok(Err)` when the payload
    /// cannot be made (an image whose geometry does not fit its pixels).
    fn written_payload(
        &mut self,
        fields: &mut Fields<'_>,
        stats: &mut ImageStats,
    ) -> Result<Result<Payload, UnusableImage>, WireError> {
        let image = match wire::decode_payload(fields)? {
            Written::Payload(payload) => return Ok(Ok(payload)),
            Written::Image(image) => image,
        };
        stats.images += 1;
        let pixels: Pixels = match image.pixels {
            ImagePixels::Inline(bytes) => {
                stats.copied_bytes += bytes.len() as u64;
                Pixels::from(bytes)
            }
            ImagePixels::Allocated { handle, copied } => {
                let Some(at) = self.allocated.iter().position(|(h, _)| *h == handle) else {
                    return Ok(Err(UnusableImage::NotAllocated(handle)));
                };
                let Some((_, pixels)) = self.allocated.remove(at) else {
                    return Ok(Err(UnusableImage::BufferLost));
                };
                if copied {
                    stats.copied_bytes += pixels.len() as u64;
                }
                pixels.freeze()
            }
            ImagePixels::Held(handle) => match self.held.get(&handle).map(|s| &s.payload) {
                Some(Payload::Image(held)) => held.pixels.clone(),
                _ => {
                    return Ok(Err(UnusableImage::NoLongerHeld(handle)));
                }
            },
        };
        Ok(
            Image::with_stride(image.width, image.height, image.format, image.stride, pixels)
                .map(Payload::Image)
                .map_err(UnusableImage::Size),
        )
    }
}

/// Why an image a worker wrote cannot be made into a sample: the write is refused, the worker goes on.
#[derive(Debug, thiserror::Error)]
enum UnusableImage {
    /// A handle the runtime never gave, or whose buffer was already written.
    #[error("image buffer {0} is not one the runtime allocated (or was already written)")]
    NotAllocated(u64),
    /// The buffer was found and then could not be taken.
    #[error("image buffer lost")]
    BufferLost,
    /// An input's image released before it was written on.
    #[error("input image {0} is no longer held for this component")]
    NoLongerHeld(u64),
    /// The geometry does not fit the pixels.
    #[error(transparent)]
    Size(#[from] kairos_sdk_core::payload::ImageSizeError),
}

fn indices(fields: &mut Fields<'_>) -> Result<Vec<usize>, WireError> {
    let count = fields.u16("a list of inputs")?;
    (0..count)
        .map(|_| fields.u16("a list of inputs").map(usize::from))
        .collect()
}

//! Live in Foxglove: chosen outputs published, in the schemas recordings use, through the `foxglove`
//! crate's WebSocket server (`kairos serve --foxglove`, or the protocol's `foxglove_publish`).
//!
//! One thread reads the chosen outputs and hands each encoded sample to the server, which queues it per
//! client (bounded, the oldest dropped) and sends it from its own threads. Nothing here waits for a client,
//! so a slow or stuck viewer never slows the diagram. An output is read only while a client subscribes to
//! its channel: until then the channel is advertised (made from the output's first sample, whose payload
//! gives the schema) and nothing is encoded.

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::Context as _;
use foxglove::{PartialMetadata, RawChannel, Schema, WebSocketServerHandle};
use kairos_pack_recording::encode::{encode, schema_for};
use kairos_sdk_core::host::{OutputBuffer, Reader, ReaderConfig};
use kairos_sdk_core::{DataType, ReaderPolicy, RunSignal, Sample};

use super::runtime::Runtime;

/// Where `--foxglove` listens when given no address: Foxglove's own default, on loopback.
pub const DEFAULT_FOXGLOVE_ADDRESS: &str = "127.0.0.1:8765";

/// Messages queued per client before the oldest are dropped. Foxglove's default is 1024; a client that
/// stops reading holds this many of each output's messages, so it stays small enough for images
/// (64 × 0.9 MB for a 640×480 RGB camera) and large enough to ride out a hiccup at IMU rates.
pub const DEFAULT_BACKLOG: usize = 64;

/// How often the publishing thread looks at subscriptions and the deployed diagram when no sample wakes it.
const LOOK_PERIOD: Duration = Duration::from_millis(50);

/// Where the publisher finds outputs: a `kairos serve` runtime, whose diagram may be replaced, or the
/// engine of `kairos run`.
pub trait Outputs: Send + Sync {
    /// Changes whenever the outputs are replaced (a new diagram deployed).
    fn generation(&self) -> u64;
    /// Every output's name (`component.port`).
    fn output_names(&self) -> Vec<String>;
    /// The buffer of `output` (`component.port`).
    fn output(&self, output: &str) -> Option<OutputBuffer>;
}

impl Outputs for Runtime {
    fn generation(&self) -> u64 {
        Runtime::generation(self)
    }

    fn output_names(&self) -> Vec<String> {
        Runtime::output_names(self)
    }

    fn output(&self, output: &str) -> Option<OutputBuffer> {
        let (component, port) = output.rsplit_once('.')?;
        Runtime::output(self, component, port).map(|(buffer, _)| buffer)
    }
}

/// The outputs of one engine, for its whole life (`kairos run`).
#[derive(Debug)]
pub struct EngineOutputs(Vec<OutputBuffer>);

impl EngineOutputs {
    /// Every output of `engine`.
    pub fn of(engine: &kairos_runtime::Engine) -> Self {
        EngineOutputs(
            engine
                .output_names()
                .iter()
                .filter_map(|name| {
                    let (component, port) = name.rsplit_once('.')?;
                    engine.output_buffer(component, port).cloned()
                })
                .collect(),
        )
    }
}

impl Outputs for EngineOutputs {
    fn generation(&self) -> u64 {
        0
    }

    fn output_names(&self) -> Vec<String> {
        self.0.iter().map(|b| b.output().to_owned()).collect()
    }

    fn output(&self, output: &str) -> Option<OutputBuffer> {
        self.0.iter().find(|b| b.output() == output).cloned()
    }
}

/// The first of `wanted` that `existing` (the outputs of a deployed diagram) lacks; none while nothing is
/// deployed, as the outputs are then looked for in whatever is deployed later.
pub fn unknown_output<'w>(
    existing: &[String],
    wanted: impl IntoIterator<Item = &'w String>,
) -> Option<&'w String> {
    if existing.is_empty() {
        return None;
    }
    wanted.into_iter().find(|o| !existing.contains(o))
}

/// Which outputs are published.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Selection {
    /// Every output of the deployed diagram.
    pub all: bool,
    /// These outputs (`camera.image`), when not `all`.
    pub chosen: BTreeSet<String>,
}

impl Selection {
    fn includes(&self, output: &str) -> bool {
        self.all || self.chosen.contains(output)
    }
}

/// The Foxglove server of a `kairos serve`, and the thread that feeds it.
pub struct Foxglove {
    address: SocketAddr,
    selection: Mutex<Selection>,
    /// Bumped when the selection changes, so the thread rebuilds its channels.
    selection_version: AtomicU64,
    wake: Arc<RunSignal>,
    stop: AtomicBool,
    thread: Mutex<Option<JoinHandle<()>>>,
    server: Mutex<Option<WebSocketServerHandle>>,
    /// The server's threads (the crate's own would be shared with whatever else uses it); an `Option` so
    /// that dropping it never blocks, wherever the last reference goes.
    network: Option<tokio::runtime::Runtime>,
}

impl Drop for Foxglove {
    fn drop(&mut self) {
        if let Some(network) = self.network.take() {
            network.shutdown_background();
        }
    }
}

impl std::fmt::Debug for Foxglove {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Foxglove")
            .field("address", &self.address)
            .finish_non_exhaustive()
    }
}

impl Foxglove {
    /// Listens on `address` and publishes `selection` of `outputs`, keeping at most `backlog` messages per
    /// client.
    pub fn start(
        outputs: Arc<dyn Outputs>,
        address: SocketAddr,
        selection: Selection,
        backlog: usize,
    ) -> anyhow::Result<Arc<Foxglove>> {
        let network = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("k:foxglove")
            .enable_all()
            .build()
            .context("cannot start the Foxglove server's thread")?;
        // Clients connect at the front door, which also serves those offering the protocol's former name
        // (`foxglove_door`); the crate's server listens behind it on loopback.
        let door = std::net::TcpListener::bind(address)
            .and_then(|listener| listener.set_nonblocking(true).map(|()| listener))
            .with_context(|| format!("cannot serve Foxglove on {address}"))?;
        let bound = door.local_addr().unwrap_or(address);
        let context = foxglove::Context::new();
        let server = context
            .websocket_server()
            .name(format!("kairos {}", env!("CARGO_PKG_VERSION")))
            .bind("127.0.0.1", 0)
            .message_backlog_size(backlog.max(1))
            .tokio_runtime(network.handle());
        // Started from a thread of its own: the caller may be on the control protocol's async threads,
        // where blocking on another runtime is not allowed.
        let handle = std::thread::scope(|scope| {
            scope
                .spawn(|| network.block_on(server.start()))
                .join()
                .unwrap_or_else(|_| Err(foxglove::FoxgloveError::Unspecified("the start panicked".into())))
        })
        .with_context(|| format!("cannot serve Foxglove on {address}"))?;
        let behind = SocketAddr::from(([127, 0, 0, 1], handle.port()));
        let door = {
            let _entered = network.enter();
            tokio::net::TcpListener::from_std(door)
                .with_context(|| format!("cannot serve Foxglove on {address}"))?
        };
        network.spawn(crate::foxglove_door::serve(door, behind));
        let foxglove = Arc::new(Foxglove {
            address: bound,
            selection: Mutex::new(selection),
            selection_version: AtomicU64::new(0),
            wake: Arc::new(RunSignal::new()),
            stop: AtomicBool::new(false),
            thread: Mutex::new(None),
            server: Mutex::new(Some(handle)),
            network: Some(network),
        });
        let thread = {
            let foxglove = Arc::clone(&foxglove);
            std::thread::Builder::new()
                .name("k:foxglove pub".to_owned())
                .spawn(move || Publisher::new(outputs, context).run(&foxglove))
                .context("cannot start the Foxglove publishing thread")?
        };
        *lock(&foxglove.thread) = Some(thread);
        tracing::info!(
            "Foxglove: serving on ws://{bound} (in Foxglove: Open connection, Foxglove WebSocket)"
        );
        Ok(foxglove)
    }

    /// The address clients connect to (`ws://` and this).
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    /// What is published now.
    pub fn selection(&self) -> Selection {
        lock(&self.selection).clone()
    }

    /// Publishes (`publish`) or stops publishing `outputs`; `existing` lists the deployed diagram's outputs,
    /// so that taking one out of "every output" keeps the others.
    pub fn choose(&self, outputs: &[String], publish: bool, existing: &[String]) -> Selection {
        let mut selection = lock(&self.selection);
        if publish {
            selection.chosen.extend(outputs.iter().cloned());
        } else {
            if selection.all {
                selection.all = false;
                selection.chosen = existing.iter().cloned().collect();
            }
            for output in outputs {
                selection.chosen.remove(output);
            }
        }
        let now = selection.clone();
        drop(selection);
        self.selection_version.fetch_add(1, Ordering::Release);
        self.wake.wake();
        now
    }

    /// What is published, where, and to how many clients, as the control protocol says it.
    pub fn state(&self) -> kairos_protocol::FoxgloveState {
        let selection = self.selection();
        kairos_protocol::FoxgloveState {
            address: Some(format!("ws://{}", self.address)),
            all: selection.all,
            outputs: selection.chosen.into_iter().collect(),
            clients: self.clients(),
        }
    }

    /// How many Foxglove clients are connected.
    pub fn clients(&self) -> usize {
        lock(&self.server)
            .as_ref()
            .map_or(0, WebSocketServerHandle::client_count)
    }

    /// Stops the thread and the server.
    pub fn shutdown(&self) {
        self.stop.store(true, Ordering::Release);
        self.wake.wake();
        if let Some(thread) = lock(&self.thread).take() {
            let _ = thread.join();
        }
        if let Some(server) = lock(&self.server).take() {
            // The handle's shutdown waits on the server's runtime, which is ours: let it finish alone.
            drop(server.stop());
        }
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

/// One published output: its channel once a sample gave its schema, and a reader while someone watches.
struct Published {
    output: String,
    channel: Option<(Arc<RawChannel>, DataType)>,
    reader: Option<Reader>,
    /// Samples of another schema than the channel's, passed over (an output typed `any`).
    mismatched: u64,
}

/// The publishing thread's state.
struct Publisher {
    source: Arc<dyn Outputs>,
    context: Arc<foxglove::Context>,
    outputs: BTreeMap<String, Published>,
    generation: u64,
    selection_version: u64,
    scratch: Vec<u8>,
}

impl Publisher {
    fn new(source: Arc<dyn Outputs>, context: Arc<foxglove::Context>) -> Self {
        Publisher {
            source,
            context,
            outputs: BTreeMap::new(),
            generation: u64::MAX,
            selection_version: u64::MAX,
            scratch: Vec::new(),
        }
    }

    fn run(mut self, foxglove: &Foxglove) {
        foxglove.wake.bind_current_thread();
        while !foxglove.stop.load(Ordering::Acquire) {
            self.follow(foxglove);
            let mut published = self.publish_pending();
            if !published {
                // Armed first, then one more look, so a sample written in between is not slept over.
                foxglove.wake.park();
                published = self.publish_pending();
                if !published {
                    foxglove.wake.park_timeout(LOOK_PERIOD);
                }
                foxglove.wake.disarm();
            }
        }
        self.close_all();
    }

    /// Matches the published outputs to the deployed diagram and the selection, and each output's reader to
    /// whether a client subscribes to its channel.
    fn follow(&mut self, foxglove: &Foxglove) {
        let generation = self.source.generation();
        let version = foxglove.selection_version.load(Ordering::Acquire);
        if generation != self.generation || version != self.selection_version {
            let selection = foxglove.selection();
            let wanted: BTreeSet<String> = self
                .source
                .output_names()
                .into_iter()
                .filter(|o| selection.includes(o))
                .collect();
            if generation != self.generation {
                // A new engine: every buffer is new, and a schema may have changed with the diagram.
                self.close_all();
            }
            self.outputs.retain(|output, published| {
                let keep = wanted.contains(output);
                if !keep && let Some((channel, _)) = &published.channel {
                    channel.close();
                }
                keep
            });
            for output in wanted {
                self.outputs.entry(output.clone()).or_insert(Published {
                    output,
                    channel: None,
                    reader: None,
                    mismatched: 0,
                });
            }
            self.generation = generation;
            self.selection_version = version;
        }
        for published in self.outputs.values_mut() {
            let watched = published
                .channel
                .as_ref()
                .is_none_or(|(channel, _)| channel.has_sinks());
            if watched && published.reader.is_none() {
                // Before a channel exists the newest sample is enough to make it; after, every sample.
                let policy = if published.channel.is_some() {
                    ReaderPolicy::Fifo
                } else {
                    ReaderPolicy::LastOrNext
                };
                published.reader = attach(&*self.source, &published.output, policy, &foxglove.wake);
            } else if !watched && published.reader.is_some() {
                published.reader = None;
            }
        }
    }

    fn close_all(&mut self) {
        for (_, published) in std::mem::take(&mut self.outputs) {
            if let Some((channel, _)) = published.channel {
                channel.close();
            }
        }
    }

    /// Hands every sample waiting to the server; whether there was any.
    fn publish_pending(&mut self) -> bool {
        let mut any = false;
        for published in self.outputs.values_mut() {
            while let Some(sample) = published.reader.as_mut().and_then(Reader::try_read) {
                any = true;
                if published.channel.is_none() {
                    published.channel = advertise(&self.context, &published.output, &sample);
                    // Read from now on only if someone subscribes.
                    published.reader = None;
                    break;
                }
                publish(published, &sample, &mut self.scratch);
            }
        }
        any
    }
}

fn attach(
    outputs: &dyn Outputs,
    output: &str,
    policy: ReaderPolicy,
    wake: &Arc<RunSignal>,
) -> Option<Reader> {
    let buffer = outputs.output(output)?;
    Some(buffer.attach(
        ReaderConfig::new(policy, format!("{output} -> foxglove")),
        Arc::clone(wake),
    ))
}

/// The channel for `output`, in the schema of `sample`'s payload.
fn advertise(
    context: &Arc<foxglove::Context>,
    output: &str,
    sample: &Sample,
) -> Option<(Arc<RawChannel>, DataType)> {
    let spec = schema_for(&sample.payload);
    let schema = (!spec.name.is_empty()).then(|| Schema::new(&spec.name, &spec.encoding, spec.data.clone()));
    match context
        .channel_builder(output)
        .message_encoding(&spec.message_encoding)
        .schema(schema)
        .add_metadata("kairos.type", &sample.payload.data_type().to_string())
        .build_raw()
    {
        Ok(channel) => Some((channel, sample.payload.data_type())),
        Err(error) => {
            tracing::warn!("Foxglove: cannot advertise {output}: {error}");
            None
        }
    }
}

/// Encodes `sample` as a recording would and logs it, stamped with its time of issue as recordings are.
fn publish(published: &mut Published, sample: &Sample, scratch: &mut Vec<u8>) {
    let Some((channel, data_type)) = &published.channel else {
        return;
    };
    if !channel.has_sinks() {
        return;
    }
    if sample.payload.data_type() != *data_type {
        published.mismatched += 1;
        if published.mismatched == 1 {
            tracing::warn!(
                "Foxglove: {} carried a {} after {} samples; such samples are not published",
                published.output,
                sample.payload.data_type(),
                data_type
            );
        }
        return;
    }
    if let Err(error) = encode(&sample.payload, sample.timestamp, &published.output, scratch) {
        tracing::warn!(
            "Foxglove: cannot encode a sample of {}: {error}",
            published.output
        );
        return;
    }
    let log_time = u64::try_from(sample.time_of_issue.as_nanos()).unwrap_or(0);
    channel.log_with_meta(scratch, PartialMetadata::with_log_time(log_time));
}

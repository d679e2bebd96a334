//! `kairos serve`: a headless runtime driven over the control protocol (`kairos_protocol`) by the studio
//! or any WebSocket client, on this machine or across a network.
//!
//! The network side runs on a small tokio runtime of its own; the diagram's components keep their own
//! threads, so clients (slow, flooding, vanishing) never share a thread with a component.

mod auth;
pub mod devices;
mod foxglove;
mod foxglove_door;
pub mod log_tap;
mod runtime;
mod samples;
mod session;
mod shm;
mod spread;

use std::net::{SocketAddr, ToSocketAddrs as _};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{Context as _, bail};
use kairos_protocol::{ErrorCode, ProtocolError, ServerMessage, Token};
use kairos_sdk_core::Registry;
use tokio_tungstenite::tungstenite::Message;

pub use auth::{Access, load_or_create_token};
pub use foxglove::{
    DEFAULT_BACKLOG as DEFAULT_FOXGLOVE_BACKLOG, DEFAULT_FOXGLOVE_ADDRESS, EngineOutputs, Foxglove, Outputs,
    Selection,
};
pub use runtime::Runtime;

/// The address `kairos serve` listens on unless told otherwise.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7400";

/// How the tokens of the hosts a runtime coordinates (a diagram spread over them) travel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum HostTokens {
    /// Over wss://, or over plain ws:// to this machine only.
    #[default]
    Protected,
    /// Over plain ws:// to other machines too: a network the user trusts (`--allow-clear-text-tokens`).
    ClearTextAllowed,
}

/// What `kairos serve` was asked to do.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Where to listen.
    pub listen: String,
    /// The operator token's file (created with a fresh token when missing).
    pub token_file: Option<PathBuf>,
    /// The monitor token's file (created when missing).
    pub monitor_token_file: Option<PathBuf>,
    /// A diagram to deploy at boot.
    pub diagram: Option<PathBuf>,
    /// Start that diagram at boot.
    pub start: bool,
    /// The most clients at once.
    pub max_connections: usize,
    /// Stop when standard input closes (the program that started the runtime ended).
    pub stop_with_stdin: bool,
    /// Remove the token file at exit, and its folder when empty.
    pub temporary_token: bool,
    /// Answer other runtimes' clock exchanges on this UDP address.
    pub clock_master: Option<String>,
    /// Follow the clock master at this UDP address.
    pub clock_slave_of: Option<String>,
    /// Run on the system clock (kept by PTP or chrony), measured against the clock master at this UDP
    /// address, alarming past this bound.
    pub clock_system: Option<(String, std::time::Duration)>,
    /// Serve over TLS with this certificate chain and private key (PEM files).
    pub tls: Option<(PathBuf, PathBuf)>,
    /// Where packs shipped by a deploying machine are written ([`default_shipped_pack_folder`] when
    /// `None`).
    pub shipped_pack_folder: Option<PathBuf>,
    /// How the tokens of the hosts this runtime coordinates travel.
    pub host_tokens: HostTokens,
    /// Publish to Foxglove from boot.
    pub foxglove: Option<FoxgloveOptions>,
    /// Messages queued per Foxglove client before the oldest are dropped (also for a server started later
    /// by `foxglove_publish`).
    pub foxglove_backlog: usize,
}

/// `--foxglove`: where, and what.
#[derive(Debug, Clone)]
pub struct FoxgloveOptions {
    /// Where to listen (`127.0.0.1:8765`).
    pub address: String,
    /// What to publish.
    pub selection: Selection,
    /// Listening off loopback was asked for explicitly (Foxglove's protocol carries no token).
    pub open_to_network: bool,
    /// Messages queued per client before the oldest are dropped.
    pub backlog: usize,
}

/// Where packs shipped here are written unless told otherwise: `$XDG_DATA_HOME/kairos/shipped-packs`, else
/// `~/.local/share/kairos/shipped-packs`, else a folder in the temporary directory. They are loaded when
/// shipped, never at boot: each deployment ships what it needs, so a stale version is never picked up.
pub fn default_shipped_pack_folder() -> PathBuf {
    let data = std::env::var_os("XDG_DATA_HOME")
        .filter(|d| !d.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|home| PathBuf::from(home).join(".local/share")));
    data.map_or_else(
        || std::env::temp_dir().join("kairos-shipped-packs"),
        |d| d.join("kairos/shipped-packs"),
    )
}

/// What every session shares.
pub(crate) struct Shared {
    runtime: Arc<Runtime>,
    access: Access,
    server_name: String,
    shipped_pack_folder: PathBuf,
    /// The Foxglove server, once started (at boot, or by the first `foxglove_publish`).
    foxglove: std::sync::Mutex<Option<Arc<Foxglove>>>,
    foxglove_backlog: usize,
}

impl Shared {
    /// What is published to Foxglove now.
    fn foxglove_state(&self) -> kairos_protocol::FoxgloveState {
        let foxglove = self
            .foxglove
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone();
        foxglove.map_or_else(kairos_protocol::FoxgloveState::default, |f| f.state())
    }

    /// Publishes `outputs` to Foxglove, or stops (`publish` false); the first publication starts a server on
    /// loopback, at Foxglove's usual port when it is free.
    fn foxglove_publish(
        &self,
        outputs: &[String],
        publish: bool,
    ) -> Result<kairos_protocol::FoxgloveState, ProtocolError> {
        let existing = self.runtime.output_names();
        if let Some(unknown) = foxglove::unknown_output(&existing, outputs) {
            return Err(ProtocolError::new(
                ErrorCode::NotFound,
                format!(
                    "no output '{unknown}' in the deployed diagram; its outputs are: {}",
                    existing.join(", ")
                ),
            ));
        }
        let mut slot = self
            .foxglove
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if slot.is_none() {
            if !publish {
                return Ok(kairos_protocol::FoxgloveState::default());
            }
            *slot = Some(self.start_foxglove_on_loopback()?);
        }
        let foxglove = slot
            .clone()
            .ok_or_else(|| ProtocolError::new(ErrorCode::Internal, "no Foxglove server"))?;
        drop(slot);
        foxglove.choose(outputs, publish, &existing);
        tracing::info!(
            "Foxglove: {} {} on ws://{}",
            if publish {
                "publishing"
            } else {
                "no longer publishing"
            },
            outputs.join(", "),
            foxglove.address()
        );
        Ok(foxglove.state())
    }

    fn start_foxglove_on_loopback(&self) -> Result<Arc<Foxglove>, ProtocolError> {
        let usual: SocketAddr = DEFAULT_FOXGLOVE_ADDRESS
            .parse()
            .map_err(|_| ProtocolError::new(ErrorCode::Internal, "the default Foxglove address"))?;
        let start = |address| {
            Foxglove::start(
                Arc::clone(&self.runtime) as Arc<dyn Outputs>,
                address,
                Selection::default(),
                self.foxglove_backlog,
            )
        };
        start(usual)
            .or_else(|_| start(SocketAddr::new(usual.ip(), 0)))
            .map_err(|e| ProtocolError::new(ErrorCode::Internal, format!("{e:#}")))
    }
}

fn token(path: Option<&PathBuf>, what: &str) -> anyhow::Result<Option<Token>> {
    let Some(path) = path else { return Ok(None) };
    let (token, created) = load_or_create_token(path)?;
    if created {
        println!(
            "wrote a new {what} token to {} (readable only by you); clients send it in their hello",
            path.display()
        );
    }
    Ok(Some(token))
}

/// Runs `kairos serve` until Ctrl-C or SIGTERM (or, with `stop_with_stdin`, until standard input closes).
pub fn serve(registry: Registry, options: &ServeOptions) -> anyhow::Result<ExitCode> {
    let scheme = if options.tls.is_some() { "wss" } else { "ws" };
    serve_with(registry, options, |bound| {
        use std::io::Write as _;
        // The one line scripts read to find the port (with --listen HOST:0).
        println!("listening on {scheme}://{bound}");
        let _ = std::io::stdout().flush();
    })
}

/// The address `--listen` names.
fn listen_address(listen: &str) -> anyhow::Result<SocketAddr> {
    listen
        .to_socket_addrs()
        .with_context(|| format!("--listen {listen}: not an address (use HOST:PORT, e.g. {DEFAULT_LISTEN})"))?
        .next()
        .with_context(|| format!("--listen {listen}: the name resolves to no address"))
}

/// Like [`serve`], calling `on_listening` with the bound address once connections are accepted (for
/// embedding a server in another program, such as the benchmarks).
pub fn serve_with(
    registry: Registry,
    options: &ServeOptions,
    on_listening: impl FnOnce(SocketAddr) + Send,
) -> anyhow::Result<ExitCode> {
    let address = listen_address(&options.listen)?;
    let access = access_for(address, options)?;
    let tls = options
        .tls
        .as_ref()
        .map(|(certificate, key)| {
            // Links on a tls/ endpoint listen with the same identity as the control endpoint.
            kairos_pack_link::network::set_identity(certificate, key);
            tls_acceptor(certificate, key)
        })
        .transpose()?;
    let runtime = Runtime::new(registry);
    if options.host_tokens == HostTokens::ClearTextAllowed {
        runtime.allow_clear_text_tokens();
    }
    synchronise_clock(&runtime, options)?;
    if let Some(path) = &options.diagram
        && !deploy_at_boot(&runtime, path, options.start)?
    {
        return Ok(ExitCode::from(1));
    }
    let foxglove = options
        .foxglove
        .as_ref()
        .map(|f| start_foxglove(Arc::clone(&runtime) as Arc<dyn Outputs>, f))
        .transpose()?;
    let shared = Arc::new(Shared {
        foxglove: std::sync::Mutex::new(foxglove.clone()),
        foxglove_backlog: options.foxglove_backlog,
        runtime: Arc::clone(&runtime),
        access,
        server_name: format!("kairos {}", env!("CARGO_PKG_VERSION")),
        shipped_pack_folder: options
            .shipped_pack_folder
            .clone()
            .unwrap_or_else(default_shipped_pack_folder),
    });
    let shared_for_exit = Arc::clone(&shared);
    let network = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("k:net")
        .enable_all()
        .build()
        .context("cannot start the network threads")?;
    let mut stop_rx = stop_signal(options.stop_with_stdin)?;
    let max_connections = options.max_connections.max(1);
    let result: anyhow::Result<()> = network.block_on(async move {
        let listener = tokio::net::TcpListener::bind(address)
            .await
            .with_context(|| format!("cannot listen on {address}"))?;
        let bound = listener.local_addr().context("the listening address")?;
        on_listening(bound);
        tracing::info!(
            "serving on {}://{bound}{}",
            if tls.is_some() { "wss" } else { "ws" },
            if shared.access.requires_token() {
                " (token required)"
            } else {
                " (loopback, no token)"
            }
        );
        let slots = Arc::new(tokio::sync::Semaphore::new(max_connections));
        loop {
            tokio::select! {
                _ = stop_rx.changed() => break,
                accepted = listener.accept() => {
                    let Ok((stream, peer)) = accepted else { continue };
                    let _ = stream.set_nodelay(true);
                    let shared = Arc::clone(&shared);
                    match Arc::clone(&slots).try_acquire_owned() {
                        Ok(slot) => {
                            let tls = tls.clone();
                            tokio::spawn(async move {
                                serve_connection(stream, peer, shared, tls).await;
                                drop(slot);
                            });
                        }
                        Err(_) => {
                            tokio::spawn(refuse_busy(stream, max_connections));
                        }
                    }
                }
            }
        }
        Ok(())
    });
    network.shutdown_timeout(std::time::Duration::from_secs(1));
    if let Some(foxglove) = foxglove_of(&shared_for_exit) {
        foxglove.shutdown();
    }
    runtime.shutdown();
    if options.temporary_token
        && let Some(path) = &options.token_file
    {
        remove_temporary_token(path);
    }
    tracing::info!("stopped");
    result.map(|()| ExitCode::SUCCESS)
}

/// Who may connect: the tokens read or made; refused off loopback without an operator token.
fn access_for(address: SocketAddr, options: &ServeOptions) -> anyhow::Result<Access> {
    let operator = token(options.token_file.as_ref(), "operator")?;
    let monitor = token(options.monitor_token_file.as_ref(), "monitor")?;
    if !address.ip().is_loopback() && operator.is_none() {
        bail!(
            "refusing to listen on {address} without a token: anyone who can reach it could run code on this \
             machine. Give --token-file FILE (a fresh token is written there if FILE does not exist; or make \
             one with `openssl rand -hex 32 > FILE`)"
        );
    }
    Ok(Access::new(operator, monitor))
}

/// `--foxglove`: the server, listening; refused off loopback unless asked for explicitly.
///
/// # Errors
///
/// Not an address, off loopback without `open_to_network`, an output `outputs` lacks, or the address
/// cannot be listened on.
pub fn start_foxglove(outputs: Arc<dyn Outputs>, options: &FoxgloveOptions) -> anyhow::Result<Arc<Foxglove>> {
    let address = options
        .address
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .with_context(|| {
            format!(
                "--foxglove {}: not an address (use HOST:PORT, e.g. {DEFAULT_FOXGLOVE_ADDRESS})",
                options.address
            )
        })?;
    check_foxglove_outputs(&*outputs, &options.selection)?;
    if !address.ip().is_loopback() && !options.open_to_network {
        bail!(
            "refusing to publish to Foxglove on {address}: its protocol carries no token, so anyone who can \
             reach that address would see the published outputs. Keep it on loopback (reach it through an SSH \
             tunnel: ssh -L 8765:127.0.0.1:8765 HOST), or add --foxglove-open-to-network to accept the risk"
        );
    }
    let foxglove = Foxglove::start(outputs, address, options.selection.clone(), options.backlog)?;
    println!("foxglove on ws://{}", foxglove.address());
    Ok(foxglove)
}

/// `--foxglove-output`s that the diagram lacks are refused, naming what it has.
fn check_foxglove_outputs(outputs: &dyn Outputs, selection: &Selection) -> anyhow::Result<()> {
    let existing = outputs.output_names();
    if let Some(unknown) = foxglove::unknown_output(&existing, &selection.chosen) {
        bail!(
            "--foxglove-output {unknown}: no such output in the diagram; its outputs are: {}",
            existing.join(", ")
        );
    }
    Ok(())
}

fn foxglove_of(shared: &Shared) -> Option<Arc<Foxglove>> {
    shared
        .foxglove
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .clone()
}

/// `--diagram` (and `--start`): whether it was deployed (and started); why not is printed.
fn deploy_at_boot(runtime: &Runtime, path: &Path, start: bool) -> anyhow::Result<bool> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    if let Err(error) = runtime.deploy(&text, None, path.parent()) {
        eprintln!("{}: {}", path.display(), error.message);
        return Ok(false);
    }
    if start {
        if let Err(error) = runtime.start(None, false, None) {
            eprintln!("{}: {}", path.display(), error.message);
            return Ok(false);
        }
        tracing::info!("started {}", path.display());
    }
    Ok(true)
}

/// Serves one accepted connection, over TLS when `tls`.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    tls: Option<tokio_rustls::TlsAcceptor>,
) {
    match tls {
        Some(acceptor) => match acceptor.accept(stream).await {
            Ok(stream) => session::run(stream, peer, shared).await,
            Err(e) => tracing::warn!("{peer}: TLS handshake refused: {e}"),
        },
        None => session::run(stream, peer, shared).await,
    }
}

/// The TLS side of `--tls-cert` and `--tls-key`: the certificate chain and key read, or why not.
fn tls_acceptor(cert: &Path, key: &Path) -> anyhow::Result<tokio_rustls::TlsAcceptor> {
    use rustls::pki_types::pem::PemObject as _;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(cert)
        .and_then(Iterator::collect)
        .map_err(|e| anyhow::anyhow!("--tls-cert {}: not a PEM certificate chain: {e}", cert.display()))?;
    anyhow::ensure!(
        !chain.is_empty(),
        "--tls-cert {}: no certificate in the file",
        cert.display()
    );
    let private = PrivateKeyDer::from_pem_file(key)
        .map_err(|e| anyhow::anyhow!("--tls-key {}: not a PEM private key: {e}", key.display()))?;
    let config =
        rustls::ServerConfig::builder_with_provider(Arc::new(rustls::crypto::ring::default_provider()))
            .with_safe_default_protocol_versions()
            .context("TLS protocol versions")?
            .with_no_client_auth()
            .with_single_cert(chain, private)
            .with_context(|| {
                format!(
                    "--tls-cert {} and --tls-key {} do not make a usable pair",
                    cert.display(),
                    key.display()
                )
            })?;
    Ok(tokio_rustls::TlsAcceptor::from(Arc::new(config)))
}

/// What turns true when the server is to stop: Ctrl-C or SIGTERM, and the end of standard input when
/// `with_stdin`.
fn stop_signal(with_stdin: bool) -> anyhow::Result<tokio::sync::watch::Receiver<bool>> {
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    if with_stdin {
        stop_when_stdin_closes(stop_tx.clone())?;
    }
    ctrlc::set_handler(move || {
        let _ = stop_tx.send(true);
    })
    .context("cannot install the Ctrl-C handler")?;
    Ok(stop_rx)
}

/// Sends `stop` once standard input reaches its end. A parent that holds the other end of the pipe closes
/// it however it ends (even SIGKILL), so a runtime started by the studio never outlives it.
fn stop_when_stdin_closes(stop: tokio::sync::watch::Sender<bool>) -> anyhow::Result<()> {
    std::thread::Builder::new()
        .name("k:stdin".to_owned())
        .spawn(move || {
            // Whatever arrives is ignored: only the end matters. A read error ends the wait too, as an
            // input that cannot be read cannot tell when the parent ends.
            let _ = std::io::copy(&mut std::io::stdin().lock(), &mut std::io::sink());
            tracing::info!("standard input closed: stopping");
            let _ = stop.send(true);
        })
        .context("cannot start the thread that watches standard input")?;
    Ok(())
}

/// Removes a token made for one run, and its folder when nothing else is in it.
fn remove_temporary_token(path: &Path) {
    if let Err(error) = std::fs::remove_file(path)
        && error.kind() != std::io::ErrorKind::NotFound
    {
        tracing::warn!("cannot remove the token file {}: {error}", path.display());
    }
    // Only succeeds when empty, which is the point: a folder holding anything else is the user's.
    if let Some(folder) = path.parent() {
        let _ = std::fs::remove_dir(folder);
    }
}

/// Tells a client over the connection limit why it is turned away.
async fn refuse_busy(stream: tokio::net::TcpStream, limit: usize) {
    use futures_util::SinkExt as _;
    let Ok(mut websocket) = tokio_tungstenite::accept_async(stream).await else {
        return;
    };
    let refusal = ServerMessage::error(
        None,
        ProtocolError::new(
            ErrorCode::Busy,
            format!("this runtime already serves {limit} clients; try again later"),
        ),
    );
    if let Some(text) = session::text_of(&refusal) {
        let _ = websocket.send(Message::text(text)).await;
    }
    let _ = websocket.close(None).await;
}

/// `--clock-master`: answer other runtimes' clock exchanges; `--clock-slave-of`: run every diagram deployed
/// here on a clock that follows the master's.
fn synchronise_clock(runtime: &Runtime, options: &ServeOptions) -> anyhow::Result<()> {
    if let Some(bind) = &options.clock_master {
        let bound = kairos_clock_sync::run_master(bind)
            .with_context(|| format!("--clock-master {bind}: cannot answer clock exchanges there"))?;
        tracing::info!("clock master: answering on udp://{bound}");
        runtime.set_clock_master();
    }
    if let Some((master, alarm)) = &options.clock_system {
        let address = master
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .with_context(|| format!("--clock-system-against {master}: not an address (HOST:PORT)"))?;
        let clock = Arc::new(kairos_clock_sync::SystemClock::new(*alarm));
        kairos_clock_sync::run_system_check(address, Arc::clone(&clock))
            .with_context(|| format!("--clock-system-against {master}: cannot open the clock socket"))?;
        runtime.set_clock(clock);
        tracing::info!("running on the system clock, measured against the clock master at udp://{address}");
    }
    if let Some(master) = &options.clock_slave_of {
        let address = master
            .to_socket_addrs()
            .ok()
            .and_then(|mut a| a.next())
            .with_context(|| format!("--clock-slave-of {master}: not an address (HOST:PORT)"))?;
        // A documented test-only setting: a machine whose clock is this far off.
        let shifted = std::env::var("KAIROS_TEST_CLOCK_OFFSET_MS")
            .ok()
            .and_then(|ms| ms.parse::<i64>().ok())
            .unwrap_or(0);
        // And one whose crystal runs this many parts per million fast (slow when negative).
        let drift_ppm = std::env::var("KAIROS_TEST_CLOCK_DRIFT_PPM")
            .ok()
            .and_then(|ppm| ppm.parse::<f64>().ok())
            .unwrap_or(0.0);
        let clock = Arc::new(
            kairos_sdk_core::DisciplinedClock::new(kairos_clock_sync::MASTER_SOURCE)
                .trusting_each_reference()
                .estimating_rate()
                .drifted_by_ppm(drift_ppm)
                .shifted_by(shifted.saturating_mul(1_000_000)),
        );
        kairos_clock_sync::run_slave(address, Arc::clone(&clock))
            .with_context(|| format!("--clock-slave-of {master}: cannot open the clock socket"))?;
        runtime.set_clock(clock);
        tracing::info!("following the clock master at udp://{address}");
    }
    Ok(())
}

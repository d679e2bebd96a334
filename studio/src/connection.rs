//! The runtime the studio drives: the client of its control protocol, the local `kairos serve` the studio
//! may have started, and restarting that one with packs built in the studio. Nothing here waits on the
//! interface's thread: the client connects on its own thread, and a local runtime restarts on one too.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, TryRecvError, channel};

use kairos_protocol::{LogLevel, Token};

use crate::client::RuntimeClient;
use crate::local::{LocalRuntime, LocalStartError};
use crate::session::{Effect, Session};

/// A runtime's address and token, to connect to it again.
#[derive(Debug, Clone)]
pub struct RuntimeAddress {
    /// `ws://HOST:PORT`.
    pub url: String,
    /// Its token (a [`Token`]'s `Debug` never shows it).
    pub token: Token,
}

/// How the studio reaches runtimes on other machines: the certificate to trust for `wss://` addresses, and
/// whether a token may cross the network in clear text (`--certificate`, `--allow-clear-text-tokens`).
#[derive(Debug, Clone, Default)]
pub struct Reach {
    /// The certificate to trust (PEM: the runtime's own, or its authority's).
    pub certificate: Option<PathBuf>,
    /// Send a token over plain `ws://` to another machine.
    pub allow_clear_text_token: bool,
}

impl Reach {
    /// The client's options for a connection with `token`.
    pub fn options(&self, token: Option<Token>) -> kairos_client::ConnectOptions {
        kairos_client::ConnectOptions {
            token,
            certificate: self.certificate.clone(),
            allow_clear_text_token: self.allow_clear_text_token,
            ..kairos_client::ConnectOptions::operator(format!("kairos-studio {}", env!("CARGO_PKG_VERSION")))
        }
    }
}

/// A local runtime being started with packs, on a thread of its own.
#[derive(Debug)]
struct Restart {
    /// The folder whose packs it loads, for the log.
    folder: PathBuf,
    started: Receiver<Result<LocalRuntime, LocalStartError>>,
}

/// The connection to the runtime and the local runtime behind it.
#[derive(Debug, Default)]
pub struct Connection {
    client: Option<RuntimeClient>,
    /// Kept alive as long as the studio: dropping it stops the local runtime.
    local: Option<LocalRuntime>,
    /// The local runtime's address, to go back to it.
    local_address: Option<RuntimeAddress>,
    /// Folders of pack libraries built from the studio, loaded into the local runtime.
    pack_paths: Vec<PathBuf>,
    /// The `kairos` program, which generates components and runs the local runtime.
    pub kairos: Option<PathBuf>,
    restart: Option<Restart>,
    /// How runtimes on other machines are reached.
    pub reach: Reach,
}

/// What the connection calls when an event arrives: one repaint. egui answers an immediate request with two
/// frames (to let things settle) but a delayed one with a single frame, and a millisecond is nothing to a
/// person: half the frames while a diagram runs.
pub fn repaint_once(ctx: &egui::Context) -> impl Fn() + Send + Sync + 'static {
    let ctx = ctx.clone();
    move || ctx.request_repaint_after(std::time::Duration::from_millis(1))
}

impl Connection {
    /// A connection through `client` (none: editing only), to `local` when the studio started it.
    pub fn new(client: Option<RuntimeClient>, local: Option<LocalRuntime>) -> Connection {
        Connection {
            client,
            local_address: local.as_ref().map(|l| RuntimeAddress {
                url: l.url.clone(),
                token: l.token.clone(),
            }),
            pack_paths: local.as_ref().map(|l| l.packs.clone()).unwrap_or_default(),
            local,
            kairos: crate::local::kairos_binary(),
            restart: None,
            reach: Reach::default(),
        }
    }

    /// The client, when there is a runtime.
    pub fn client(&self) -> Option<&RuntimeClient> {
        self.client.as_ref()
    }

    /// The local runtime's address, when the studio started one.
    pub fn local_address(&self) -> Option<&RuntimeAddress> {
        self.local_address.as_ref()
    }

    /// Drops the current connection and connects to `url` (on the client's thread: this returns at once).
    pub fn connect(
        &mut self,
        ctx: &egui::Context,
        session: &mut Session,
        url: &str,
        token: Option<Token>,
        certificate: Option<PathBuf>,
        label: String,
    ) {
        let mut options = self.reach.options(token);
        // A certificate named for this address goes before the one given on the command line.
        if certificate.is_some() {
            options.certificate = certificate;
        }
        self.client = Some(RuntimeClient::connect_with(url, options, repaint_once(ctx)));
        session.connecting(label, url);
    }

    /// Connects to the local runtime again.
    pub fn use_local(&mut self, ctx: &egui::Context, session: &mut Session) {
        if let Some(address) = self.local_address.clone() {
            self.connect(
                ctx,
                session,
                &address.url,
                Some(address.token),
                None,
                format!("local runtime {}", address.url),
            );
        }
    }

    /// Hands what arrived to the session, and says what was dropped.
    pub fn poll(&mut self, session: &mut Session) {
        let Some(client) = &self.client else { return };
        for event in client.poll() {
            session.handle(event);
        }
        session.report_dropped(client.dropped());
    }

    /// Does what the session asked of the connection.
    pub fn carry_out(&mut self, session: &mut Session) {
        let effects = session.take_effects();
        let Some(client) = &mut self.client else { return };
        for effect in effects {
            match effect {
                Effect::Send(request) => client.send(&request),
                Effect::ReadShared(services) => {
                    if let Err(error) = client.receive_shared(services) {
                        session.handle(crate::client::ClientEvent::SharedMemory(Err(error)));
                    }
                }
            }
        }
    }

    /// Restarts the local runtime with the pack libraries in `folder` too (on a thread of its own), and
    /// reconnects to it once it listens ([`Connection::poll_restart`]).
    pub fn load_pack(&mut self, ctx: &egui::Context, session: &mut Session, folder: &Path) {
        if self.local_address.is_none() {
            session.note(
                LogLevel::Warn,
                format!(
                    "built {}; the studio drives a remote runtime: copy the library to that machine's pack path",
                    folder.display()
                ),
            );
            return;
        }
        let Some(binary) = self.kairos.clone() else {
            session.note(
                LogLevel::Error,
                format!(
                    "built {}, but there is no `kairos` program to restart the local runtime with it",
                    folder.display()
                ),
            );
            return;
        };
        if !self.pack_paths.iter().any(|p| p == folder) {
            self.pack_paths.push(folder.to_path_buf());
        }
        let (sender, started) = channel();
        let (packs, waker) = (self.pack_paths.clone(), ctx.clone());
        let spawned = std::thread::Builder::new()
            .name("studio:restart".to_owned())
            .spawn(move || {
                // The studio may have closed meanwhile: then nobody needs the runtime.
                let _ = sender.send(LocalRuntime::start_with_packs(&binary, &packs));
                waker.request_repaint();
            });
        match spawned {
            Ok(_) => {
                session.note(
                    LogLevel::Info,
                    format!(
                        "restarting the local runtime with the packs in {}",
                        folder.display()
                    ),
                );
                self.restart = Some(Restart {
                    folder: folder.to_path_buf(),
                    started,
                });
            }
            Err(error) => session.note(
                LogLevel::Error,
                format!("cannot start a thread to restart the local runtime: {error}"),
            ),
        }
    }

    /// Once a restarted local runtime listens, connects to it in place of the old one.
    pub fn poll_restart(&mut self, ctx: &egui::Context, session: &mut Session) {
        let Some(restart) = &self.restart else { return };
        let result = match restart.started.try_recv() {
            Ok(result) => result,
            Err(TryRecvError::Empty) => return,
            Err(TryRecvError::Disconnected) => Err(LocalStartError::RestartThreadEnded),
        };
        let Some(restart) = self.restart.take() else {
            return;
        };
        match result {
            Ok(local) => {
                let address = RuntimeAddress {
                    url: local.url.clone(),
                    token: local.token.clone(),
                };
                self.local_address = Some(address);
                self.local = Some(local);
                self.use_local(ctx, session);
                session.succeeded(format!("loaded the packs in {}", restart.folder.display()));
            }
            Err(error) => session.note(LogLevel::Error, error.to_string()),
        }
    }
}

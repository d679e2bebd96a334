//! The local runtime the studio starts when it is not told to connect elsewhere: `kairos serve` on loopback,
//! a free port, a fresh token, stopped with the studio.

use std::io::{BufRead as _, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

/// Whether the user said the network is trusted (`--allow-clear-text-tokens`): the local runtimes started
/// then send the tokens of the hosts they coordinate over plain ws:// too. One answer for the whole
/// process, as the command line gives it.
static NETWORK_TRUSTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Says the network is trusted: tokens may cross it over plain ws:// (see [`NETWORK_TRUSTED`]).
pub fn trust_the_network() {
    NETWORK_TRUSTED.store(true, std::sync::atomic::Ordering::Release);
}

/// A `kairos serve` child process.
#[derive(Debug)]
pub struct LocalRuntime {
    child: Child,
    /// The write end of the runtime's standard input: it closes however the studio ends (even SIGKILL),
    /// and the runtime, started with `--stop-with-stdin`, stops then and removes its token.
    _lifeline: std::process::ChildStdin,
    /// Its address (`ws://127.0.0.1:PORT`).
    pub url: String,
    /// Its token (whose `Debug` does not show it).
    pub token: kairos_protocol::Token,
    /// The folders it loads packs from besides its own.
    pub packs: Vec<PathBuf>,
    folder: PathBuf,
}

impl Drop for LocalRuntime {
    fn drop(&mut self) {
        // Best effort, with nobody left to tell: the runtime may have ended already, and a folder left in
        // the temporary directory holds only a token that no runtime accepts any more.
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

/// Where the `kairos` binary is: beside the studio's own executable, else on `PATH`.
pub fn kairos_binary() -> Option<PathBuf> {
    let beside = std::env::current_exe().ok()?.parent()?.join("kairos");
    if beside.is_file() {
        return Some(beside);
    }
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|folder| folder.join("kairos"))
            .find(|candidate| candidate.is_file())
    })
}

/// Why the studio's own runtime did not start: the studio runs on without one, and says this.
#[derive(Debug, thiserror::Error)]
pub enum LocalStartError {
    /// No `kairos` binary beside the studio or on the PATH.
    #[error(
        "cannot find the `kairos` runtime beside the studio or on PATH; build it with `cargo build --release`"
    )]
    NoBinary,
    /// The runtime's private folder could not be made.
    #[error("cannot create {}: {source}", .folder.display())]
    Folder {
        /// The folder.
        folder: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The binary would not start.
    #[error("cannot start {}: {source}", .binary.display())]
    Spawn {
        /// The binary.
        binary: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Its pipes were not made.
    #[error("no {0} the runtime")]
    NoPipe(&'static str),
    /// It exited before saying where it listens.
    #[error("{} stopped before listening", .0.display())]
    StoppedEarly(PathBuf),
    /// Without the thread that forwards its output, the runtime would stall on a full pipe.
    #[error("cannot start a thread for the runtime's output: {0}")]
    OutputThread(#[source] std::io::Error),
    /// Its token file could not be read.
    #[error("cannot read the runtime's token: {0}")]
    Token(#[source] std::io::Error),
    /// The thread starting it ended without a word (it panicked).
    #[error("the thread restarting the local runtime ended")]
    RestartThreadEnded,
}

impl LocalRuntime {
    /// The file holding its token (private to this user).
    pub fn token_file(&self) -> PathBuf {
        self.folder.join("token")
    }

    /// Starts `kairos serve` and waits until it listens.
    pub fn start() -> Result<LocalRuntime, LocalStartError> {
        Self::start_for(None)
    }

    /// Starts `kairos serve` for `diagram`: with the `packs/` folder beside it, as `kairos run` finds it.
    pub fn start_for(diagram: Option<&std::path::Path>) -> Result<LocalRuntime, LocalStartError> {
        let binary = kairos_binary().ok_or(LocalStartError::NoBinary)?;
        let beside: Vec<PathBuf> = diagram
            .and_then(std::path::Path::parent)
            .map(|folder| folder.join("packs"))
            .filter(|packs| packs.is_dir())
            .into_iter()
            .collect();
        Self::start_with_packs(&binary, &beside)
    }

    /// Starts `binary serve` (a `kairos` at a known place) and waits until it listens.
    pub fn start_binary(binary: &std::path::Path) -> Result<LocalRuntime, LocalStartError> {
        Self::start_with_packs(binary, &[])
    }

    /// Starts `binary serve` loading the pack libraries in `packs` too, and waits until it listens.
    /// Told to [`trust_the_network`], it sends the tokens of the hosts it coordinates over plain ws://.
    pub fn start_with_packs(
        binary: &std::path::Path,
        packs: &[PathBuf],
    ) -> Result<LocalRuntime, LocalStartError> {
        // One folder per runtime started, so two in one process never share a token file.
        static STARTED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let serial = STARTED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let folder = std::env::temp_dir().join(format!("kairos-studio-{}-{serial}", std::process::id()));
        if let Err(source) = std::fs::create_dir_all(&folder) {
            return Err(LocalStartError::Folder { folder, source });
        }
        let token_file = folder.join("token");
        // A token file from an earlier runtime of the same process id; none is the usual case.
        let _ = std::fs::remove_file(&token_file);
        let mut command = Command::new(binary);
        for pack in packs {
            command.arg("--pack-path").arg(pack);
        }
        let mut child = command
            .args([
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--stop-with-stdin",
                "--temporary-token",
                "--token-file",
            ])
            .arg(&token_file)
            .args(
                NETWORK_TRUSTED
                    .load(std::sync::atomic::Ordering::Acquire)
                    .then_some("--allow-clear-text-tokens"),
            )
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|source| LocalStartError::Spawn {
                binary: binary.to_owned(),
                source,
            })?;
        let lifeline = child.stdin.take().ok_or(LocalStartError::NoPipe("input to"))?;
        let stdout = child
            .stdout
            .take()
            .ok_or(LocalStartError::NoPipe("output from"))?;
        let mut lines = BufReader::new(stdout).lines();
        let url = loop {
            let Some(Ok(line)) = lines.next() else {
                let _ = child.kill();
                return Err(LocalStartError::StoppedEarly(binary.to_owned()));
            };
            if let Some(url) = line.strip_prefix("listening on ") {
                break url.to_owned();
            }
        };
        // Its console output (core.console) keeps flowing; let it go to ours. Without the thread the output
        // would fill the pipe and stall the runtime, so failing to start it fails the start.
        if let Err(error) = std::thread::Builder::new()
            .name("studio:runtime-out".to_owned())
            .spawn(move || {
                for line in lines.map_while(Result::ok) {
                    println!("{line}");
                }
            })
        {
            let _ = child.kill();
            return Err(LocalStartError::OutputThread(error));
        }
        let token = kairos_protocol::Token::new(
            std::fs::read_to_string(&token_file)
                .map_err(LocalStartError::Token)?
                .trim(),
        );
        Ok(LocalRuntime {
            child,
            _lifeline: lifeline,
            url,
            token,
            packs: packs.to_vec(),
            folder,
        })
    }
}

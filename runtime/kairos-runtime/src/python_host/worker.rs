//! A component's Python process: started with its socket as standard input, its output and errors
//! logged line by line, and watched by a monitor thread that wakes the component when the process hangs
//! up (it ended or was killed) or when one of the pack's `.py` files changes.

use std::collections::VecDeque;
use std::io::{BufRead as _, BufReader};
use std::os::fd::{AsFd as _, OwnedFd};
use std::os::unix::net::UnixStream;
use std::os::unix::process::CommandExt as _;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use kairos_sdk_core::RunSignal;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::inotify::{AddWatchFlags, InitFlags, Inotify};

use super::ComponentSpec;
use super::sdk::python_path;
use super::wire::Connection;

/// Lines of the process's standard error kept to explain how it ended.
const STDERR_LINES_KEPT: usize = 20;
/// Editors write a file in several steps: a reload waits this long after the last change.
const RELOAD_SETTLE: Duration = Duration::from_millis(150);

/// What the monitor found, read by the component between requests.
#[derive(Debug, Default)]
pub struct Watch {
    hung_up: AtomicBool,
    changed: AtomicBool,
}

impl Watch {
    /// Whether the process closed its socket (it ended).
    pub fn hung_up(&self) -> bool {
        self.hung_up.load(Ordering::Acquire)
    }

    /// Whether a `.py` file of the pack changed since the last call.
    pub fn take_changed(&self) -> bool {
        self.changed.swap(false, Ordering::AcqRel)
    }

    pub fn changed(&self) -> bool {
        self.changed.load(Ordering::Acquire)
    }
}

/// Starts `command` so that the kernel kills the child when this process ends, however it ends (`kill -9`
/// included): no worker outlives its runtime, spinning in Python or not.
///
/// `PR_SET_PDEATHSIG` fires when the *thread* that forked the child ends, so every worker is forked by
/// one thread that lives as long as the process, never by a component's or a request's thread, which
/// may end long before the worker should.
fn spawn_ended_with_this_process(command: Command) -> std::io::Result<Child> {
    type Request = (Command, std::sync::mpsc::Sender<std::io::Result<Child>>);
    static SPAWNER: std::sync::OnceLock<Mutex<std::sync::mpsc::Sender<Request>>> = std::sync::OnceLock::new();
    let spawner = SPAWNER.get_or_init(|| {
        let (requests, incoming) = std::sync::mpsc::channel::<Request>();
        let started = std::thread::Builder::new()
            .name("k:python-spawner".to_owned())
            .spawn(move || {
                for (mut command, answer) in incoming {
                    let _ = answer.send(spawn_with_death_signal(&mut command));
                }
            });
        if let Err(error) = started {
            tracing::warn!("cannot start the thread that starts Python workers: {error}");
        }
        Mutex::new(requests)
    });
    let (answer, answered) = std::sync::mpsc::channel();
    spawner
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .send((command, answer))
        .map_err(|_| std::io::Error::other("the thread that starts Python workers is gone"))?;
    answered
        .recv()
        .map_err(|_| std::io::Error::other("the thread that starts Python workers is gone"))?
}

/// Spawns `command` with SIGKILL as its parent-death signal; refused if the parent died before the
/// signal was set (the child would then never get it).
#[allow(
    unsafe_code,
    reason = "pre_exec runs between fork and exec, where only async-signal-safe calls are allowed: \
              prctl and getppid are"
)]
fn spawn_with_death_signal(command: &mut Command) -> std::io::Result<Child> {
    let parent = nix::unistd::Pid::this();
    // SAFETY: the closure calls prctl(2) and getppid(2) only, both async-signal-safe, and allocates
    // nothing.
    unsafe {
        command.pre_exec(move || {
            nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL)?;
            if nix::unistd::getppid() != parent {
                // The runtime ended while its worker started (no allocation here: an OS error code).
                return Err(nix::errno::Errno::ESRCH.into());
            }
            Ok(())
        });
    }
    command.spawn()
}

/// Why a worker could not be started: the component fails at its birth with this.
#[derive(Debug, thiserror::Error)]
pub enum WorkerStartError {
    /// The socket the runtime and the worker talk over.
    #[error("cannot make the worker's socket: {0}")]
    Socket(#[source] std::io::Error),
    /// The interpreter would not start (moved, not executable, out of processes).
    #[error("cannot start the Python interpreter {}: {source}", .interpreter.display())]
    Interpreter {
        interpreter: std::path::PathBuf,
        source: std::io::Error,
    },
    /// Without a thread draining its output the worker would block at its first long print.
    #[error("cannot start the thread that logs the worker's output: {0}")]
    LogThread(#[source] std::io::Error),
    /// The socket that ends the monitor thread.
    #[error("cannot make the monitor's socket: {0}")]
    MonitorSocket(#[source] std::io::Error),
    /// The monitor's copy of the worker's socket, on which it sees the worker hang up.
    #[error("cannot watch the worker's socket: {0}")]
    WatchSocket(#[source] std::io::Error),
    /// The thread that wakes the component when the worker dies or a file changes.
    #[error("cannot start the worker's monitor: {0}")]
    MonitorThread(#[source] std::io::Error),
    /// The socket could not be set up for framed reads.
    #[error("cannot use the worker's socket: {0}")]
    Connection(#[source] std::io::Error),
}

/// A running worker process.
#[derive(Debug)]
pub struct Worker {
    child: Child,
    pub connection: Connection,
    pub watch: Arc<Watch>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    /// Dropping it ends the monitor thread.
    monitor_quit: Option<UnixStream>,
    monitor: Option<JoinHandle<()>>,
    pub pid: u32,
}

impl Worker {
    /// Starts the worker of component `id` and its monitor, which wakes `signal`.
    pub fn start(spec: &ComponentSpec, id: &str, signal: Arc<RunSignal>) -> Result<Worker, WorkerStartError> {
        let (ours, theirs) = UnixStream::pair().map_err(WorkerStartError::Socket)?;
        let mut command = Command::new(&spec.interpreter);
        command
            .args(["-m", "kairos_sdk.worker", "--component", id])
            // A group of its own: Ctrl-C in the terminal (sent to the whole foreground group) reaches
            // the runtime, which stops the worker in order, and never kills the worker under it.
            .process_group(0)
            .current_dir(&spec.folder)
            .env("PYTHONPATH", python_path(&spec.sdk))
            // Lines printed by the component reach the log as they are printed.
            .env("PYTHONUNBUFFERED", "1")
            .stdin(Stdio::from(OwnedFd::from(theirs)))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child =
            spawn_ended_with_this_process(command).map_err(|source| WorkerStartError::Interpreter {
                interpreter: spec.interpreter.clone(),
                source,
            })?;
        let pid = child.id();
        let stderr_tail = Arc::new(Mutex::new(VecDeque::new()));
        // A pipe nobody drains would block the worker at its first long print: without the thread that
        // reads it, the worker is not kept.
        let mut logging = Ok(());
        if let Some(stdout) = child.stdout.take() {
            let id = id.to_owned();
            logging = std::thread::Builder::new()
                .name(format!("{id} stdout"))
                .spawn(move || log_lines(stdout, &id, None))
                .map(drop);
        }
        if let (Ok(()), Some(stderr)) = (&logging, child.stderr.take()) {
            let id = id.to_owned();
            let tail = Arc::clone(&stderr_tail);
            logging = std::thread::Builder::new()
                .name(format!("{id} stderr"))
                .spawn(move || log_lines(stderr, &id, Some(&tail)))
                .map(drop);
        }
        if let Err(e) = logging {
            let _ = child.kill();
            let _ = child.wait();
            return Err(WorkerStartError::LogThread(e));
        }
        let watch = Arc::new(Watch::default());
        let (quit_ours, quit_theirs) = UnixStream::pair().map_err(WorkerStartError::MonitorSocket)?;
        let hang_up = ours.try_clone().map_err(WorkerStartError::WatchSocket)?;
        let monitor = {
            let watch = Arc::clone(&watch);
            let folder = spec.folder.clone();
            std::thread::Builder::new()
                .name(format!("{id} monitor"))
                .spawn(move || monitor(&hang_up, &quit_theirs, &folder, &watch, &signal))
                .map_err(WorkerStartError::MonitorThread)?
        };
        let connection = Connection::new(ours).map_err(WorkerStartError::Connection)?;
        Ok(Worker {
            child,
            connection,
            watch,
            stderr_tail,
            monitor_quit: Some(quit_ours),
            monitor: Some(monitor),
            pid,
        })
    }

    /// Ends the process now (SIGKILL).
    pub fn kill(&mut self) {
        let _ = self.child.kill();
    }

    /// How the process ended, waiting for it at most `timeout`; `None` if it still runs.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let started = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(status)) => return Some(status),
                Ok(None) if started.elapsed() < timeout => std::thread::sleep(Duration::from_millis(2)),
                _ => return None,
            }
        }
    }

    /// How the process ended, in words, with the last lines it wrote on standard error.
    pub fn ending(&mut self) -> String {
        let status = match self.wait_exit(Duration::from_millis(500)) {
            Some(status) => describe_exit(status),
            None => "closed its connection".to_owned(),
        };
        let tail = self.stderr_tail.lock().unwrap_or_else(PoisonError::into_inner);
        if tail.is_empty() {
            status
        } else {
            let lines: Vec<&str> = tail.iter().map(String::as_str).collect();
            format!("{status}; it wrote:\n{}", lines.join("\n"))
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        if self.wait_exit(Duration::ZERO).is_none() {
            self.kill();
            let _ = self.child.wait();
        }
        drop(self.monitor_quit.take());
        if let Some(monitor) = self.monitor.take() {
            let _ = monitor.join();
        }
    }
}

fn describe_exit(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt as _;
    if let Some(signal) = status.signal() {
        let name = nix::sys::signal::Signal::try_from(signal)
            .map_or_else(|_| format!("signal {signal}"), |s| s.as_str().to_owned());
        format!("was killed by {name}")
    } else {
        format!("exited with status {}", status.code().unwrap_or(-1))
    }
}

/// Logs what the process prints, one record per line, under the component's id.
fn log_lines(pipe: impl std::io::Read, id: &str, tail: Option<&Mutex<VecDeque<String>>>) {
    for line in BufReader::new(pipe).lines() {
        let Ok(line) = line else { break };
        match tail {
            None => tracing::info!("{id}: {line}"),
            Some(tail) => {
                tracing::warn!("{id}: {line}");
                let mut tail = tail.lock().unwrap_or_else(PoisonError::into_inner);
                if tail.len() == STDERR_LINES_KEPT {
                    tail.pop_front();
                }
                tail.push_back(line);
            }
        }
    }
}

/// Waits, without a timer, for the worker to hang up, for a `.py` file of `folder` to change, or to be
/// told to quit; wakes the component for the first two.
fn monitor(socket: &UnixStream, quit: &UnixStream, folder: &Path, watch: &Watch, signal: &RunSignal) {
    let inotify = Inotify::init(InitFlags::IN_CLOEXEC | InitFlags::IN_NONBLOCK).ok();
    if let Some(inotify) = &inotify {
        let flags = AddWatchFlags::IN_CLOSE_WRITE | AddWatchFlags::IN_MOVED_TO | AddWatchFlags::IN_CREATE;
        if let Err(error) = inotify.add_watch(folder, flags) {
            tracing::debug!("not watching {} for changes: {error}", folder.display());
        }
    }
    let mut settle_until: Option<Instant> = None;
    loop {
        let timeout = settle_until.map_or(PollTimeout::NONE, |until| {
            let left = until.saturating_duration_since(Instant::now());
            PollTimeout::from(u16::try_from(left.as_millis()).unwrap_or(u16::MAX))
        });
        let hung_up = watch.hung_up();
        let mut fds = vec![PollFd::new(quit.as_fd(), PollFlags::POLLIN)];
        if !hung_up {
            // No event asked: a hang-up (POLLHUP) is reported whatever is asked, and only that.
            fds.push(PollFd::new(socket.as_fd(), PollFlags::empty()));
        }
        if let Some(inotify) = &inotify {
            fds.push(PollFd::new(inotify.as_fd(), PollFlags::POLLIN));
        }
        match poll(&mut fds, timeout) {
            Ok(_) | Err(nix::errno::Errno::EINTR) => {}
            Err(_) => return,
        }
        let ready = |fd: Option<&PollFd>| fd.and_then(PollFd::revents).is_some_and(|r| !r.is_empty());
        if ready(fds.first()) {
            return;
        }
        let (socket_fd, inotify_fd) = if hung_up {
            (None, fds.get(1))
        } else {
            (fds.get(1), fds.get(2))
        };
        if ready(socket_fd) {
            watch.hung_up.store(true, Ordering::Release);
            signal.wake();
        }
        if ready(inotify_fd)
            && let Some(inotify) = &inotify
        {
            let python_changed = inotify.read_events().unwrap_or_default().iter().any(|event| {
                event
                    .name
                    .as_ref()
                    .is_some_and(|name| super::manifest::is_component_module(name))
            });
            if python_changed {
                settle_until = Some(Instant::now() + RELOAD_SETTLE);
            }
        }
        if settle_until.is_some_and(|until| Instant::now() >= until) {
            settle_until = None;
            watch.changed.store(true, Ordering::Release);
            signal.wake();
        }
        drop(fds);
    }
}

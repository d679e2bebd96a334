//! The real `kairos-studio` binary in a real window, on a virtual X display (Xvfb): what only a running
//! program shows. At rest it draws no frames; killed, it takes its local runtime with it.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::io::{BufRead as _, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// A virtual X display, stopped when dropped.
struct Display {
    server: Child,
    name: String,
}

impl Drop for Display {
    fn drop(&mut self) {
        let _ = self.server.kill();
        let _ = self.server.wait();
    }
}

/// Starts Xvfb on a display number no other server holds: Xvfb picks it and writes it to its standard
/// output (`-displayfd 1`), so tests running at once never share a display.
fn display() -> Display {
    let mut server = Command::new("Xvfb")
        .args([
            "-displayfd",
            "1",
            "-screen",
            "0",
            "1280x900x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|error| {
            panic!(
                "cannot start Xvfb ({error}): these tests need it (Debian package xvfb; .ci/run installs it)"
            )
        });
    let mut line = String::new();
    BufReader::new(server.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let number: u32 = line
        .trim()
        .parse()
        .unwrap_or_else(|_| panic!("Xvfb did not say its display number: {line:?}"));
    Display {
        server,
        name: format!(":{number}"),
    }
}

/// A studio in its own window, the frames it draws read from its standard error as they come.
struct Studio {
    process: Child,
    /// Each frame's time since the studio started, in milliseconds.
    frames: mpsc::Receiver<u64>,
}

impl Drop for Studio {
    fn drop(&mut self) {
        let _ = self.process.kill();
        let _ = self.process.wait();
    }
}

fn studio(display: &Display, arguments: &[&str]) -> Studio {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    let config = tempfile::tempdir().unwrap().keep();
    let mut process = Command::new(env!("CARGO_BIN_EXE_kairos-studio"))
        .args(arguments)
        .current_dir(&examples)
        .env("DISPLAY", &display.name)
        .env_remove("WAYLAND_DISPLAY")
        .env("XDG_CONFIG_HOME", &config)
        .env("KAIROS_STUDIO_TRACE_FRAMES", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = process.stderr.take().unwrap();
    let (sender, frames) = mpsc::channel();
    std::thread::Builder::new()
        .name("window".to_owned())
        .spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                // "studio frame 12 at 3456 ms (what asked for it)"
                let at = line
                    .strip_prefix("studio frame ")
                    .and_then(|rest| rest.split_once(" at "))
                    .and_then(|(_, rest)| rest.split_once(" ms"))
                    .and_then(|(ms, _)| ms.parse::<u64>().ok());
                match at {
                    Some(at) => {
                        if sender.send(at).is_err() {
                            return;
                        }
                    }
                    None => eprintln!("studio: {line}"),
                }
            }
        })
        .expect("starting a thread");
    Studio { process, frames }
}

impl Studio {
    /// Waits (up to `patience`) until a whole `quiet` passes without a frame; false if it never does.
    fn settles(&self, quiet: Duration, patience: Duration) -> bool {
        let started = Instant::now();
        while started.elapsed() < patience {
            match self.frames.recv_timeout(quiet) {
                Err(mpsc::RecvTimeoutError::Timeout) => return true,
                Err(mpsc::RecvTimeoutError::Disconnected) => panic!("the studio ended"),
                Ok(_) => {}
            }
        }
        false
    }

    /// The frames drawn over the next `span`.
    fn frames_over(&self, span: Duration) -> usize {
        let until = Instant::now() + span;
        let mut frames = 0;
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            match self.frames.recv_timeout(left) {
                Ok(_) => frames += 1,
                Err(mpsc::RecvTimeoutError::Timeout) => break,
                Err(mpsc::RecvTimeoutError::Disconnected) => panic!("the studio ended"),
            }
        }
        frames
    }
}

/// The processes whose parent is `parent`.
fn children(parent: u32) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().map_while(Result::ok) {
        let Some(pid) = entry.file_name().to_str().and_then(|n| n.parse::<u32>().ok()) else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // The fields after the command's closing parenthesis: state, then the parent's id.
        let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
        if after.split_whitespace().nth(1) == Some(&parent.to_string()) {
            found.push(pid);
        }
    }
    found
}

/// Whether `pid` still runs (a zombie waiting for its parent to read its status has ended).
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        let state = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next());
        state != Some("Z") && state != Some("X")
    })
}

#[test]
fn at_rest_the_studio_draws_nothing() {
    let display = display();
    for arguments in [&[][..], &["hello.ron"][..]] {
        let studio = studio(&display, arguments);
        assert!(
            studio.frames.recv_timeout(Duration::from_mins(1)).is_ok(),
            "the studio ({arguments:?}) drew no first frame"
        );
        // Connecting to its local runtime and learning its library draw a few frames; then nothing moves.
        assert!(
            studio.settles(Duration::from_secs(1), Duration::from_secs(30)),
            "the studio ({arguments:?}) never stopped drawing"
        );
        let frames = studio.frames_over(Duration::from_secs(3));
        assert_eq!(frames, 0, "frames drawn at rest over 3 s ({arguments:?})");
    }
}

#[test]
fn the_local_runtime_ends_with_the_studio() {
    let display = display();
    for signal in ["KILL", "TERM"] {
        let mut studio = studio(&display, &[]);
        assert!(studio.frames.recv_timeout(Duration::from_mins(1)).is_ok());
        let pid = studio.process.id();
        let runtime = children(pid);
        assert_eq!(runtime.len(), 1, "one local runtime: {runtime:?}");
        let token_folder = std::env::temp_dir().join(format!("kairos-studio-{pid}-0"));
        assert!(token_folder.join("token").is_file(), "{}", token_folder.display());
        let status = Command::new("kill")
            .args([format!("-{signal}"), pid.to_string()])
            .status()
            .unwrap();
        assert!(status.success());
        studio.process.wait().unwrap();
        let killed = Instant::now();
        while alive(runtime[0]) || token_folder.exists() {
            assert!(
                killed.elapsed() < Duration::from_secs(2),
                "2 s after SIG{signal} of the studio, its runtime runs ({}) or its token folder is left ({})",
                alive(runtime[0]),
                token_folder.exists()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// The studio's resident memory, in kilobytes.
fn rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches(" kB").trim().parse().ok())
        .unwrap()
}

#[test]
fn memory_stays_flat_with_the_3d_viewer_open() {
    let display = display();
    let studio = studio(&display, &["sensors.ron", "--view", "lidar.points", "--run"]);
    assert!(studio.frames.recv_timeout(Duration::from_mins(1)).is_ok());
    // Drawing continuously from here: keep the frame channel drained.
    let pid = studio.process.id();
    let drain = |span: Duration| {
        let until = Instant::now() + span;
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            let _ = studio.frames.recv_timeout(left);
        }
    };
    // Warm up: the runtime's first samples, the renderer's pipelines and caches.
    drain(Duration::from_secs(15));
    let (start, at_start) = (Instant::now(), rss_kb(pid));
    drain(Duration::from_mins(1));
    let grown_kb = rss_kb(pid).saturating_sub(at_start);
    let slope = grown_kb as f64 / 1024.0 / start.elapsed().as_secs_f64();
    // The viewers' histories are bounded (a plot's series, a table's rows) and fill within the first
    // minute, about 1 MB in all; a leak per frame or per sample grows by megabytes a second (the 3D view
    // on lavapipe grew 4 MB/s). 0.2 MB/s leaves room for the first and none for the second.
    assert!(
        slope < 0.2,
        "the studio grew {grown_kb} kB in a minute ({slope:.2} MB/s) with the 3D viewer open"
    );
}

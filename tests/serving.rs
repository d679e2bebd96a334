//! Helpers shared by the tests that drive a real `kairos serve`: start one, connect, say hello, call.
#![allow(dead_code, reason = "not every test file uses every helper")]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use serde_json::{Value, json};
use std::io::{BufRead as _, BufReader};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

pub type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

/// A `kairos serve` on a free loopback port, killed when dropped.
pub struct Server {
    pub child: Child,
    pub url: String,
    pub token: String,
    /// What `--foxglove` printed: `ws://127.0.0.1:PORT`.
    pub foxglove: Option<String>,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `N` fresh temporary folders: the runtimes' and the deploying machine's.
pub fn folders<const N: usize>() -> [tempfile::TempDir; N] {
    std::array::from_fn(|_| tempfile::tempdir().unwrap())
}

pub fn serve(dir: &Path, extra: &[&str]) -> Server {
    serve_with_env(dir, extra, &[])
}

pub fn serve_with_env(dir: &Path, extra: &[&str], env: &[(&str, &str)]) -> Server {
    serve_on(dir, "127.0.0.1:0", extra, env)
}

pub fn serve_on(dir: &Path, listen: &str, extra: &[&str], env: &[(&str, &str)]) -> Server {
    serve_in(None, dir, listen, extra, env)
}

/// The `kairos` binary, run in network namespace `namespace` when given (`ip netns exec` execs it, so the
/// child is kairos itself).
fn kairos_in(namespace: Option<&str>) -> Command {
    match namespace {
        Some(namespace) => {
            let mut command = Command::new("ip");
            command.args(["netns", "exec", namespace, env!("CARGO_BIN_EXE_kairos")]);
            command
        }
        None => Command::new(env!("CARGO_BIN_EXE_kairos")),
    }
}

/// What `kairos status` run in `here` prints of `server`, whose token file is in `dir`.
pub fn status_text(here: &Path, server: &Server, dir: &Path) -> String {
    let shown = crate::common::kairos(
        here,
        &[
            "status",
            &server.url,
            "--token-file",
            dir.join("token.txt").to_str().unwrap(),
        ],
    );
    crate::common::text(&shown).0
}

/// `kairos serve` in network namespace `namespace` (`ip netns exec`), or in this one.
pub fn serve_in(
    namespace: Option<&str>,
    dir: &Path,
    listen: &str,
    extra: &[&str],
    env: &[(&str, &str)],
) -> Server {
    let token_file = dir.join("token.txt");
    let mut child = kairos_in(namespace)
        .envs(env.iter().copied())
        .args(["serve", "--listen", listen, "--token-file"])
        .arg(&token_file)
        .arg("--monitor-token-file")
        .arg(dir.join("monitor.txt"))
        .args(extra)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join("serve.log")).unwrap())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut foxglove = None;
    let url = loop {
        let line = lines.next().expect("serve printed its address").unwrap();
        if let Some(url) = line.strip_prefix("listening on ") {
            break url.to_owned();
        }
        if let Some(url) = line.strip_prefix("foxglove on ") {
            foxglove = Some(url.to_owned());
        }
    };
    // Keep draining standard output (the console component prints there) so the server never blocks.
    std::thread::Builder::new()
        .name("serving".to_owned())
        .spawn(move || for _ in lines {})
        .expect("starting a thread");
    let token = std::fs::read_to_string(&token_file).unwrap().trim().to_owned();
    Server {
        child,
        url,
        token,
        foxglove,
    }
}

pub fn connect(server: &Server) -> Socket {
    let (socket, _) = tungstenite::connect(&server.url).unwrap();
    if let MaybeTlsStream::Plain(stream) = socket.get_ref() {
        stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    }
    socket
}

/// Sends `request` and returns the reply with its id, skipping events and sample frames.
pub fn call(socket: &mut Socket, request: &Value) -> Value {
    socket.send(Message::text(request.to_string())).unwrap();
    loop {
        match socket.read().unwrap() {
            Message::Text(text) => {
                let message: Value = serde_json::from_str(text.as_str()).unwrap();
                if message["type"] == "reply" && message["id"] == request["id"] {
                    return message;
                }
            }
            Message::Close(_) => panic!("closed while waiting for {request}"),
            _ => {}
        }
    }
}

pub fn hello(socket: &mut Socket, token: &str, role: &str) -> Value {
    call(
        socket,
        &json!({"id": 1, "type": "hello", "protocol": 1, "client": "test", "token": token, "role": role}),
    )
}

pub fn operator(server: &Server) -> Socket {
    let mut socket = connect(server);
    let reply = hello(&mut socket, &server.token, "operator");
    assert_eq!(reply["ok"], true, "{reply}");
    socket
}

pub fn deploy_and_start(socket: &mut Socket, diagram: &str) {
    let reply = call(socket, &json!({"id": 2, "type": "deploy", "diagram": diagram}));
    assert_eq!(reply["ok"], true, "{reply}");
    let reply = call(socket, &json!({"id": 3, "type": "start"}));
    assert_eq!(reply["ok"], true, "{reply}");
}

pub fn state(socket: &mut Socket) -> String {
    let reply = call(socket, &json!({"id": 99, "type": "status"}));
    reply["result"]["state"].as_str().unwrap().to_owned()
}

/// Tests that time a running diagram take the machine alone: on two cores, servers started by the other
/// tests of this file in parallel took enough CPU to make a 1 kHz diagram miss a third of its ticks.
pub static MACHINE: RwLock<()> = RwLock::new(());

/// Shares the machine with the other tests.
pub fn shared_machine() -> RwLockReadGuard<'static, ()> {
    MACHINE.read().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Has the machine alone while timing.
pub fn whole_machine() -> RwLockWriteGuard<'static, ()> {
    MACHINE.write().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A diagram over two served hosts and this machine: a sine into a CSV file on each.
pub fn two_host_diagram(a: &Server, b: &str) -> String {
    let connection =
        r#"Connection(from: "sine_a.out", to: "csv_a.in1"), Connection(from: "sine_b.out", to: "csv_b.in1")"#;
    format!(
        r#"Diagram(format: 1,
            hosts: {{"a": Host(endpoint: "{}", token_file: "a.token"), "b": Host(endpoint: "{b}", token_file: "b.token")}},
            packs: [],
            components: [
                Component(id: "sine_a", type: "core.sine", host: "a"),
                Component(id: "csv_a", type: "core.csv_writer", host: "a", properties: {{"path": "a.csv"}}),
                Component(id: "sine_b", type: "core.sine", host: "b"),
                Component(id: "csv_b", type: "core.csv_writer", host: "b", properties: {{"path": "b.csv"}}),
                Component(id: "sine_here", type: "core.sine"),
                Component(id: "csv_here", type: "core.csv_writer", properties: {{"path": "here.csv"}}),
            ],
            connections: [{connection}, Connection(from: "sine_here.out", to: "csv_here.in1")])"#,
        a.url
    )
}

pub fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `timestamp → value` of each row of a CSV written by `core.csv_writer`.
pub fn csv_values(path: &Path) -> Vec<(i64, f64)> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .skip(1)
        .filter_map(|row| {
            let fields: Vec<&str> = row.split(',').collect();
            Some((fields.get(1)?.parse().ok()?, fields.last()?.parse().ok()?))
        })
        .collect()
}

/// Waits until `log` (a file being written) holds `text`; the time waited.
pub fn wait_for_log(log: &Path, text: &str, within: Duration) -> Duration {
    let start = Instant::now();
    loop {
        let content = std::fs::read_to_string(log).unwrap_or_default();
        if content.contains(text) {
            return start.elapsed();
        }
        assert!(
            start.elapsed() < within,
            "no {text:?} within {within:?}:\n{content}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Now, in ns since the UNIX epoch, as samples are stamped.
pub fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64
}

/// Waits (30 s at most) until `csv` holds a sample stamped after `since_ns` or `deploying` ends, then stops
/// it with Ctrl-C and checks it ended well: how many samples came after `since_ns`, and its log.
/// Starts `kairos deploy ARGS` in `here`, in network namespace `namespace` when given, its log written to
/// `log`; stop it with [`interrupt`].
pub fn deploy_in_background(namespace: Option<&str>, here: &Path, args: &[&str], log: &Path) -> Child {
    kairos_in(namespace)
        .arg("deploy")
        .args(args)
        .current_dir(here)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap()
}

/// Stops a running `kairos deploy` as Ctrl-C stops it (if it has not ended): how it ended, and its log.
pub fn interrupt(deploying: &mut Child, log: &Path) -> (std::process::ExitStatus, String) {
    if deploying.try_wait().unwrap().is_none() {
        nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(i32::try_from(deploying.id()).unwrap()),
            nix::sys::signal::Signal::SIGINT,
        )
        .unwrap();
    }
    let status = deploying.wait().unwrap();
    (status, std::fs::read_to_string(log).unwrap())
}

pub fn samples_after_then_stop(
    deploying: &mut Child,
    csv: &Path,
    since_ns: i64,
    log: &Path,
) -> (usize, String) {
    let after = || {
        csv_values(csv)
            .iter()
            .filter(|(stamp, _)| *stamp > since_ns)
            .count()
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while after() == 0 && Instant::now() < deadline && deploying.try_wait().unwrap().is_none() {
        std::thread::sleep(Duration::from_millis(100));
    }
    let (status, content) = interrupt(deploying, log);
    assert!(status.success(), "{content}");
    (after(), content)
}

/// The losses `kairos deploy` said at the end, link by link (`link ... : sent S, received R, lost L`).
pub fn final_losses(said: &str) -> Vec<u64> {
    said.lines()
        .filter_map(|line| line.split(", lost ").nth(1))
        .filter_map(|rest| rest.split_whitespace().next()?.parse().ok())
        .collect()
}

/// What came back through a counter's round trip between hosts: the values, in order, each once (asserted);
/// how many of those up to the last are missing; and the final losses `kairos deploy` said, one per link
/// of the two.
pub struct RoundTrip {
    pub values: Vec<f64>,
    pub missing: u64,
    pub losses: Vec<u64>,
}

impl RoundTrip {
    /// Checks `values` (the counter as it came back) and `said` (what `kairos deploy` said).
    pub fn of(values: Vec<f64>, said: &str) -> Self {
        assert!(
            values.windows(2).all(|w| w[1] > w[0]),
            "out of order or repeated\n{said}"
        );
        let missing = values.last().copied().unwrap_or(0.0) as u64 + 1 - values.len() as u64;
        let losses = final_losses(said);
        assert_eq!(losses.len(), 2, "{said}");
        RoundTrip {
            values,
            missing,
            losses,
        }
    }

    /// Every value missing was counted lost on one of the two links; beyond those, at most `beyond`.
    pub fn assert_every_missing_value_counted(&self, beyond: u64, said: &str) {
        let (missing, losses) = (self.missing, &self.losses);
        let counted: u64 = losses.iter().sum();
        eprintln!(
            "{missing} values missing of {}; counted lost, by link: {losses:?}",
            missing + self.values.len() as u64
        );
        assert!(
            (missing..=missing + beyond).contains(&counted),
            "{missing} values missing, {counted} counted lost ({losses:?})\n{said}"
        );
    }
}

//! The studio's connection to a runtime on another machine goes through the one protocol client: a
//! `wss://` runtime is reached with the certificate the user names, and a token never crosses the
//! network in clear text unless the user says so.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::io::{BufRead as _, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::kairos_binary;
use kairos_protocol::Token;
use kairos_studio::client::{ClientEvent, RuntimeClient};
use kairos_studio::connection::Reach;

/// A self-signed certificate for 127.0.0.1 and its key, as `NAME.pem` and `NAME.key` in `dir`; false
/// (saying why) where `openssl` is missing.
fn make_certificate(dir: &Path, name: &str) -> bool {
    let made = Command::new("openssl")
        .args([
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
        ])
        .args(["-nodes", "-days", "2", "-subj", "/CN=kairos test"])
        .args(["-addext", "subjectAltName=IP:127.0.0.1"])
        .args(["-addext", "basicConstraints=critical,CA:FALSE"])
        .arg("-keyout")
        .arg(dir.join(format!("{name}.key")))
        .arg("-out")
        .arg(dir.join(format!("{name}.pem")))
        .stderr(Stdio::null())
        .status();
    match made {
        Ok(status) if status.success() => true,
        other => {
            eprintln!("skipped: openssl could not make a test certificate ({other:?})");
            false
        }
    }
}

/// `kairos serve` over TLS on a free loopback port: the process and its `wss://` address.
fn serve_over_tls(dir: &Path) -> (Child, String) {
    let mut child = Command::new(kairos_binary())
        .args(["serve", "--listen", "127.0.0.1:0", "--token-file"])
        .arg(dir.join("token.txt"))
        .arg("--tls-cert")
        .arg(dir.join("runtime.pem"))
        .arg("--tls-key")
        .arg(dir.join("runtime.key"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let url = loop {
        let line = lines.next().expect("serve printed its address").unwrap();
        if let Some(url) = line.strip_prefix("listening on ") {
            break url.to_owned();
        }
    };
    std::thread::Builder::new()
        .name("serve stdout".to_owned())
        .spawn(move || for _ in lines {})
        .unwrap();
    (child, url)
}

/// How a session began: the runtime's name, or why it ended at once.
#[derive(Debug)]
enum Outcome {
    Connected(String),
    Ended(String),
}

impl Outcome {
    fn ended(self) -> String {
        match self {
            Outcome::Ended(why) => why,
            Outcome::Connected(server) => panic!("connected to {server}"),
        }
    }
}

/// The first event that says whether the session began.
fn outcome(client: &RuntimeClient) -> Outcome {
    let started = Instant::now();
    loop {
        for event in client.poll() {
            match event {
                ClientEvent::Connected(welcome) => return Outcome::Connected(welcome.server),
                ClientEvent::Disconnected(why) => return Outcome::Ended(why),
                _ => {}
            }
        }
        assert!(started.elapsed() < Duration::from_secs(30), "no outcome in 30 s");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn the_studio_reaches_a_runtime_over_tls_with_the_certificate_it_is_given() {
    let dir = tempfile::tempdir().unwrap();
    if !make_certificate(dir.path(), "runtime") {
        return;
    }
    let (mut runtime, url) = serve_over_tls(dir.path());
    assert!(url.starts_with("wss://"), "{url}");
    let token = Token::new(
        std::fs::read_to_string(dir.path().join("token.txt"))
            .unwrap()
            .trim(),
    );

    let trusting = Reach {
        certificate: Some(dir.path().join("runtime.pem")),
        allow_clear_text_token: false,
    };
    let client = RuntimeClient::connect_with(&url, trusting.options(Some(token.clone())), || {});
    let server = match outcome(&client) {
        Outcome::Connected(server) => server,
        Outcome::Ended(why) => panic!("over TLS: {why}"),
    };
    assert!(server.starts_with("kairos"), "{server}");
    drop(client);

    // No certificate named: refused with the studio's own fix.
    let client = RuntimeClient::connect_with(&url, Reach::default().options(Some(token.clone())), || {});
    let why = outcome(&client).ended();
    assert!(
        why.contains("needs the certificate to trust") && why.contains("--certificate"),
        "{why}"
    );

    // Another certificate than the runtime's: the handshake fails, naming the certificate.
    assert!(make_certificate(dir.path(), "other"));
    let other = Reach {
        certificate: Some(dir.path().join("other.pem")),
        allow_clear_text_token: false,
    };
    let client = RuntimeClient::connect_with(&url, other.options(Some(token)), || {});
    let why = outcome(&client).ended();
    assert!(why.contains("certificate"), "{why}");

    let _ = runtime.kill();
    let _ = runtime.wait();
}

#[test]
fn the_studio_sends_no_token_in_clear_text_to_another_machine_unless_told_to() {
    let token = Token::new("0123456789abcdef0123456789abcdef");
    // 192.0.2.1 is a documentation address (TEST-NET-1): off this machine, and nothing answers there.
    let url = "ws://192.0.2.1:7400";
    let client = RuntimeClient::connect_with(url, Reach::default().options(Some(token.clone())), || {});
    let why = outcome(&client).ended();
    assert!(
        why.contains("clear text") && why.contains("wss://") && why.contains("--allow-clear-text-token"),
        "{why}"
    );
    // Told to, the studio tries: what ends it now is the network, not the rule.
    let allowed = Reach {
        certificate: None,
        allow_clear_text_token: true,
    };
    let mut options = allowed.options(Some(token));
    options.wait = Duration::from_millis(300);
    let client = RuntimeClient::connect_with(url, options, || {});
    let why = outcome(&client).ended();
    assert!(
        !why.contains("clear text") && why.contains("unreachable"),
        "{why}"
    );
}

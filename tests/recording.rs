//! Recording to MCAP through the real binary: what goes in comes out (our reader and an independent one),
//! and a recorder killed mid-run leaves every closed chunk readable.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{example, kairos, repo_root, text};

/// Each test runs a diagram with a camera; run them one at a time so timings stay realistic on 2 cores.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn inspect(dir: &Path, file: &Path) -> (Option<i32>, serde_json::Value) {
    let output = kairos(dir, &["inspect", "--json", file.to_str().unwrap()]);
    let (stdout, stderr) = text(&output);
    let json = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stdout}{stderr}"));
    (output.status.code(), json)
}

fn channel<'a>(report: &'a serde_json::Value, topic: &str) -> &'a serde_json::Value {
    report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == topic)
        .unwrap_or_else(|| panic!("no {topic}: {report}"))
}

/// Runs the record example for `duration` into `file`, with extra `--set` overrides.
fn record_for(dir: &Path, file: &Path, duration: &str, overrides: &[&str]) -> std::process::Output {
    let path = format!("recorder.path={}", file.display());
    let mut args = vec![
        "run",
        example_path(),
        "--for",
        duration,
        "--stats",
        "--set",
        &path,
    ];
    for o in overrides {
        args.extend(["--set", o]);
    }
    kairos(dir, &args)
}

/// Starts the record example into `file` with 0.2 s chunks, to be killed.
fn start_recording(dir: &Path, file: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", example_path()])
        .args([
            "--set",
            &format!("recorder.path={}", file.display()),
            "--set",
            "recorder.chunk_period_s=0.2",
        ])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

fn example_path() -> &'static str {
    static PATH: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    PATH.get_or_init(|| example("record").to_str().unwrap().to_owned())
}

#[test]
fn camera_imu_and_gnss_are_recorded_with_their_schemas_and_read_back() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("drive.mcap");
    let output = record_for(dir.path(), &file, "2s", &[]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");

    let (code, report) = inspect(dir.path(), &file);
    assert_eq!(code, Some(0), "{report}");
    assert_eq!(report["complete"], true);
    for (topic, schema, kind, rate) in [
        ("camera.image", "foxglove.RawImage", "image", 30.0),
        ("imu.imu", "kairos.Imu", "imu", 100.0),
        ("imu.pose", "foxglove.PoseInFrame", "pose", 100.0),
        ("gnss.fix", "foxglove.LocationFix", "gnss_fix", 10.0),
    ] {
        let c = channel(&report, topic);
        assert_eq!(
            (c["schema"].as_str(), c["kairos_type"].as_str()),
            (Some(schema), Some(kind)),
            "{c}"
        );
        let messages = c["messages"].as_f64().unwrap();
        assert!(
            messages >= rate * 1.5 && messages <= rate * 2.2,
            "{topic}: {messages} messages in 2 s"
        );
    }
    // Drops are recorded per track, and none happened.
    let drops = &report["metadata"]["kairos.drops"];
    let camera = drops["in1 camera.image"].as_str().unwrap();
    assert!(
        camera.contains("overwritten=0") && camera.contains("skipped=0"),
        "{camera}"
    );
    assert!(
        report["metadata"]["kairos.recording"]["clock"]
            .as_str()
            .unwrap()
            .starts_with("real time")
    );

    // An independent reader (Python `mcap`, CRCs checked, Foxglove schemas decoded with protobuf) agrees.
    let checked = Command::new("python3")
        .arg(repo_root().join("tests/recording/check_mcap.py"))
        .arg(&file)
        .output()
        .expect("python3");
    let (stdout, stderr) = text(&checked);
    assert!(
        checked.status.success(),
        "install the Python packages mcap and mcap-protobuf-support: {stderr}"
    );
    let topics: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    for topic in ["camera.image", "imu.imu", "imu.pose", "gnss.fix"] {
        assert_eq!(
            topics[topic]["count"],
            channel(&report, topic)["messages"],
            "{topic}"
        );
    }
    assert_eq!(topics["camera.image"]["first"]["width"], 320);
    assert_eq!(topics["camera.image"]["first"]["encoding"], "rgb8");
    assert!((topics["gnss.fix"]["first"]["latitude"].as_f64().unwrap() - 48.7167).abs() < 0.01);
}

#[test]
fn a_recorder_killed_mid_run_leaves_every_closed_chunk_readable() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    for attempt in 0..3 {
        let file = dir.path().join(format!("killed{attempt}.mcap"));
        let mut child = start_recording(dir.path(), &file);
        std::thread::sleep(Duration::from_millis(1500 + 200 * attempt));
        child.kill().unwrap();
        child.wait().unwrap();

        let (code, report) = inspect(dir.path(), &file);
        assert_eq!(code, Some(3), "a damaged file is reported: {report}");
        assert_eq!(report["complete"], false);
        assert!(report["damage"].as_str().unwrap().contains("intact"), "{report}");
        // Over a second of closed chunks (0.2 s each): every track has data.
        for topic in ["camera.image", "imu.imu", "gnss.fix"] {
            assert!(
                channel(&report, topic)["messages"].as_u64().unwrap() > 0,
                "{topic} empty after a crash: {report}"
            );
        }
    }
}

#[test]
fn a_truncated_or_foreign_file_is_reported_not_a_crash() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("whole.mcap");
    let output = record_for(dir.path(), &file, "1500ms", &["recorder.chunk_period_s=0.2"]);
    assert!(output.status.success());
    let whole = std::fs::read(&file).unwrap();
    let (_, complete) = inspect(dir.path(), &file);
    let total = complete["messages"].as_u64().unwrap();

    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &whole[..whole.len() * 2 / 3]).unwrap();
    let (code, report) = inspect(dir.path(), &cut);
    assert_eq!(code, Some(3));
    let kept = report["messages"].as_u64().unwrap();
    assert!(kept > 0 && kept < total, "{kept} of {total}");

    let mut flipped = whole.clone();
    let middle = flipped.len() / 2;
    for byte in &mut flipped[middle..middle + 64] {
        *byte ^= 0x5a;
    }
    let damaged = dir.path().join("flipped.mcap");
    std::fs::write(&damaged, &flipped).unwrap();
    let (code, report) = inspect(dir.path(), &damaged);
    assert_eq!(code, Some(3), "{report}");
    assert!(report["messages"].as_u64().unwrap() < total);

    let foreign = dir.path().join("notes.mcap");
    std::fs::write(&foreign, "not a recording").unwrap();
    let output = kairos(dir.path(), &["inspect", foreign.to_str().unwrap()]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert!(stderr.contains("not an MCAP recording"), "{stderr}");
}

#[test]
fn recover_turns_a_crashed_recording_into_a_complete_one() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("crashed.mcap");
    let mut child = start_recording(dir.path(), &file);
    std::thread::sleep(Duration::from_millis(1500));
    child.kill().unwrap();
    child.wait().unwrap();
    let (_, damaged) = inspect(dir.path(), &file);

    let fixed = dir.path().join("fixed.mcap");
    let output = kairos(
        dir.path(),
        &["recover", file.to_str().unwrap(), fixed.to_str().unwrap()],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(stdout.contains("recovered"), "{stdout}");
    let (code, report) = inspect(dir.path(), &fixed);
    assert_eq!(code, Some(0), "{report}");
    assert_eq!(report["complete"], true);
    assert_eq!(
        report["messages"], damaged["messages"],
        "every intact message is kept"
    );
    assert!(
        report["metadata"]["kairos.recording"]["clock"].is_string(),
        "metadata is kept: {report}"
    );
}

#[test]
fn splitting_by_duration_loses_and_repeats_nothing() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("split.mcap");
    let output = record_for(dir.path(), &file, "1800ms", &["recorder.split_duration_s=0.5"]);
    assert!(output.status.success());
    let mut parts: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    parts.sort();
    assert!(parts.len() >= 3, "{parts:?}");
    let mut recorded = 0;
    let mut last_report = serde_json::Value::Null;
    for part in &parts {
        let (code, report) = inspect(dir.path(), part);
        assert_eq!(code, Some(0), "{report}");
        recorded += channel(&report, "imu.imu")["messages"].as_u64().unwrap();
        if part.file_name().is_some_and(|n| n == "split.mcap") {
            continue;
        }
        last_report = report;
    }
    // The drop counters in the last part are cumulative over the run: every sample read was recorded once.
    let drops = last_report["metadata"]["kairos.drops"]["in2 imu.imu"]
        .as_str()
        .unwrap()
        .to_owned();
    let read: u64 = drops
        .split_whitespace()
        .find_map(|f| f.strip_prefix("recorded="))
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(recorded, read, "{drops}");
}

#[test]
fn the_free_space_guard_stops_the_recorder_alone_and_leaves_a_valid_file() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("guarded.mcap");
    let output = record_for(dir.path(), &file, "1500ms", &["recorder.min_free_mb=1000000000"]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("stopped recording") && stderr.contains("guarded.mcap"),
        "{stderr}"
    );
    let camera = stderr.lines().rev().find(|l| l.starts_with("camera ")).unwrap();
    assert!(
        camera.contains("stopped"),
        "the camera kept running until the end: {camera}"
    );
    let (code, report) = inspect(dir.path(), &file);
    assert_eq!(code, Some(0), "the file is closed and valid: {report}");
}

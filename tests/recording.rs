//! Recording to MCAP through the real binary: what goes in comes out (our reader and an independent one),
//! and a recorder killed mid-run leaves every closed chunk readable.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

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

/// Two recordings of 0.6 s made by two runs (so on two runtimes' clocks, neither locked): `car.mcap`
/// and `rsu.mcap` in `dir`.
fn two_runs(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let (car, roadside) = (dir.join("car.mcap"), dir.join("rsu.mcap"));
    for file in [&car, &roadside] {
        let output = record_for(dir, file, "600ms", &[]);
        assert!(output.status.success(), "{}", text(&output).1);
    }
    (car, roadside)
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

/// Whether every track of the recording `file`, being written, has data in a closed chunk.
fn every_track_has_data(dir: &Path, file: &Path) -> bool {
    let output = kairos(dir, &["inspect", "--json", file.to_str().unwrap()]);
    // Not a report yet (no file, or not even its header) is no data yet.
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap_or_default();
    ["camera.image", "imu.imu", "gnss.fix"].iter().all(|topic| {
        report["channels"].as_array().is_some_and(|channels| {
            channels
                .iter()
                .any(|c| c["topic"] == *topic && c["messages"].as_u64().is_some_and(|n| n > 0))
        })
    })
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
        // Never more than the source's rate allows in 2 s; how close to it depends on the machine.
        let messages = c["messages"].as_f64().unwrap();
        assert!(
            messages >= 1.0 && messages <= rate * 2.2,
            "{topic}: {messages} messages in 2 s"
        );
    }
    // Drops are recorded per track: every camera image written is recorded (each one in the file) or
    // counted as dropped. How many were dropped depends on the machine's speed.
    let drops = &report["metadata"]["kairos.drops"];
    let camera = drops["in1 camera.image"].as_str().unwrap();
    let count = |name: &str| -> u64 {
        camera
            .split_whitespace()
            .find_map(|field| field.strip_prefix(name)?.strip_prefix('='))
            .unwrap_or_else(|| panic!("no {name} in {camera}"))
            .parse()
            .unwrap()
    };
    assert_eq!(
        count("written"),
        count("recorded") + count("overwritten") + count("skipped") + count("queued"),
        "{camera}"
    );
    assert_eq!(
        channel(&report, "camera.image")["messages"].as_u64(),
        Some(count("recorded")),
        "{camera}"
    );
    assert!(
        report["metadata"]["kairos.recording"]["clock"]
            .as_str()
            .unwrap()
            .starts_with("real time")
    );
    // The clock's state is in the file: here the machine's own, free-running.
    let clock = &report["metadata"]["kairos.clock"];
    assert_eq!(clock["source"], "this machine", "{clock}");
    assert_eq!(clock["state"], "free", "{clock}");

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
    for attempt in 0..10 {
        let file = dir.path().join(format!("killed{attempt}.mcap"));
        let mut child = start_recording(dir.path(), &file);
        std::thread::sleep(Duration::from_millis(1100 + 70 * attempt));
        // And on until every track has data in a closed chunk (done already on a fast machine).
        let deadline = Instant::now() + Duration::from_secs(30);
        while Instant::now() < deadline && !every_track_has_data(dir.path(), &file) {
            std::thread::sleep(Duration::from_millis(100));
        }
        child.kill().unwrap();
        child.wait().unwrap();

        let (code, report) = inspect(dir.path(), &file);
        assert_eq!(code, Some(3), "a damaged file is reported: {report}");
        assert_eq!(report["complete"], false);
        assert!(report["damage"].as_str().unwrap().contains("intact"), "{report}");
        // The drop counts until the last closed chunk are in the file, though it was never closed.
        let drops = &report["metadata"]["kairos.drops"];
        assert!(
            drops["in1 camera.image"]
                .as_str()
                .is_some_and(|d| d.starts_with("written=")),
            "{report}"
        );
        // Closed chunks (0.2 s each) with data of every track.
        for topic in ["camera.image", "imu.imu", "gnss.fix"] {
            assert!(
                channel(&report, topic)["messages"].as_u64().unwrap() > 0,
                "{topic} empty after a crash: {report}"
            );
        }
        // Every message of every closed chunk decodes, and recovery keeps each one, unchanged.
        let intact = decoded_messages_of_damaged(&file);
        let fixed = dir.path().join(format!("fixed{attempt}.mcap"));
        let output = kairos(
            dir.path(),
            &["recover", file.to_str().unwrap(), fixed.to_str().unwrap()],
        );
        assert!(output.status.success(), "{}", text(&output).1);
        assert!(
            decoded_messages(&fixed) == intact,
            "attempt {attempt}: recovery changed messages"
        );
        let total: usize = intact.values().map(Vec::len).sum();
        assert_eq!(report["messages"].as_u64(), Some(total as u64));
    }
}

#[test]
fn a_truncated_or_foreign_file_is_reported_not_a_crash() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("whole.mcap");
    // 1 MiB chunks, one image each: the middle of the file, flipped below, lies in a chunk's data (message
    // indexes and metadata records carry no checksum in MCAP, so a flip there cannot be seen).
    let output = record_for(
        dir.path(),
        &file,
        "1500ms",
        &["recorder.chunk_period_s=0.2", "recorder.chunk_size_kb=1024"],
    );
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
    let intact = report["messages"].as_u64().unwrap();
    assert!(intact < total);
    let regions = report["damaged_chunks"].as_array().unwrap();
    assert!(!regions.is_empty(), "{report}");
    let left_out: u64 = regions.iter().map(|r| r["messages"].as_u64().unwrap()).sum();
    assert_eq!(
        intact + left_out,
        total,
        "every message is intact or counted as left out: {report}"
    );
    // Recovery leaves the damaged chunks out and keeps every intact one, after them too.
    let fixed = dir.path().join("flipped-fixed.mcap");
    let output = kairos(
        dir.path(),
        &["recover", damaged.to_str().unwrap(), fixed.to_str().unwrap()],
    );
    let (stdout, _) = text(&output);
    assert!(
        stdout.contains("damaged chunk(s)") && stdout.contains("left out with its"),
        "{stdout}"
    );
    let (code, recovered) = inspect(dir.path(), &fixed);
    assert_eq!(code, Some(0), "{recovered}");
    assert_eq!(recovered["messages"].as_u64(), Some(intact));

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

type Decoded = BTreeMap<String, Vec<(u64, u64, kairos_sdk_core::Payload)>>;

/// Every message of `file` decoded, by topic: (publish time, log time, payload), in file order.
fn decoded_messages(file: &Path) -> Decoded {
    let (topics, damage) = read_decoded(file);
    assert!(damage.is_none(), "{damage:?}");
    topics
}

/// Like [`decoded_messages`] for a file damaged at its end: what lies before the damage.
fn decoded_messages_of_damaged(file: &Path) -> Decoded {
    let (topics, damage) = read_decoded(file);
    assert!(damage.is_some(), "a killed recorder's file is incomplete");
    topics
}

fn read_decoded(file: &Path) -> (Decoded, Option<String>) {
    let bytes = std::fs::read(file).unwrap();
    let mut topics: BTreeMap<String, Vec<_>> = BTreeMap::new();
    let damage = kairos_pack_recording::safe_read::read_intact(
        &bytes,
        |message| {
            let decoder = kairos_pack_recording::decode::ChannelDecoder::of(&message.channel);
            let (payload, _) = decoder.decode(&message.data).unwrap();
            topics.entry(message.channel.topic.clone()).or_default().push((
                message.publish_time,
                message.log_time,
                payload,
            ));
        },
        |_| {},
    );
    (topics, damage)
}

/// A player replaying `recording` into a recorder writing `copy`, every link NeverSkipping.
fn replay_into_recorder(recording: &Path, copy: &Path, mode: &str) -> String {
    format!(
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "recording", version: "^0.1")],
    components: [
        Component(id: "player", type: "recording.player", properties: {{"path": "{}", "mode": "{mode}"}}),
        Component(id: "copy", type: "recording.recorder", properties: {{"path": "{}"}}),
    ],
    connections: [
        Connection(from: "player.camera_image", to: "copy.in1", policy: NeverSkipping),
        Connection(from: "player.imu_imu", to: "copy.in2", policy: NeverSkipping),
        Connection(from: "player.gnss_fix", to: "copy.in3", policy: NeverSkipping),
        Connection(from: "player.imu_pose", to: "copy.in4", policy: NeverSkipping),
    ],
)"#,
        recording.display(),
        copy.display()
    )
}

#[test]
fn a_replay_gives_back_what_was_recorded_values_and_both_times() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("drive.mcap");
    assert!(record_for(dir.path(), &file, "2s", &[]).status.success());

    for mode in ["as_fast_as_possible", "real_time"] {
        let copy = dir.path().join(format!("copy-{mode}.mcap"));
        let diagram = dir.path().join("replay.ron");
        std::fs::write(&diagram, replay_into_recorder(&file, &copy, mode)).unwrap();
        let started = Instant::now();
        // No --for: the run ends when the recording does.
        let output = kairos(dir.path(), &["run", diagram.to_str().unwrap()]);
        let (_, stderr) = text(&output);
        assert!(output.status.success(), "{stderr}");
        let elapsed = started.elapsed().as_secs_f64();
        if mode == "real_time" {
            assert!(
                elapsed > 1.8,
                "a 2 s recording replayed in real time took {elapsed:.2} s"
            );
        }

        let original = decoded_messages(&file);
        let replayed = decoded_messages(&copy);
        for (topic, copied) in [
            ("camera.image", "player.camera_image"),
            ("imu.imu", "player.imu_imu"),
            ("imu.pose", "player.imu_pose"),
            ("gnss.fix", "player.gnss_fix"),
        ] {
            let (sent, got) = (&original[topic], &replayed[copied]);
            assert!(!sent.is_empty());
            assert_eq!(sent.len(), got.len(), "{mode}: {topic}");
            assert!(sent == got, "{mode}: {topic} differs after a replay");
        }
    }
}

/// The CSV rows of each input, without the time of issue (when the row's sample was written, which a
/// processing stage sets anew on every run).
fn rows_by_input(csv: &str) -> BTreeMap<String, Vec<String>> {
    let mut rows: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for line in csv.lines().filter(|l| !l.starts_with("input,")) {
        let fields: Vec<&str> = line.split(',').collect();
        let kept: Vec<&str> = fields
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != 2)
            .map(|(_, f)| *f)
            .collect();
        rows.entry(fields[0].to_owned()).or_default().push(kept.join(","));
    }
    rows
}

#[test]
fn two_fast_replays_through_one_diagram_give_identical_outputs() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("drive.mcap");
    assert!(record_for(dir.path(), &file, "1500ms", &[]).status.success());
    let recorded = decoded_messages(&file);
    let diagram = dir.path().join("process.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "recording", version: "^0.1")],
    components: [
        Component(id: "player", type: "recording.player", properties: {{"path": "{}", "mode": "as_fast_as_possible"}}),
        Component(id: "stage", type: "core.delay", properties: {{"delay_ms": 0.5}}),
        Component(id: "csv", type: "core.csv_writer", properties: {{"path": "out.csv"}}),
    ],
    connections: [
        Connection(from: "player.gnss_fix", to: "csv.in1", policy: NeverSkipping),
        Connection(from: "player.imu_imu", to: "stage.in", policy: NeverSkipping),
        Connection(from: "stage.out", to: "csv.in2", policy: NeverSkipping),
        Connection(from: "player.camera_image", to: "csv.in3", policy: NeverSkipping),
    ],
)"#,
            file.display()
        ),
    )
    .unwrap();
    let mut outputs = Vec::new();
    for _ in 0..2 {
        let output = kairos(dir.path(), &["run", diagram.to_str().unwrap()]);
        let (_, stderr) = text(&output);
        assert!(output.status.success(), "{stderr}");
        outputs.push(rows_by_input(
            &std::fs::read_to_string(dir.path().join("out.csv")).unwrap(),
        ));
    }
    assert!(outputs[0] == outputs[1], "two replays differ");
    for (input, topic) in [("in1", "gnss.fix"), ("in2", "imu.imu"), ("in3", "camera.image")] {
        assert_eq!(
            outputs[0][input].len(),
            recorded[topic].len(),
            "every {topic} sample was processed"
        );
    }
}

#[test]
fn a_player_without_its_recording_is_refused_where_the_path_is_given() {
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("replay.ron");
    std::fs::write(
        &diagram,
        "Diagram(\n    format: 1,\n    packs: [Pack(name: \"recording\", version: \"^0.1\")],\n    components: [\n        Component(id: \"player\", type: \"recording.player\", properties: {\"path\": \"missing.mcap\"}),\n    ],\n)\n",
    )
    .unwrap();
    let output = kairos(dir.path(), &["validate", diagram.to_str().unwrap()]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("replay.ron:5:")
            && stderr.contains("'player' (property 'path')")
            && stderr.contains("missing.mcap"),
        "{stderr}"
    );
}

/// Runs `script` (sh) where it may mount a small tmpfs: in a user and mount namespace of its own
/// (`unshare -rm`), or directly when that is refused and we are root. `$KAIROS` is the binary.
fn with_a_small_disk(dir: &Path, script: &str) -> std::process::Output {
    let run = |wrapper: &[&str]| {
        Command::new(wrapper[0])
            .args(&wrapper[1..])
            .args(["sh", "-ec", script])
            .current_dir(dir)
            .env("KAIROS", env!("CARGO_BIN_EXE_kairos"))
            .env("RUST_LOG", "info")
            .output()
    };
    match run(&["unshare", "-rm"]) {
        Ok(output) if output.status.success() => output,
        first => run(&["env"]).unwrap_or_else(|e| {
            panic!("cannot mount a tmpfs: unshare -rm gave {first:?}, and sh failed: {e}")
        }),
    }
}

#[test]
fn a_full_disk_stops_the_recorder_alone_naming_the_file() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let record = example_path();
    // Uncompressed camera frames fill 16 MB in about two seconds. First with the free-space guard
    // (stop at 4 MB free), then without it (min_free_mb = 0: the writes themselves fail).
    let script = format!(
        r#"mkdir -p disk
mount -t tmpfs -o size=16m tmpfs disk
for guard in 4 0; do
  "$KAIROS" run {record} --for 3s --stats --set recorder.path=disk/drive.mcap \
    --set recorder.compression=none --set recorder.min_free_mb=$guard > out-$guard.txt 2> err-$guard.txt || echo $? > code-$guard.txt
  cp disk/drive.mcap copy-$guard.mcap
  rm disk/drive.mcap
done
umount disk"#
    );
    let output = with_a_small_disk(dir.path(), &script);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    for (guard, expected_inspect) in [("4", 0), ("0", 3)] {
        let log = std::fs::read_to_string(dir.path().join(format!("err-{guard}.txt"))).unwrap();
        let code = std::fs::read_to_string(dir.path().join(format!("code-{guard}.txt"))).unwrap_or_default();
        assert_eq!(
            code.trim(),
            "2",
            "min_free_mb={guard}: a failed component is exit code 2\n{log}"
        );
        assert!(
            log.contains("disk/drive.mcap"),
            "min_free_mb={guard}: the error names the file\n{log}"
        );
        if guard == "0" {
            assert!(log.contains("No space left on device"), "{log}");
        } else {
            assert!(log.contains("stopped recording"), "{log}");
        }
        let camera = log.lines().rev().find(|l| l.starts_with("camera ")).unwrap();
        assert!(camera.contains("stopped"), "the camera ran to the end: {camera}");
        // With the guard the file is closed and valid; without it, readable up to the last closed chunk.
        let (code, report) = inspect(dir.path(), &dir.path().join(format!("copy-{guard}.mcap")));
        assert_eq!(code, Some(expected_inspect), "min_free_mb={guard}: {report}");
        assert!(report["messages"].as_u64().unwrap() > 0, "{report}");
    }
}

/// A camera kept in a pre-trigger ring, a trigger every 2 s (from 2 s on), events into `disk/`.
const PRE_TRIGGER_ON_DISK: &str = r#"Diagram(
    format: 1,
    components: [
        Component(id: "camera", type: "sensors.camera", properties: {"width": 160, "height": 120, "rate": 30.0}),
        Component(id: "every_2s", type: "core.counter", properties: {"rate": 0.5}),
        Component(id: "recorder", type: "recording.recorder", properties: {
            "mode": "pre_trigger", "pre_trigger_s": 1.0, "post_trigger_s": 0.5,
            "path": "disk/event.mcap", "compression": "none", "min_free_mb": 0.0,
        }),
    ],
    connections: [
        Connection(from: "camera.image", to: "recorder.in1"),
        Connection(from: "every_2s.out", to: "recorder.trigger"),
    ],
)"#;

#[test]
fn a_disk_filling_during_a_pre_trigger_write_names_the_error_and_keeps_the_ring() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("pretrigger.ron"), PRE_TRIGGER_ON_DISK).unwrap();
    // An 8 MB disk that something else has nearly filled when the first trigger comes (2 s); the space is
    // freed at 3.2 s, before the second (4 s). One second of the camera is 1.7 MB. Then again with the
    // free-space guard at 2 MB, on a disk with 3 MB free: the first event stops cleanly when it passes
    // the guard, the next is refused before it opens a file.
    let script = r#"mkdir -p disk full guarded
mount -t tmpfs -o size=8m tmpfs disk
head -c 7900k /dev/zero > disk/filler
"$KAIROS" run pretrigger.ron --for 7s --stats > out-full.txt 2> err-full.txt &
sleep 3.2
rm disk/filler
wait $! || echo $? > code-full.txt
cp disk/*.mcap full/
rm -f disk/*
head -c 5000k /dev/zero > disk/filler
"$KAIROS" run pretrigger.ron --for 5s --stats --set recorder.min_free_mb=2 > out-guard.txt 2> err-guard.txt   || echo $? > code-guard.txt
cp disk/*.mcap guarded/
umount disk"#;
    let output = with_a_small_disk(dir.path(), script);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");

    let log = std::fs::read_to_string(dir.path().join("err-full.txt")).unwrap();
    assert!(
        !dir.path().join("code-full.txt").exists(),
        "the recorder does not fail: {log}"
    );
    assert!(
        log.contains("No space left on device") && log.contains("still in memory"),
        "the error is named: {log}"
    );
    let recorder = log.lines().rev().find(|l| l.starts_with("recorder ")).unwrap();
    assert!(recorder.contains("stopped"), "{recorder}");
    // The first event could not be written: its partial file is gone, not left empty or damaged, and
    // its number goes to the next. That one, written once there was room, holds the second before its
    // trigger: the ring was kept through the failure.
    let files: Vec<String> = std::fs::read_dir(dir.path().join("full"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        files.iter().all(|f| f.starts_with("event_00")) && files.contains(&"event_001.mcap".to_owned()),
        "{files:?}\n{log}"
    );
    for file in &files {
        let (code, report) = inspect(dir.path(), &dir.path().join("full").join(file));
        assert_eq!(code, Some(0), "{file} is whole: {report}");
    }
    assert!(log.contains("event 1 into disk/event_001.mcap"), "{log}");
    let second = dir.path().join("full/event_001.mcap");
    let (code, report) = inspect(dir.path(), &second);
    assert_eq!(code, Some(0), "{report}");
    let camera = channel(&report, "camera.image");
    assert!(camera["messages"].as_u64().unwrap() >= 1, "{camera}");
    assert!(report["duration_s"].as_f64().unwrap() >= 1.3, "{report}");

    let log = std::fs::read_to_string(dir.path().join("err-guard.txt")).unwrap();
    assert!(!dir.path().join("code-guard.txt").exists(), "{log}");
    assert!(
        log.contains("stopped writing disk/event_001.mcap")
            && log.contains("below min_free_mb = 2")
            && log.contains("kept in memory"),
        "{log}"
    );
    assert!(
        log.contains("no event written to disk/event.mcap"),
        "the next trigger is refused before it opens a file: {log}"
    );
    let (code, report) = inspect(dir.path(), &dir.path().join("guarded/event_001.mcap"));
    assert_eq!(code, Some(0), "closed and valid: {report}");
}

/// A trigger storm (1000 triggers a second for 2 s) on a full 1 MB disk: no event file is left behind
/// empty or damaged, the error is logged about once a second with a count, and the log's event numbers
/// are the files'.
#[test]
fn a_trigger_storm_on_a_full_disk_leaves_no_file_and_logs_once_a_second() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("storm.ron"),
        PRE_TRIGGER_ON_DISK
            .replace(r#""rate": 0.5"#, r#""rate": 1000.0"#)
            .replace("every_2s", "storm"),
    )
    .unwrap();
    let script = r#"mkdir -p disk left
mount -t tmpfs -o size=1m tmpfs disk
head -c 1020k /dev/zero > disk/filler || true
"$KAIROS" run storm.ron --for 2500ms --stats > out.txt 2> err.txt || echo $? > code.txt
ls disk > left/files.txt
umount disk"#;
    let output = with_a_small_disk(dir.path(), script);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let log = std::fs::read_to_string(dir.path().join("err.txt")).unwrap();
    assert!(
        !dir.path().join("code.txt").exists(),
        "the recorder does not fail: {log}"
    );
    let files = std::fs::read_to_string(dir.path().join("left/files.txt")).unwrap();
    assert_eq!(
        files.trim(),
        "filler",
        "no event file is left on the full disk: {files}"
    );
    let errors = log.lines().filter(|l| l.contains("ERROR")).count();
    assert!((1..=4).contains(&errors), "{errors} error lines in 2.5 s:\n{log}");
    assert!(log.contains("event(s) not written in all"), "{log}");
    // An event that opened its file before the disk refused more says what became of the file.
    if log.contains(": event 1 into") {
        assert!(
            log.contains("partial file disk/event_001.mcap is removed"),
            "{log}"
        );
    }
}

/// Markers belong to the data: in pre-trigger mode a marker on the `mark` input waits in the ring and is
/// written with the event it falls in, not into a file of its own; a mark input held on marks once.
#[test]
fn markers_wait_in_the_ring_and_a_mark_input_held_on_marks_once() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    // A square wave at 0.4 Hz: on for 1.25 s from 0, then off, on again at 2.5 s (sampled at 20 Hz);
    // one trigger at 4 s (the counter's second count). The pre-trigger window of 1 s before it holds no
    // rising edge; the event written at 4 s holds none of the first markers.
    let diagram = r#"Diagram(
    format: 1,
    components: [
        Component(id: "camera", type: "sensors.camera", properties: {"width": 80, "height": 60, "rate": 20.0}),
        Component(id: "square", type: "core.square", properties: {"frequency": 0.4, "rate": 20.0, "offset": 0.5, "amplitude": 0.5}),
        Component(id: "every_4s", type: "core.counter", properties: {"rate": 0.25}),
        Component(id: "recorder", type: "recording.recorder", properties: {
            "mode": "pre_trigger", "pre_trigger_s": 2.0, "post_trigger_s": 0.2,
            "path": "event.mcap", "compression": "none", "min_free_mb": 0.0,
        }),
    ],
    connections: [
        Connection(from: "camera.image", to: "recorder.in1"),
        Connection(from: "square.out", to: "recorder.mark"),
        Connection(from: "every_4s.out", to: "recorder.trigger"),
    ],
)"#;
    std::fs::write(dir.path().join("marks.ron"), diagram).unwrap();
    let output = kairos(dir.path(), &["run", "marks.ron", "--for", "4600ms"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let files: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|f| Path::new(f).extension().is_some_and(|e| e == "mcap"))
        .collect();
    assert_eq!(
        files,
        vec!["event_001.mcap".to_owned()],
        "one event, no file for a marker alone: {stderr}"
    );
    let (code, report) = inspect(dir.path(), &dir.path().join("event_001.mcap"));
    assert_eq!(code, Some(0), "{report}");
    // The edge at 2.5 s falls in the 2 s before the trigger at 4 s: one marker, not one per sample.
    let markers = report["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["topic"] == "kairos.markers")
        .map_or(0, |c| c["messages"].as_u64().unwrap());
    assert_eq!(markers, 1, "{report}");
    // The file's drop counts say what it holds of each track, and what the ring let go before it.
    let camera = channel(&report, "camera.image")["messages"].as_u64().unwrap();
    let drops = report["metadata"]["kairos.drops"]["in1 camera.image"]
        .as_str()
        .unwrap_or_default();
    assert!(
        drops.contains(&format!("in_file={camera} ")) && drops.contains("ring_dropped_before="),
        "{drops}: {camera} in the file"
    );
    let dropped: u64 = drops
        .rsplit("ring_dropped_before=")
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(dropped > 0, "2 s of a 4 s wait were let go: {drops}");
}

#[test]
fn recordings_of_two_runs_on_unlocked_clocks_merge_only_when_allowed_and_then_say_so() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (car, roadside) = two_runs(dir.path());
    let one = dir.path().join("one.mcap");
    let args = |extra: &'static [&'static str]| {
        let mut args = vec![
            "merge".to_owned(),
            car.display().to_string(),
            format!("roadside={}", roadside.display()),
            "-o".to_owned(),
            one.display().to_string(),
        ];
        args.extend(extra.iter().map(|s| (*s).to_owned()));
        args
    };
    let refused = args(&[]);
    let output = kairos(
        dir.path(),
        &refused.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    assert!(
        stderr.contains("not made on synchronised clocks") && stderr.contains("car.mcap (car): clock free"),
        "{stderr}"
    );
    let allowed = args(&["--allow-unsynchronised"]);
    let output = kairos(
        dir.path(),
        &allowed.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stdout.contains("car/camera.image") && stdout.contains("roadside/imu.imu"),
        "{stdout}"
    );
    let (code, report) = inspect(dir.path(), &one);
    assert_eq!(code, Some(0), "{report}");
    assert!(
        report["metadata"]["kairos.merge"]["UNSYNCHRONISED CLOCKS"]
            .as_str()
            .is_some_and(|s| s.contains("rsu.mcap (roadside)")),
        "{report}"
    );
}

/// A truncated recording (a copy cut short, a file from a host that lost power) is not merged as if it
/// were whole: refused, naming what it holds; merged with `--allow-damaged`, the merged file says what
/// was lost and `inspect` exits 3 on it as on a damaged file. A file of a few bytes is refused the same.
#[test]
fn damaged_recordings_are_merged_only_when_allowed_and_the_merged_file_says_what_was_lost() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (car, roadside) = two_runs(dir.path());
    let whole = std::fs::read(&car).unwrap();
    let (cut, tiny) = (dir.path().join("cut.mcap"), dir.path().join("tiny.mcap"));
    std::fs::write(&cut, &whole[..whole.len() / 3]).unwrap();
    std::fs::write(&tiny, &whole[..10]).unwrap();
    let merged = dir.path().join("merged.mcap");
    let merge = |input: &Path, extra: &[&str]| {
        let mut args = vec![
            "merge".to_owned(),
            format!("car={}", input.display()),
            format!("roadside={}", roadside.display()),
            "-o".to_owned(),
            merged.display().to_string(),
            "--allow-unsynchronised".to_owned(),
        ];
        args.extend(extra.iter().map(|s| (*s).to_owned()));
        kairos(dir.path(), &args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    for input in [&cut, &tiny] {
        let refused = merge(input, &[]);
        let (_, stderr) = text(&refused);
        assert!(!refused.status.success(), "{}: {stderr}", input.display());
        assert!(
            stderr.contains("damaged recordings")
                && stderr.contains("(car): ")
                && stderr.contains("--allow-damaged"),
            "{stderr}"
        );
        assert!(!merged.exists(), "nothing written for a refused merge");
    }
    let allowed = merge(&cut, &["--allow-damaged"]);
    let (stdout, stderr) = text(&allowed);
    assert!(allowed.status.success(), "{stderr}");
    assert!(stdout.contains("merged although damaged"), "{stdout}");
    let (code, report) = inspect(dir.path(), &merged);
    assert_eq!(code, Some(3), "a merge of a damaged file is not whole: {report}");
    assert!(
        report["input_damage"]
            .as_str()
            .is_some_and(|s| s.contains("cut.mcap (car)") && s.contains("messages intact")),
        "{report}"
    );
}

/// Two recordings on unlocked clocks replayed on one timeline: the player says, as merge refuses, that
/// their times may not line up.
#[test]
fn the_player_warns_when_its_recordings_clocks_were_not_synchronised() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let (car, roadside) = two_runs(dir.path());
    let diagram = dir.path().join("both.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "player", type: "recording.player", properties: {{"path": "{}", "path2": "{}"}}),
            ])"#,
            car.display(),
            roadside.display()
        ),
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", diagram.to_str().unwrap(), "--for", "300ms"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("not made on synchronised clocks") && stderr.contains("car.mcap: clock free"),
        "{stderr}"
    );
}

#[test]
fn lz4_and_uncompressed_chunks_are_read_by_inspect_the_player_and_python() {
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    for compression in ["lz4", "none"] {
        let file = dir.path().join(format!("{compression}.mcap"));
        let setting = format!("recorder.compression={compression}");
        let output = record_for(dir.path(), &file, "600ms", &[&setting]);
        assert!(output.status.success(), "{}", text(&output).1);
        let (code, report) = inspect(dir.path(), &file);
        assert_eq!(code, Some(0), "{report}");
        let checked = Command::new("python3")
            .arg(repo_root().join("tests/recording/check_mcap.py"))
            .arg(&file)
            .output()
            .expect("python3");
        let (stdout, stderr) = text(&checked);
        assert!(checked.status.success(), "{compression}: {stderr}");
        let topics: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(
            topics["imu.imu"]["count"],
            channel(&report, "imu.imu")["messages"],
            "{compression}"
        );
        // The player replays every IMU sample of it.
        let index = kairos_pack_recording::timeline::RecordingIndex::open(&file).unwrap();
        let blocks: usize = (0..index.block_count())
            .map(|b| index.read_block(b).unwrap().len())
            .sum();
        assert_eq!(Some(blocks as u64), report["messages"].as_u64(), "{compression}");
    }
}

/// A rosbag2 recording written by the `rosbags` package (`recording/write_rosbag2.py`): the bag and
/// what it holds, per topic.
fn rosbag2(dir: &Path, storage: &str) -> (std::path::PathBuf, serde_json::Value) {
    let script = repo_root().join("tests/recording/write_rosbag2.py");
    let written = Command::new("python3")
        .arg(&script)
        .arg(dir)
        .arg(storage)
        .output()
        .expect("python3");
    assert!(
        written.status.success(),
        "{}",
        String::from_utf8_lossy(&written.stderr)
    );
    let expected = std::fs::read_to_string(dir.join("expected.json")).unwrap();
    (dir.join("drive"), serde_json::from_str(&expected).unwrap())
}

fn close(a: f64, b: &serde_json::Value) -> bool {
    (a - b.as_f64().unwrap()).abs() <= 1e-9 * a.abs().max(1.0)
}

fn close3([x, y, z]: [f64; 3], b: &serde_json::Value) -> bool {
    close(x, &b[0]) && close(y, &b[1]) && close(z, &b[2])
}

#[test]
fn a_rosbag2_recording_replays_each_message_as_its_kairos_type_at_its_header_stamp() {
    replay_rosbag2("mcap");
}

#[test]
fn a_sqlite_rosbag2_recording_replays_alike_with_or_without_its_definitions() {
    replay_rosbag2("sqlite3");
    // A bag from before ROS 2 Iron: the types Kairos knows replay, the others are refused saying why.
    replay_rosbag2("sqlite3-old");
}

/// Whether a replayed payload is what `write_rosbag2.py` wrote (`values`, its JSON).
fn matches_what_was_written(payload: &kairos_sdk_core::Payload, values: &serde_json::Value) -> bool {
    use kairos_sdk_core::{FixStatus, Payload};
    match payload {
        Payload::Imu(imu) => {
            close3(imu.angular_velocity.to_array(), &values["angular_velocity"])
                && close3(imu.linear_acceleration.to_array(), &values["linear_acceleration"])
                && match (imu.orientation, &values["orientation"]) {
                    (None, serde_json::Value::Null) => true,
                    (Some(q), wanted) => {
                        close(q.x, &wanted[0]) && close(q.z, &wanted[2]) && close(q.w, &wanted[3])
                    }
                    _ => false,
                }
        }
        Payload::GnssFix(fix) => {
            let status = match fix.status {
                FixStatus::NoFix => "no_fix",
                FixStatus::Fix => "fix",
                FixStatus::Differential => "differential",
                FixStatus::RtkFixed => "rtk_fixed",
            };
            close(fix.latitude_deg, &values["latitude"])
                && close(fix.longitude_deg, &values["longitude"])
                && close(fix.altitude_m, &values["altitude"])
                && close(fix.horizontal_accuracy_m, &values["horizontal_accuracy"])
                && close(fix.vertical_accuracy_m, &values["vertical_accuracy"])
                && status == values["status"]
        }
        Payload::Image(image) => {
            // A lossy JPEG is compared by its size and format alone.
            let pixels_match = values["data"].as_array().is_none_or(|data| {
                let data: Vec<u8> = data.iter().map(|v| v.as_u64().unwrap() as u8).collect();
                image.pixels[..] == data[..]
            });
            values["width"] == image.width
                && values["height"] == image.height
                && values["step"] == image.stride
                && values["format"]
                    .as_str()
                    .is_none_or(|f| f == format!("{:?}", image.format))
                && pixels_match
        }
        Payload::PointCloud(cloud) => {
            let xyz = values["xyz"].as_array().unwrap();
            cloud.points.len() == xyz.len()
                && cloud
                    .points
                    .iter()
                    .zip(xyz)
                    .all(|(p, w)| close3(p.as_dvec3().to_array(), w))
                && cloud.intensity.as_ref().is_some_and(|i| {
                    i.iter()
                        .zip(values["intensity"].as_array().unwrap())
                        .all(|(a, b)| close(f64::from(*a), b))
                })
        }
        Payload::F64(value) => close(*value, &values["data"]),
        Payload::Pose(pose) => {
            close3(pose.position.to_array(), &values["position"])
                && close(pose.orientation.y, &values["orientation"][1])
                && close(pose.orientation.w, &values["orientation"][3])
        }
        Payload::Text(text) => {
            let json: serde_json::Value = serde_json::from_str(text).unwrap();
            close(json["temperature"].as_f64().unwrap(), &values["temperature"])
                && json["header"]["frame_id"] == values["frame_id"]
        }
        other => panic!("replayed as {other:?}, not {values}"),
    }
}

/// A bag the `rosbags` package writes in `storage`, inspected, then replayed through the player into a
/// Kairos recording whose every value and both times are compared with what the bag was given.
fn replay_rosbag2(storage: &str) {
    let dir = tempfile::tempdir().unwrap();
    let (bag, expected) = rosbag2(dir.path(), storage);
    let without_definitions = storage == "sqlite3-old";

    // kairos inspect names each topic's ROS type and the Kairos type it replays as.
    let (code, report) = inspect(dir.path(), &bag);
    assert_eq!(code, Some(0), "{report}");
    for (topic, schema, kairos_type) in [
        ("/imu", "sensor_msgs/msg/Imu", "imu"),
        ("/fix", "sensor_msgs/msg/NavSatFix", "gnss_fix"),
        ("/camera/image_raw", "sensor_msgs/msg/Image", "image"),
        ("/points", "sensor_msgs/msg/PointCloud2", "point_cloud"),
        ("/speed", "std_msgs/msg/Float64", "f64"),
        ("/pose", "geometry_msgs/msg/PoseStamped", "pose"),
        ("/temperature", "sensor_msgs/msg/Temperature", "text"),
        ("/camera/compressed", "sensor_msgs/msg/CompressedImage", "image"),
    ] {
        let channel = channel(&report, topic);
        assert_eq!(channel["schema"], schema, "{channel}");
        assert_eq!(channel["kairos_type"], kairos_type, "{channel}");
        assert_eq!(
            channel["messages"].as_u64().unwrap() as usize,
            expected[topic].as_array().unwrap().len()
        );
    }

    // Replayed through the player into a Kairos recorder, every link NeverSkipping.
    let topics = [
        "/imu",
        "/fix",
        "/camera/image_raw",
        "/points",
        "/speed",
        "/pose",
        "/temperature",
        "/camera/compressed",
    ];
    let copy = dir.path().join("copy.mcap");
    let mut connections = String::new();
    for (i, topic) in topics.iter().enumerate() {
        let _ = writeln!(
            connections,
            "Connection(from: \"player.{}\", to: \"copy.in{}\", policy: NeverSkipping),",
            kairos_sdk_core::port_name_for_topic(topic),
            i + 1
        );
    }
    let diagram = dir.path().join("replay.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, packs: [Pack(name: "recording", version: "^0.1")],
    components: [
        Component(id: "player", type: "recording.player", properties: {{"path": "{}"}}),
        Component(id: "copy", type: "recording.recorder", properties: {{"path": "{}"}}),
    ],
    connections: [{connections}],
)"#,
            // The bag's folder, as `ros2 bag record` leaves it.
            bag.display(),
            copy.display()
        ),
    )
    .unwrap();
    let output = kairos(dir.path(), &["run", diagram.to_str().unwrap()]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    if without_definitions {
        assert!(
            stderr.contains("carries no definition of sensor_msgs/msg/Temperature"),
            "{stderr}"
        );
        assert_eq!(stderr.matches("cannot be decoded").count(), 1, "{stderr}");
    } else {
        assert!(!stderr.contains("cannot be decoded"), "{stderr}");
    }

    let replayed = decoded_messages(&copy);
    for topic in topics {
        let sent = expected[topic].as_array().unwrap();
        let name = format!("player.{}", kairos_sdk_core::port_name_for_topic(topic));
        if without_definitions && topic == "/temperature" {
            assert!(
                !replayed.contains_key(&name),
                "{storage}: {topic} replayed without a definition"
            );
            continue;
        }
        let got = &replayed[&name];
        assert_eq!(got.len(), sent.len(), "{topic}");
        for ((timestamp, time_of_issue, payload), values) in got.iter().zip(sent) {
            // The header stamp is the timestamp, the bag's log time the time of issue.
            if topic != "/speed" {
                assert_eq!(*timestamp, values["stamp_ns"].as_u64().unwrap(), "{topic}");
            }
            assert_eq!(*time_of_issue, values["log_ns"].as_u64().unwrap(), "{topic}");
            let matches = matches_what_was_written(payload, values);
            assert!(matches, "{topic}: {payload:?} is not {values}");
        }
    }
}

#[test]
fn the_rosbag2_profile_writes_what_ros_readers_decode_and_kairos_reads_back_the_same() {
    use kairos_sdk_core::Payload;
    let _serial = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("drive_ros.mcap");
    let output = record_for(dir.path(), &file, "1s", &["recorder.profile=rosbag2"]);
    assert!(output.status.success(), "{}", text(&output).1);

    // Two independent ROS 2 readers decode every message alike (the script checks they agree).
    let checked = Command::new("python3")
        .arg(repo_root().join("tests/recording/check_rosbag2.py"))
        .arg(&file)
        .output()
        .expect("python3");
    assert!(
        checked.status.success(),
        "{}",
        String::from_utf8_lossy(&checked.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&checked.stdout).unwrap();
    assert_eq!(report["profile"], "ros2");
    let ours = decoded_messages(&file);
    for (topic, schema) in [
        ("/camera/image", "sensor_msgs/msg/Image"),
        ("/imu/imu", "sensor_msgs/msg/Imu"),
        ("/imu/pose", "geometry_msgs/msg/PoseStamped"),
        ("/gnss/fix", "sensor_msgs/msg/NavSatFix"),
    ] {
        let theirs = &report["topics"][topic];
        assert_eq!(theirs["schema"], schema, "{topic}");
        assert_eq!(theirs["message_encoding"], "cdr");
        let theirs = theirs["messages"].as_array().unwrap();
        let ours = &ours[topic];
        assert!(!ours.is_empty());
        assert_eq!(ours.len(), theirs.len(), "{topic}");
        for ((timestamp, time_of_issue, payload), message) in ours.iter().zip(theirs) {
            // The header's stamp is the timestamp, the log time the time of issue.
            assert_eq!(*timestamp, message["stamp"].as_u64().unwrap(), "{topic}");
            assert_eq!(*time_of_issue, message["log_time"].as_u64().unwrap(), "{topic}");
            let same = match payload {
                Payload::Image(image) => {
                    let sum: u64 = image.pixels.iter().map(|b| u64::from(*b)).sum();
                    message["width"] == image.width
                        && message["height"] == image.height
                        && message["step"] == image.stride
                        && message["encoding"] == "rgb8"
                        && message["sum"] == sum
                }
                Payload::Imu(imu) => {
                    close3(imu.angular_velocity.to_array(), &message["angular_velocity"])
                        && close3(
                            imu.linear_acceleration.to_array(),
                            &message["linear_acceleration"],
                        )
                        && imu
                            .orientation
                            .is_some_and(|q| close(q.w, &message["orientation"][3]))
                }
                Payload::Pose(pose) => {
                    close3(pose.position.to_array(), &message["position"])
                        && close(pose.orientation.z, &message["orientation"][2])
                }
                Payload::GnssFix(fix) => {
                    close(fix.latitude_deg, &message["latitude"])
                        && close(fix.longitude_deg, &message["longitude"])
                        && close(fix.altitude_m, &message["altitude"])
                        && close(fix.horizontal_accuracy_m.powi(2), &message["covariance"][0])
                        && close(fix.vertical_accuracy_m.powi(2), &message["covariance"][8])
                }
                other => panic!("{topic} read back as {other:?}"),
            };
            assert!(
                same,
                "{topic}: Kairos read {payload:?}, the ROS readers {message}"
            );
        }
    }
}

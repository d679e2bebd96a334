//! The `kairos` command line as a user meets it: validation messages, the component listing, Ctrl-C.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::io::Read as _;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{example, kairos, text};

#[test]
fn validate_reports_every_problem_with_its_place_and_a_fix() {
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken.ron");
    std::fs::write(
        &broken,
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "sine1", type: "core.sine", properties: {"frequncy": 2.0}),
        Component(id: "gain1", type: "core.gian"),
        Component(id: "console1", type: "core.console"),
    ],
    connections: [
        Connection(from: "sine1.out", to: "console1.in"),
        Connection(from: "sine1.out", to: "console1.in"),
    ],
)
"#,
    )
    .unwrap();
    let output = kairos(dir.path(), &["validate", broken.to_str().unwrap()]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("unknown property 'frequncy' on 'sine1'"),
        "{stderr}"
    );
    assert!(stderr.contains("did you mean 'frequency'?"), "{stderr}");
    assert!(
        stderr.contains("core.gain"),
        "suggests the close type name: {stderr}"
    );
    assert!(stderr.contains("broken.ron:5:"), "located by line: {stderr}");
    assert!(
        stderr.contains("fed twice") || stderr.contains("twice"),
        "{stderr}"
    );
}

/// A diagram where a simulator's speed feeds a gain that drives its throttle: a closed loop.
fn closed_loop(sequential: bool, time_scale: f64, road: &str) -> String {
    format!(
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "sim", version: "^0.1")],
    clock_source: "vehicle",
    sequential: {sequential},
    components: [
        Component(id: "vehicle", type: "sim.vehicle", properties: {{"time_scale": {time_scale:?}, "road": "{road}"}}),
        Component(id: "gain", type: "core.gain"),
        Component(id: "gain2", type: "core.gain"),
    ],
    connections: [
        Connection(from: "vehicle.speed", to: "gain.in"),
        Connection(from: "gain.out", to: "vehicle.throttle"),
        Connection(from: "gain2.out", to: "gain2.in"),
    ],
)
"#
    )
}

#[test]
fn a_simulator_s_loops_time_and_road_are_checked_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let check = |name: &str, diagram: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, diagram).unwrap();
        let output = kairos(dir.path(), &["validate", path.to_str().unwrap()]);
        let (stdout, stderr) = text(&output);
        (output.status.success(), format!("{stdout}{stderr}"))
    };
    // The loop through the simulator is allowed (it reads its commands at its ticks); the loop of a
    // component into itself is not.
    let (ok, said) = check("loop.ron", &closed_loop(true, 0.0, "straight 100"));
    assert!(!ok, "{said}");
    assert!(said.contains("'gain2' feeds itself"), "{said}");
    assert!(!said.contains("'gain' and 'vehicle'"), "{said}");
    assert!(!said.contains("'vehicle' and 'gain'"), "{said}");
    // As fast as possible needs one thread for all.
    let (ok, said) = check("threads.ron", &closed_loop(false, 0.0, "straight 100"));
    assert!(!ok, "{said}");
    assert!(said.contains("time_scale 0"), "{said}");
    assert!(said.contains("add `sequential: true`"), "{said}");
    // A road that does not read is reported on its property, with an example.
    let (ok, said) = check("road.ron", &closed_loop(false, 1.0, "straight 100; left 200"));
    assert!(!ok, "{said}");
    assert!(
        said.contains("segment 2 ('left 200'): the angle is missing"),
        "{said}"
    );
    assert!(!said.contains("time_scale 0"), "{said}");
}

#[test]
fn validate_accepts_several_files_and_fails_if_one_is_bad() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.ron");
    std::fs::write(
        &bad,
        "Diagram(format: 1, packs: [], components: [, connections: [])",
    )
    .unwrap();
    let good = example("hello");
    let output = kairos(
        dir.path(),
        &["validate", good.to_str().unwrap(), bad.to_str().unwrap()],
    );
    let (stdout, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert!(stdout.contains("hello.ron: valid"), "{stdout}");
    assert!(stderr.contains("bad.ron:1:"), "{stderr}");
}

#[test]
fn a_missing_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let output = kairos(dir.path(), &["run", "nowhere.ron"]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert!(stderr.contains("nowhere.ron"), "{stderr}");
}

#[test]
fn components_lists_the_library_as_text_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let output = kairos(dir.path(), &["components", "--json"]);
    assert!(output.status.success());
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let components = json["components"].as_array().unwrap();
    let sine = components.iter().find(|c| c["type_name"] == "core.sine").unwrap();
    assert_eq!(sine["outputs"][0]["name"], "out");
    assert!(
        sine["properties"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p["name"] == "frequency")
    );
    for expected in [
        "core.gain",
        "core.csv_writer",
        "sensors.camera",
        "sensors.imu",
        "sensors.gnss",
    ] {
        assert!(
            components.iter().any(|c| c["type_name"] == expected),
            "{expected} missing"
        );
    }
    assert!(
        json["packs"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p["name"] == "sensors")
    );

    let output = kairos(dir.path(), &["components", "core.counter"]);
    let (stdout, _) = text(&output);
    assert!(
        stdout.contains("core.counter") && stdout.contains("act  reset"),
        "{stdout}"
    );
    assert!(!stdout.contains("core.sine"), "the filter applies: {stdout}");
}

#[test]
fn ctrl_c_stops_cleanly_with_a_final_table() {
    let dir = tempfile::tempdir().unwrap();
    let path = example("hello");
    let mut child = Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args([
            "run",
            path.to_str().unwrap(),
            "--stats",
            "--stats-interval",
            "10s",
        ])
        .current_dir(dir.path())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1200));
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let started = Instant::now();
    let exit = loop {
        if let Some(exit) = child.try_wait().unwrap() {
            break exit;
        }
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "kairos did not stop after Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    assert!(exit.success(), "{stderr}");
    assert!(stderr.contains("stopping (Ctrl-C)"), "{stderr}");
    assert!(stderr.contains("=== final"), "{stderr}");
    assert!(stderr.contains("stopped"), "components end stopped: {stderr}");
}

#[test]
fn an_overflowing_link_is_named_at_most_once_a_second() {
    let dir = tempfile::tempdir().unwrap();
    let diagram = dir.path().join("overflow.ron");
    std::fs::write(
        &diagram,
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1")],
    components: [
        Component(id: "fast", type: "core.sine", properties: {"rate": 1000.0}),
        Component(id: "slow", type: "core.delay", properties: {"delay_ms": 20.0}),
    ],
    connections: [
        Connection(from: "fast.out", to: "slow.in", buffer_size: 4),
    ],
)
"#,
    )
    .unwrap();
    let output = kairos(
        dir.path(),
        &[
            "run",
            diagram.to_str().unwrap(),
            "--for",
            "2500ms",
            "--stats",
            "--stats-interval",
            "10s",
        ],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let warnings = stderr
        .lines()
        .filter(|l| l.contains("overflow on link 'fast.out -> slow.in'"))
        .count();
    assert!(
        (1..=3).contains(&warnings),
        "{warnings} warnings in 2.5 s:\n{stderr}"
    );
    assert!(
        stderr.contains("enlarge buffer_size"),
        "the warning says how to fix it: {stderr}"
    );
}

#[test]
fn logs_written_to_a_file_carry_no_colour_codes() {
    let dir = tempfile::tempdir().unwrap();
    let hello = example("hello");
    let output = kairos(dir.path(), &["run", hello.to_str().unwrap(), "--for", "300ms"]);
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("INFO"), "there are log lines: {stderr}");
    assert!(
        !stderr.contains('\u{1b}'),
        "standard error is a pipe here, as a file or journald would be: {stderr:?}"
    );
}

#[test]
fn inspect_of_a_missing_file_says_why_once() {
    let dir = tempfile::tempdir().unwrap();
    let output = kairos(dir.path(), &["inspect", "nowhere.mcap"]);
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert_eq!(stderr.matches("No such file or directory").count(), 1, "{stderr}");
    assert!(stderr.contains("nowhere.mcap"), "{stderr}");
}

#[test]
fn inspect_json_names_its_time_base_and_rounds_its_figures() {
    let dir = tempfile::tempdir().unwrap();
    let record = example("record");
    let run = kairos(dir.path(), &["run", record.to_str().unwrap(), "--for", "1s"]);
    assert!(run.status.success(), "{}", text(&run).1);
    let output = kairos(dir.path(), &["inspect", "drive.mcap", "--json"]);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(report["time"], "publish_time");
    let decimals = |value: &serde_json::Value| {
        value
            .to_string()
            .split_once('.')
            .map_or(0, |(_, fraction)| fraction.len())
    };
    assert!(decimals(&report["duration_s"]) <= 6, "{}", report["duration_s"]);
    for channel in report["channels"].as_array().unwrap() {
        assert!(decimals(&channel["rate_hz"]) <= 3, "{}", channel["rate_hz"]);
    }
}

#[test]
fn a_gnss_receiver_sets_the_runtime_clock_to_its_utc_whatever_the_sentence_order() {
    let root = common::repo_root();
    let dir = tempfile::tempdir().unwrap();
    // The drive as recorded (RMC, then GGA, each second), and with GGA first: its time has no date
    // until the RMC after it.
    let drive = std::fs::read_to_string(root.join("examples/data/drive.nmea")).unwrap();
    let mut swapped: Vec<&str> = drive.lines().collect();
    for pair in swapped.chunks_mut(3) {
        pair.swap(0, 1);
    }
    assert!(swapped[0].starts_with("$GPGGA") && swapped[1].starts_with("$GPRMC"));
    let swapped_path = dir.path().join("gga_first.nmea");
    std::fs::write(&swapped_path, swapped.join("\n")).unwrap();
    for path in [root.join("examples/data/drive.nmea"), swapped_path] {
        let output = kairos(
            &root,
            &[
                "run",
                "examples/gnss_replay.ron",
                "--set",
                &format!("gnss.path={}", path.display()),
                "--for",
                "3500ms",
                "--stats",
                "--stats-interval",
                "3s",
                "--clock-source",
                "gnss",
            ],
        );
        let (stdout, stderr) = text(&output);
        assert!(output.status.success(), "{stderr}");
        // Locked, within a few milliseconds (not a second off, following a replay scheduled on itself).
        let clock = stderr
            .lines()
            .find(|l| l.starts_with("clock: follows 'gnss'"))
            .unwrap_or_default();
        let error_ms: f64 = clock
            .split("error ")
            .nth(1)
            .and_then(|rest| rest.split(" ms").next())
            .and_then(|number| number.parse().ok())
            .unwrap_or(f64::NAN);
        assert!(
            clock.contains("locked") && error_ms.abs() < 5.0,
            "{}: {clock}",
            path.display()
        );
        // The fixes are from 2026-11-25 10:00:00 UTC: every sample carries that time, the first one
        // too, and none goes back.
        let stamps: Vec<f64> = stdout
            .lines()
            .filter_map(|l| l.split("t=").nth(1)?.split_whitespace().next()?.parse().ok())
            .collect();
        assert!(stamps.len() >= 3, "{stdout}");
        assert!(
            stamps
                .iter()
                .all(|t| (1_795_600_799.0..1_795_600_900.0).contains(t))
                && stamps.windows(2).all(|w| w[1] >= w[0]),
            "{}: {stamps:?}",
            path.display()
        );
    }
}

#[test]
fn a_clock_source_that_gives_its_time_and_ends_at_once_is_said_to_have_set_the_clock() {
    // Replayed fast, the minute of sentences is over in milliseconds: the source has set the clock and
    // ended before the start looks again.
    let root = common::repo_root();
    let output = kairos(
        &root,
        &[
            "run",
            "examples/gnss_replay.ron",
            "--set",
            "gnss.replay=fast",
            "--for",
            "1s",
            "--clock-source",
            "gnss",
        ],
    );
    let (_, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("the clock follows 'gnss': set to its time"),
        "{stderr}"
    );
    assert!(!stderr.contains("no time from the clock source"), "{stderr}");
}

#[test]
fn a_clock_source_that_cannot_give_the_time_is_refused_with_the_ones_that_can() {
    let root = common::repo_root();
    let output = kairos(
        &root,
        &[
            "run",
            "examples/gnss_replay.ron",
            "--for",
            "1s",
            "--clock-source",
            "console1",
        ],
    );
    let (_, stderr) = text(&output);
    assert!(!output.status.success());
    assert!(
        stderr.contains("'console1' (core.console) cannot be the clock source"),
        "{stderr}"
    );
    assert!(stderr.contains("components that can: gnss"), "{stderr}");
    let missing = kairos(
        &root,
        &[
            "run",
            "examples/gnss_replay.ron",
            "--for",
            "1s",
            "--clock-source",
            "nobody",
        ],
    );
    assert!(text(&missing).1.contains("the diagram has no component 'nobody'"));
}

#[test]
fn a_diagram_placing_components_on_other_hosts_validates_but_never_runs_them_here_unnoticed() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_hosts.ron");
    std::fs::write(
        &path,
        r#"Diagram(format: 1,
            hosts: {"car": Host(endpoint: "ws://10.0.0.2:7600", token_file: "car.token")},
            packs: [],
            components: [
                Component(id: "sine1", type: "core.sine", host: "car"),
                Component(id: "console1", type: "core.console"),
            ],
            connections: [Connection(from: "sine1.out", to: "console1.in")])"#,
    )
    .unwrap();
    let validated = kairos(dir.path(), &["validate", path.to_str().unwrap()]);
    assert!(validated.status.success(), "{}", text(&validated).1);
    let run = kairos(dir.path(), &["run", path.to_str().unwrap(), "--for", "1s"]);
    let (_, stderr) = text(&run);
    assert!(!run.status.success());
    assert!(stderr.contains("'sine1' is placed on host 'car'"), "{stderr}");
    assert!(stderr.contains("remove `host: \"car\"`"), "{stderr}");
}

#[test]
fn a_second_run_writes_beside_the_first_run_s_files_and_never_over_them() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("twice.ron"),
        r#"Diagram(format: 1, components: [
            Component(id: "count", type: "core.counter", properties: {"rate": 100.0}),
            Component(id: "csv", type: "core.csv_writer", properties: {"path": "out/count.csv"}),
            Component(id: "recorder", type: "recording.recorder", properties: {"path": "out/count.mcap", "min_free_mb": 0.0}),
            Component(id: "can", type: "can.candump_writer", properties: {"path": "out/can.log"}),
        ], connections: [
            Connection(from: "count.out", to: "csv.in1"),
            Connection(from: "count.out", to: "recorder.in1"),
        ])"#,
    )
    .unwrap();
    let run = || kairos(dir.path(), &["run", "twice.ron", "--for", "300ms"]);
    let first = run();
    assert!(first.status.success(), "{:?}", text(&first));
    let out = dir.path().join("out");
    let kept: Vec<(std::path::PathBuf, Vec<u8>)> = ["count.csv", "count.mcap", "can.log"]
        .iter()
        .map(|name| (out.join(name), std::fs::read(out.join(name)).unwrap()))
        .collect();
    let second = run();
    let (_, stderr) = text(&second);
    assert!(second.status.success(), "{stderr}");
    for (path, bytes) in &kept {
        assert_eq!(
            &std::fs::read(path).unwrap(),
            bytes,
            "{} was touched",
            path.display()
        );
    }
    for (asked, written) in [
        ("count.csv", "count-1.csv"),
        ("count.mcap", "count-1.mcap"),
        ("can.log", "can-1.log"),
    ] {
        assert!(out.join(written).is_file(), "no {written}: {stderr}");
        assert!(
            stderr.contains(&format!("{} exists and is kept", out.join(asked).display()))
                || stderr.contains(&format!("out/{asked} exists and is kept")),
            "{asked}: {stderr}"
        );
    }
    assert!(
        std::fs::read_to_string(out.join("count-1.csv"))
            .unwrap()
            .lines()
            .count()
            > 1,
        "the second run's rows are in its own file"
    );
    // Asked for, a file is replaced.
    let replaced = kairos(
        dir.path(),
        &[
            "run",
            "twice.ron",
            "--for",
            "300ms",
            "--set",
            "csv.overwrite=true",
        ],
    );
    assert!(replaced.status.success(), "{:?}", text(&replaced));
    assert_ne!(std::fs::read(out.join("count.csv")).unwrap(), kept[0].1);
    assert!(!out.join("count-2.csv").exists());
}

/// Makes a noisy colour image with OpenCV, runs it through `component` (its type and properties, as a
/// diagram writes them) with `kairos run`, and returns the most a value differs from what the Python
/// expression `opencv` makes of `source` (the image as OpenCV reads it, BGR).
/// A 320×240 colour PNG in `folder` (named as the image sequence plays it): a smooth pattern under noise of
/// `sigma` levels, from `seed`.
fn write_noisy_pattern(folder: &std::path::Path, sigma: f64, seed: u32) {
    python_output(&format!(
        "import numpy as np, cv2\n\
         y, x = np.mgrid[0:240, 0:320]\n\
         base = 127 + 100 * np.sin(x / 9.0) * np.cos(y / 7.0)\n\
         noise = np.random.default_rng({seed}).normal(0, {sigma}, (240, 320, 3))\n\
         cv2.imwrite('{}/1795575410804363450_00000000.png', np.clip(base[..., None] + noise, 0, 255).astype(np.uint8))",
        folder.display()
    ));
}

fn differs_from_opencv(component: &str, opencv: &str) -> String {
    let root = common::repo_root();
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("in"), dir.path().join("out"));
    std::fs::create_dir_all(&input).unwrap();
    let python = |script: &str| {
        let done = Command::new("python3")
            .args(["-c", script])
            .output()
            .expect("python3");
        let (stdout, stderr) = text(&done);
        assert!(
            done.status.success(),
            "install numpy and opencv-python-headless: {stderr}"
        );
        stdout.trim().to_owned()
    };
    // A smooth pattern under strong noise: every colour value and every neighbourhood comes up.
    write_noisy_pattern(&input, 60.0, 1);
    let diagram = dir.path().join("through.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "images", type: "video.image_sequence", properties: {{"folder": "{}"}}),
                Component(id: "step", {component}),
                Component(id: "out", type: "video.image_writer", properties: {{"folder": "{}"}}),
            ], connections: [
                Connection(from: "images.image", to: "step.in", policy: NeverSkipping),
                Connection(from: "step.out", to: "out.image"),
            ])"#,
            input.display(),
            output.display()
        ),
    )
    .unwrap();
    let run = kairos(&root, &["run", diagram.to_str().unwrap(), "--for", "1500ms"]);
    assert!(run.status.success(), "{}", text(&run).1);
    python(&format!(
        "import glob, numpy as np, cv2\n\
         source = cv2.imread(glob.glob('{}/*.png')[0])\n\
         ours = cv2.imread(sorted(glob.glob('{}/*.png'))[0], cv2.IMREAD_UNCHANGED)\n\
         theirs = {opencv}\n\
         print(int(np.abs(ours.astype(int) - theirs.astype(int)).max()))",
        input.display(),
        output.display()
    ))
}

/// The Gaussian blur with sigma 0, at each size OpenCV has a fixed kernel for, is OpenCV's `GaussianBlur`.
#[test]
fn the_gaussian_blur_with_sigma_0_is_opencv_s_value_for_value() {
    for size in [3, 5, 7] {
        let differs = differs_from_opencv(
            &format!(r#"type: "vision.gaussian_blur", properties: {{"size": {size}, "sigma": 0.0}}"#),
            &format!("cv2.GaussianBlur(source, ({size}, {size}), 0)"),
        );
        assert_eq!(
            differs, "0",
            "size {size}: the most a value differs from OpenCV's"
        );
    }
}

/// Colour to grey is OpenCV's `cvtColor(..., COLOR_BGR2GRAY)`.
#[test]
fn grey_is_opencv_s_value_for_value() {
    let differs = differs_from_opencv(
        r#"type: "vision.convert", properties: {"to": "gray"}"#,
        "cv2.cvtColor(source, cv2.COLOR_BGR2GRAY)",
    );
    assert_eq!(differs, "0", "the most a grey value differs from OpenCV's");
}

/// Shrinking by area at scales that are not whole numbers is OpenCV's `INTER_AREA`.
#[test]
fn the_area_resize_is_opencv_s_at_any_scale() {
    assert_resizes_as_opencv("area", "INTER_AREA", &[(128, 96), (240, 180), (100, 70)]);
}

/// Asserts that `vision.resize` with `interpolation` gives OpenCV's `cv2.resize` with `flag` to each size,
/// value for value.
fn assert_resizes_as_opencv(interpolation: &str, flag: &str, sizes: &[(u32, u32)]) {
    for (width, height) in sizes {
        let differs = differs_from_opencv(
            &format!(
                r#"type: "vision.resize", properties: {{"width": {width}, "height": {height}, "interpolation": "{interpolation}"}}"#
            ),
            &format!("cv2.resize(source, ({width}, {height}), interpolation=cv2.{flag})"),
        );
        assert_eq!(
            differs, "0",
            "{interpolation} to {width}×{height}: the most a value differs from OpenCV's"
        );
    }
}

/// Bilinear resizing, shrinking and enlarging, is OpenCV's `INTER_LINEAR` value for value (its 11-bit
/// fixed point, computed in Kairos's own vector loops).
#[test]
fn the_bilinear_resize_is_opencv_s_at_any_scale() {
    assert_resizes_as_opencv(
        "bilinear",
        "INTER_LINEAR",
        &[(128, 96), (240, 180), (100, 70), (517, 389), (3, 2)],
    );
}

/// Runs `script` with the tests' Python; its standard output.
fn python_output(script: &str) -> String {
    let done = Command::new("python3")
        .args(["-c", script])
        .output()
        .expect("python3");
    let (stdout, stderr) = text(&done);
    assert!(
        done.status.success(),
        "the tests' Python (tests/run installs it): {stderr}"
    );
    stdout
}

/// Signals of every kind (Intel and Motorola, signed and not, scaled and offset, described values, an
/// extended identifier), encoded by cantools from random values, decoded by `kairos run` and compared with
/// what cantools decodes from the same frames.
#[test]
fn the_dbc_decoder_agrees_with_cantools_on_frames_cantools_encodes() {
    const DBC: &str = r#"VERSION ""

NS_ :

BS_:

BU_: ECU DASH

BO_ 256 Engine: 8 ECU
 SG_ Speed : 0|16@1+ (0.25,0) [0|16383.75] "rpm" DASH
 SG_ Temperature : 16|8@1- (1,-40) [-168|87] "degC" DASH
 SG_ Torque : 24|12@1- (0.5,10) [-1014|1033.5] "Nm" DASH
 SG_ Running : 36|1@1+ (1,0) [0|1] "" DASH

BO_ 512 Brake: 8 ECU
 SG_ Pressure : 7|12@0+ (0.1,0) [0|409.5] "bar" DASH
 SG_ Wear : 11|10@0- (0.01,0) [-5.12|5.11] "mm" DASH

BO_ 2566834709 Gear: 8 ECU
 SG_ Selected : 0|4@1- (1,0) [-8|7] "" DASH
 SG_ ParkingBrake : 8|2@1+ (1,0) [0|3] "" DASH

VAL_ 2566834709 Selected -1 "Reverse" 0 "Neutral" 1 "First" 2 "Second" ;
VAL_ 2566834709 ParkingBrake 0 "Off" 1 "On" 2 "Fault" 3 "Unknown" ;
"#;
    let root = common::repo_root();
    let dir = tempfile::tempdir().unwrap();
    let (dbc, log) = (dir.path().join("car.dbc"), dir.path().join("bus.log"));
    std::fs::write(&dbc, DBC).unwrap();
    // cantools: random raw values in each signal's range, the log, and what it decodes (choices named).
    let expected = python_output(&format!(
        "import cantools, json, random\n\
         db = cantools.database.load_file('{dbc}')\n\
         random.seed(7)\n\
         lines, decoded = [], []\n\
         for i in range(300):\n\
         \x20   message = db.messages[i % len(db.messages)]\n\
         \x20   raw = {{}}\n\
         \x20   for s in message.signals:\n\
         \x20       low, high = (-(1 << (s.length - 1)), (1 << (s.length - 1)) - 1) if s.is_signed else (0, (1 << s.length) - 1)\n\
         \x20       raw[s.name] = random.randint(low, high)\n\
         \x20   data = message.encode(raw, scaling=False, strict=False)\n\
         \x20   frame_id = ('%08X' if message.is_extended_frame else '%03X') % message.frame_id\n\
         \x20   lines.append('(%.6f) can0 %s#%s' % (1.0 + i / 1000, frame_id, data.hex().upper()))\n\
         \x20   values = message.decode(data, decode_choices=True)\n\
         \x20   decoded.append([message.name, {{k: (str(v) if not isinstance(v, (int, float)) else v) for k, v in values.items()}}])\n\
         open('{log}', 'w').write('\\n'.join(lines) + '\\n')\n\
         print(json.dumps(decoded))",
        dbc = dbc.display(),
        log = log.display()
    ));
    let expected: Vec<(String, serde_json::Map<String, serde_json::Value>)> =
        serde_json::from_str(&expected).unwrap();
    let diagram = dir.path().join("decode.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "log", type: "can.candump_reader", properties: {{"path": "{}", "replay": "fast"}}),
                Component(id: "decoder", type: "can.dbc_decoder", properties: {{"dbc": "{}"}}),
                Component(id: "print", type: "core.console"),
            ], connections: [
                Connection(from: "log.frame", to: "decoder.frame", policy: NeverSkipping),
                Connection(from: "decoder.signals", to: "print.in", policy: NeverSkipping),
            ])"#,
            log.display(),
            dbc.display()
        ),
    )
    .unwrap();
    let run = kairos(
        &root,
        &[
            "run",
            diagram.to_str().unwrap(),
            "--for",
            "3s",
            "--stats",
            "--stats-interval",
            "10s",
        ],
    );
    let (stdout, stderr) = text(&run);
    assert!(run.status.success(), "{stderr}");
    // The statuses at the end count every frame, whenever their last period fell.
    assert!(stderr.contains("frames 300,"), "{stderr}");
    assert!(stderr.contains("decoded 300, unknown_ids 0"), "{stderr}");
    // `print: t=… seq=… latency=… Message: Signal = value unit; …`
    let lines: Vec<&str> = stdout.lines().filter(|l| l.starts_with("print:")).collect();
    assert_eq!(lines.len(), expected.len(), "{stdout}");
    for (line, (message, values)) in lines.iter().zip(&expected) {
        let text = line
            .split_once(&format!(" {message}: "))
            .map(|(_, rest)| rest)
            .unwrap_or_default();
        let ours: Vec<(&str, &str)> = text
            .split("; ")
            .filter_map(|pair| pair.split_once(" = "))
            .collect();
        assert_eq!(ours.len(), values.len(), "{line} against {values:?}");
        for (name, value) in ours {
            let theirs = &values[name];
            match theirs.as_f64() {
                Some(number) => {
                    let ours: f64 = value.split_whitespace().next().unwrap().parse().unwrap();
                    assert!(
                        (ours - number).abs() <= 1e-9 * number.abs().max(1.0),
                        "{line}: {name} {theirs}"
                    );
                }
                None => assert_eq!(Some(value), theirs.as_str(), "{line}: {name}"),
            }
        }
    }
}

/// GGA and GNS sentences pynmea2 builds from random fields (both hemispheres, every fix quality, positions
/// missing when there is no fix), decoded by `kairos run` and compared with what pynmea2 reads from them.
#[test]
fn the_nmea_receiver_agrees_with_pynmea2_on_sentences_pynmea2_builds() {
    let root = common::repo_root();
    let dir = tempfile::tempdir().unwrap();
    let nmea = dir.path().join("random.nmea");
    let expected = python_output(&format!(
        "import pynmea2, json, random\n\
         random.seed(11)\n\
         lines, expected = [], []\n\
         for i in range(200):\n\
         \x20   quality = random.choice([0, 1, 2, 4, 5, 6])\n\
         \x20   if quality == 0 and random.random() < 0.5:\n\
         \x20       position = ['', '', '', '']\n\
         \x20   else:\n\
         \x20       position = ['%02d%09.6f' % (random.randint(0, 89), random.uniform(0, 59.999999)), random.choice('NS'),\n\
         \x20                   '%03d%09.6f' % (random.randint(0, 179), random.uniform(0, 59.999999)), random.choice('EW')]\n\
         \x20   time = '%02d%02d%05.2f' % (random.randint(0, 23), random.randint(0, 59), random.uniform(0, 59.99))\n\
         \x20   sats, hdop = str(random.randint(0, 24)), '%.1f' % random.uniform(0.5, 20)\n\
         \x20   altitude, separation = '%.1f' % random.uniform(-100, 3000), '%.1f' % random.uniform(-100, 100)\n\
         \x20   if i % 2:\n\
         \x20       mode = {{0: 'NN', 1: 'AA', 2: 'DA', 4: 'RA', 5: 'FN', 6: 'EN'}}[quality]\n\
         \x20       sentence = pynmea2.GNS('GN', 'GNS', [time] + position + [mode, sats, hdop, altitude, separation, '', ''])\n\
         \x20   else:\n\
         \x20       sentence = pynmea2.GGA(random.choice(['GP', 'GN', 'GL']), 'GGA', [time] + position + [str(quality), sats, hdop, altitude, 'M', separation, 'M', '', ''])\n\
         \x20   line = str(sentence)\n\
         \x20   read = pynmea2.parse(line)\n\
         \x20   has_position = position[0] != ''\n\
         \x20   expected.append({{'latitude': read.latitude if has_position else None, 'longitude': read.longitude if has_position else None,\n\
         \x20       'altitude': float(read.altitude) + float(read.geo_sep), 'satellites': int(read.num_sats), 'hdop': float(read.hdop if i % 2 else read.horizontal_dil),\n\
         \x20       'fixed': quality in (1, 2, 4, 5)}})\n\
         \x20   lines.append(line)\n\
         open('{nmea}', 'w').write('\\r\\n'.join(lines) + '\\r\\n')\n\
         print(json.dumps(expected))",
        nmea = nmea.display()
    ));
    let expected: Vec<serde_json::Value> = serde_json::from_str(&expected).unwrap();
    let (fixes, more) = (dir.path().join("fix.csv"), dir.path().join("more.csv"));
    let diagram = dir.path().join("decode.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "gnss", type: "gnss.nmea", properties: {{"source": "file", "path": "{}", "replay": "fast"}}),
                Component(id: "fixes", type: "core.csv_writer", properties: {{"path": "{}"}}),
                Component(id: "more", type: "core.csv_writer", properties: {{"path": "{}"}}),
            ], connections: [
                Connection(from: "gnss.fix", to: "fixes.in1", policy: NeverSkipping),
                Connection(from: "gnss.satellites", to: "more.in1", policy: NeverSkipping),
                Connection(from: "gnss.hdop", to: "more.in2", policy: NeverSkipping),
            ])"#,
            nmea.display(),
            fixes.display(),
            more.display()
        ),
    )
    .unwrap();
    let run = kairos(&root, &["run", diagram.to_str().unwrap(), "--for", "3s"]);
    assert!(run.status.success(), "{}", text(&run).1);
    let rows = |path: &std::path::Path| -> Vec<Vec<String>> {
        std::fs::read_to_string(path)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(str::to_owned).collect())
            .collect()
    };
    // input, timestamp, time of issue, sequence, latitude, longitude, altitude, accuracy, status
    let fix_rows = rows(&fixes);
    assert_eq!(
        fix_rows.len(),
        expected.len(),
        "a fix for every sentence, lost ones too"
    );
    let (satellites, hdops): (Vec<_>, Vec<_>) = rows(&more).into_iter().partition(|r| r[0] == "in1");
    assert_eq!((satellites.len(), hdops.len()), (expected.len(), expected.len()));
    let number = |text: &str| text.parse::<f64>().unwrap_or(f64::NAN);
    for (index, want) in expected.iter().enumerate() {
        let fix = &fix_rows[index];
        for (column, key) in [(4, "latitude"), (5, "longitude")] {
            match want[key].as_f64() {
                Some(degrees) => assert!(
                    (number(&fix[column]) - degrees).abs() < 1e-9,
                    "{index} {key}: {fix:?} {want}"
                ),
                None => assert!(number(&fix[column]).is_nan(), "{index} {key}: {fix:?}"),
            }
        }
        assert!(
            (number(&fix[6]) - want["altitude"].as_f64().unwrap()).abs() < 1e-6,
            "{index}: {fix:?} {want}"
        );
        assert_eq!(
            fix[8] != "NoFix",
            want["fixed"].as_bool().unwrap(),
            "{index}: {fix:?} {want}"
        );
        assert_eq!(
            satellites[index][4].parse::<i64>().ok(),
            want["satellites"].as_i64(),
            "{index}"
        );
        assert!(
            (number(&hdops[index][4]) - want["hdop"].as_f64().unwrap()).abs() < 1e-9,
            "{index}"
        );
    }
}

/// Packets of each Velodyne model with random distances and reflectivities, written to a pcap capture
/// and decoded by velodyne-decoder; the same capture replayed through `lidar.velodyne` and recorded; the
/// recorded points compared with velodyne-decoder's, point for point in firing order.
#[test]
fn the_velodyne_decoder_agrees_with_velodyne_decoder_for_every_model() {
    let root = common::repo_root();
    // The HDL-32E's model is read from its packets' product id.
    for (model, reference, step, property) in [
        ("VLP-16", "VLP16", 40, "VLP-16"),
        ("VLP-32C", "VLP32C", 20, "VLP-32C"),
        ("HDL-32E", "HDL32E", 17, "auto"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (capture, expected, recording) = (
            dir.path().join("lidar.pcap"),
            dir.path().join("expected.npy"),
            dir.path().join("points.mcap"),
        );
        // 120 packets: a revolution and a half at 600 rpm, the azimuth step jittered by a hundredth.
        python_output(&format!(
            "import struct, random, numpy as np, velodyne_decoder as vd\n\
             random.seed(3)\n\
             product = {{'VLP16': 0x22, 'VLP32C': 0x28, 'HDL32E': 0x21}}['{reference}']\n\
             azimuth, packets = random.randrange(36000), []\n\
             for p in range(120):\n\
             \x20   payload = b''\n\
             \x20   for b in range(12):\n\
             \x20       payload += b'\\xff\\xee' + struct.pack('<H', azimuth)\n\
             \x20       azimuth = (azimuth + {step} + random.choice((-1, 0, 1))) % 36000\n\
             \x20       for m in range(32):\n\
             \x20           units = 0 if random.random() < 0.05 else random.randrange(500, 60000)\n\
             \x20           payload += struct.pack('<HB', units, random.randrange(256))\n\
             \x20   packets.append(payload + struct.pack('<I', p * 1327) + bytes([0x37, product]))\n\
             pcap = struct.pack('<IHHiIII', 0xa1b2c3d4, 2, 4, 0, 0, 65535, 1)\n\
             for p, payload in enumerate(packets):\n\
             \x20   udp = struct.pack('>HHHH', 443, 2368, 8 + len(payload), 0) + payload\n\
             \x20   ip = struct.pack('>BBHHHBBH4s4s', 0x45, 0, 20 + len(udp), p, 0, 64, 17, 0, bytes([192, 168, 1, 201]), bytes([192, 168, 1, 77])) + udp\n\
             \x20   frame = b'\\xff' * 6 + b'\\x60\\x76\\x88\\x00\\x00\\x00' + b'\\x08\\x00' + ip\n\
             \x20   pcap += struct.pack('<IIII', 1700000000, p * 1327, len(frame), len(frame)) + frame\n\
             open('{capture}', 'wb').write(pcap)\n\
             decoder = vd.StreamDecoder(vd.Config(model=vd.Model.{reference}, min_range=0.5, max_range=1000))\n\
             scans = [decoder.decode(p * 0.001327, payload) for p, payload in enumerate(packets)] + [decoder.finish()]\n\
             points = np.concatenate([scan[1] for scan in scans if scan is not None])\n\
             np.save('{expected}', points[:, [0, 1, 2, 3]])",
            capture = capture.display(),
            expected = expected.display(),
        ));
        let diagram = dir.path().join("replay.ron");
        std::fs::write(
            &diagram,
            format!(
                r#"Diagram(format: 1, components: [
                    Component(id: "lidar", type: "lidar.velodyne", properties: {{
                        "source": "pcap", "path": "{}", "replay": "fast", "model": "{property}",
                    }}),
                    Component(id: "recorder", type: "recording.recorder", properties: {{
                        "path": "{}", "compression": "none", "min_free_mb": 0.0,
                    }}),
                ], connections: [
                    Connection(from: "lidar.points", to: "recorder.in1", policy: NeverSkipping),
                ])"#,
                capture.display(),
                recording.display()
            ),
        )
        .unwrap();
        let run = kairos(&root, &["run", diagram.to_str().unwrap(), "--for", "3s"]);
        let (_, stderr) = text(&run);
        assert!(run.status.success(), "{model}: {stderr}");
        let compared = python_output(&format!(
            "import numpy as np\n\
             from mcap.reader import make_reader\n\
             from mcap_protobuf.decoder import DecoderFactory\n\
             ours = []\n\
             with open('{recording}', 'rb') as f:\n\
             \x20   for _, _, _, cloud in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():\n\
             \x20       offsets = {{field.name: field.offset for field in cloud.fields}}\n\
             \x20       raw = np.frombuffer(cloud.data, dtype=np.uint8).reshape(-1, cloud.point_stride)\n\
             \x20       column = lambda name: raw[:, offsets[name]:offsets[name] + 4].copy().view(np.float32)[:, 0]\n\
             \x20       ours.append(np.stack([column('x'), column('y'), column('z'), column('intensity')], axis=1))\n\
             ours = np.concatenate(ours)\n\
             theirs = np.load('{expected}')\n\
             if len(ours) != len(theirs):\n\
             \x20   print(f'{{len(ours)}} points, velodyne-decoder {{len(theirs)}}')\n\
             else:\n\
             \x20   xy = np.hypot(ours[:, 0] - theirs[:, 0], ours[:, 1] - theirs[:, 1])\n\
             \x20   reach = np.hypot(theirs[:, 0], theirs[:, 1])\n\
             \x20   angle = np.degrees(xy / np.maximum(reach, 1e-6))\n\
             \x20   z = np.abs(ours[:, 2] - theirs[:, 2])\n\
             \x20   reach_ours = np.hypot(ours[:, 0], ours[:, 1])\n\
             \x20   print(f'{{len(ours)}} {{angle.max():.6f}} {{np.abs(reach_ours - reach).max():.6f}} {{z.max():.6f}} {{np.abs(np.round(ours[:, 3] * 255) - theirs[:, 3]).max()}}')",
            recording = recording.display(),
            expected = expected.display(),
        ));
        let figures: Vec<f64> = compared
            .split_whitespace()
            .map(|f| f.parse().unwrap_or(f64::NAN))
            .collect();
        eprintln!("{model}: points, azimuth (deg), reach (m), z (m), reflectivity: {compared}");
        let [points, azimuth, reach, z, reflectivity] = figures[..] else {
            panic!("{model}: {compared}");
        };
        assert!(points > 30_000.0, "{model}: {compared}");
        // The same range and elevation, offsets included: reach and height agree to float precision.
        assert!(reach < 2e-4 && z < 2e-4, "{model}: {compared}");
        // The azimuth each firing gets within its block: both interpolate by firing time, Kairos over the
        // gap to the next block as the manuals say, velodyne-decoder over the gap from the previous one,
        // rounded to 0.01° (ROS' tables). They differ by the change of speed between blocks (up to 0.02°
        // in this jittered capture), plus the rounding.
        assert!(azimuth < 0.025, "{model}: {compared}");
        assert!(reflectivity < 0.5, "{model}: {compared}");
    }
}

/// JPEG through libjpeg-turbo (`encoder: libjpeg-turbo`, the system's `libturbojpeg0`, which `tests/run`
/// installs) is OpenCV's `imencode` at the same quality: the same encoder, settings (accurate DCT) and
/// 4:2:0 chroma, so both files decode to the same pixels. The pure-Rust encoder (`encoder: rust`) makes
/// another valid JPEG of the same image, a little less faithful at the same quality (on this noisy image
/// its mean error from the source is 11 % above OpenCV's: docs/vision.md says so).
#[test]
fn jpeg_through_libjpeg_turbo_is_opencv_s_and_the_rust_encoder_is_close() {
    let root = common::repo_root();
    for encoder in ["libjpeg-turbo", "rust"] {
        let dir = tempfile::tempdir().unwrap();
        let (input, recording) = (dir.path().join("in"), dir.path().join("jpeg.mcap"));
        std::fs::create_dir_all(&input).unwrap();
        write_noisy_pattern(&input, 40.0, 2);
        let diagram = dir.path().join("jpeg.ron");
        std::fs::write(
            &diagram,
            format!(
                r#"Diagram(format: 1, components: [
                    Component(id: "images", type: "video.image_sequence", properties: {{"folder": "{}"}}),
                    Component(id: "jpeg", type: "vision.jpeg_encode", properties: {{"quality": 90, "encoder": "{encoder}"}}),
                    Component(id: "recorder", type: "recording.recorder", properties: {{
                        "path": "{}", "compression": "none", "min_free_mb": 0.0,
                    }}),
                ], connections: [
                    Connection(from: "images.image", to: "jpeg.in", policy: NeverSkipping),
                    Connection(from: "jpeg.out", to: "recorder.in1", policy: NeverSkipping),
                ])"#,
                input.display(),
                recording.display()
            ),
        )
        .unwrap();
        let run = kairos(&root, &["run", diagram.to_str().unwrap(), "--for", "1500ms"]);
        let (_, stderr) = text(&run);
        assert!(run.status.success(), "{encoder}: {stderr}");
        assert!(
            stderr.contains(&format!(
                "JPEG encoder: {}",
                if encoder == "rust" {
                    "jpeg-encoder"
                } else {
                    encoder
                }
            )),
            "{stderr}"
        );
        let compared = python_output(&format!(
            "import base64, glob, json, numpy as np, cv2\n\
             from mcap.reader import make_reader\n\
             with open('{recording}', 'rb') as f:\n\
             \x20   ours = next(base64.b64decode(json.loads(m.data)['base64']) for _, _, m in make_reader(f).iter_messages())\n\
             source = cv2.imread(glob.glob('{input}/*.png')[0])\n\
             theirs = cv2.imencode('.jpg', source, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()\n\
             a = cv2.imdecode(np.frombuffer(ours, np.uint8), cv2.IMREAD_COLOR).astype(int)\n\
             b = cv2.imdecode(np.frombuffer(theirs, np.uint8), cv2.IMREAD_COLOR).astype(int)\n\
             s = source.astype(int)\n\
             print(int(np.abs(a - b).max()), float(np.abs(a - s).mean()), float(np.abs(b - s).mean()))",
            recording = recording.display(),
            input = input.display(),
        ));
        let figures: Vec<f64> = compared.split_whitespace().map(|f| f.parse().unwrap()).collect();
        // Most difference from OpenCV's pixels; mean error from the source, ours and OpenCV's.
        if encoder == "rust" {
            assert!(figures[1] < 1.15 * figures[2], "{encoder}: {compared}");
        } else {
            assert!(figures[0] < 0.5, "{encoder}: {compared}");
        }
    }
}

/// Canny on a grey photograph-like image (smooth shapes under noise, edges in every direction) is
/// OpenCV's `Canny(grey, 50, 150)` (L1 gradient, 3×3 Sobel), edge for edge.
#[test]
fn canny_is_opencv_s_edge_for_edge() {
    let root = common::repo_root();
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("in"), dir.path().join("out"));
    std::fs::create_dir_all(&input).unwrap();
    python_output(&format!(
        "import numpy as np, cv2\n\
         y, x = np.mgrid[0:240, 0:320]\n\
         base = 127 + 90 * np.sin(x / 13.0 + y / 29.0) * np.cos(y / 11.0)\n\
         base[60:180, 80:200] += 60\n\
         base[(x - 240) ** 2 + (y - 120) ** 2 < 50 ** 2] -= 80\n\
         noise = np.random.default_rng(5).normal(0, 12, (240, 320))\n\
         cv2.imwrite('{}/1795575410804363450_00000000.png', np.clip(base + noise, 0, 255).astype(np.uint8))",
        input.display()
    ));
    let diagram = dir.path().join("canny.ron");
    std::fs::write(
        &diagram,
        format!(
            r#"Diagram(format: 1, components: [
                Component(id: "images", type: "video.image_sequence", properties: {{"folder": "{}"}}),
                Component(id: "edges", type: "vision.canny", properties: {{"low": 50, "high": 150}}),
                Component(id: "out", type: "video.image_writer", properties: {{"folder": "{}"}}),
            ], connections: [
                Connection(from: "images.image", to: "edges.in", policy: NeverSkipping),
                Connection(from: "edges.out", to: "out.image"),
            ])"#,
            input.display(),
            output.display()
        ),
    )
    .unwrap();
    let run = kairos(&root, &["run", diagram.to_str().unwrap(), "--for", "1500ms"]);
    assert!(run.status.success(), "{}", text(&run).1);
    let compared = python_output(&format!(
        "import glob, numpy as np, cv2\n\
         source = cv2.imread(glob.glob('{}/*.png')[0], cv2.IMREAD_GRAYSCALE)\n\
         ours = cv2.imread(sorted(glob.glob('{}/*.png'))[0], cv2.IMREAD_GRAYSCALE)\n\
         theirs = cv2.Canny(source, 50, 150)\n\
         print(int((ours != theirs).sum()), int((theirs > 0).sum()))",
        input.display(),
        output.display()
    ));
    let figures: Vec<u64> = compared.split_whitespace().map(|f| f.parse().unwrap()).collect();
    assert!(figures[1] > 2_000, "an image with many edges: {compared}");
    assert_eq!(
        figures[0], 0,
        "pixels that differ from OpenCV's, of its edge pixels: {compared}"
    );
}

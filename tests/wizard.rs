//! `kairos new` as a developer uses it: a pack with two components (one threaded, one reactive) generated,
//! built with cargo, loaded by the runtime from its library and run in a diagram with the core pack; and
//! answers that are refused before anything is written.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::path::Path;
use std::process::Command;

use common::{kairos, text};

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .parent()
        .unwrap()
}

/// A reactive image pass-through with a property and an action, a periodic text source, a sink of
/// anything, a conversion with no algorithm yet, an empty component, and one asked for interactively: each
/// must render into code that builds, is formatted and passes clippy.
fn generate_components_of_every_shape(dir: &Path, pack: &Path) {
    for args in [
        &[
            "blur",
            "--input",
            "image:image",
            "--output",
            "out:image",
            "--property",
            "radius:i64=3",
            "--action",
            "reset",
            "--mode",
            "reactive",
        ][..],
        &["ticker", "--output", "tick:text", "--mode", "periodic"],
        &["sink", "--input", "in:any"],
        &["convert", "--input", "in:i64", "--output", "out:bool"],
        &["empty"],
    ] {
        let mut full = vec!["new", "component", "--pack", "lab"];
        full.extend_from_slice(args);
        let made = kairos(dir, &full);
        assert!(made.status.success(), "{args:?}: {:?}", text(&made));
    }
    let mut asked = Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["new", "component"])
        .current_dir(dir)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    {
        use std::io::Write as _;
        let mut answers = asked.stdin.take().unwrap();
        // A refused name and a refused default are asked again, with the reason.
        answers
            .write_all(b"Smooth\nsmooth\nlab\nreactive\nin:f64\nout:f64\nwindow:i64=five\nwindow:i64=5\n\n")
            .unwrap();
    }
    let asked = asked.wait_with_output().unwrap();
    let (stdout, _) = text(&asked);
    assert!(asked.status.success(), "{stdout}");
    assert!(
        stdout.contains("try 'smooth'") && stdout.contains("not a whole number"),
        "{stdout}"
    );
    assert!(pack.join("src/smooth.rs").is_file());
}

/// Runs the generated pack's tests, clippy and rustfmt, and builds its library; returns the target folder.
fn build_test_and_lint(pack: &Path) -> std::path::PathBuf {
    // The workspace's lock pins the same dependency versions, so the build reuses what is compiled.
    std::fs::copy(workspace().join("Cargo.lock"), pack.join("Cargo.lock")).unwrap();
    let target = workspace().join("target").join("wizard");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned());
    let built = Command::new(&cargo)
        .args(["test", "--offline", "--quiet"])
        .env("CARGO_TARGET_DIR", &target)
        .current_dir(pack)
        .output()
        .unwrap();
    assert!(
        built.status.success(),
        "the generated pack's tests: {:?}",
        text(&built)
    );
    let linted = Command::new(&cargo)
        .args([
            "clippy",
            "--offline",
            "--quiet",
            "--all-targets",
            "--",
            "-D",
            "warnings",
        ])
        .env("CARGO_TARGET_DIR", &target)
        .current_dir(pack)
        .output()
        .unwrap();
    assert!(
        linted.status.success(),
        "clippy on the generated pack: {:?}",
        text(&linted)
    );
    let formatted = Command::new("rustfmt")
        .args(["--edition", "2024", "--check"])
        .args(
            std::fs::read_dir(pack.join("src"))
                .unwrap()
                .flatten()
                .map(|e| e.path()),
        )
        .output();
    if let Ok(formatted) = formatted {
        assert!(
            formatted.status.success(),
            "rustfmt --check: {:?}",
            text(&formatted)
        );
    }
    let built = Command::new(&cargo)
        .args(["build", "--offline", "--quiet"])
        .env("CARGO_TARGET_DIR", &target)
        .current_dir(pack)
        .output()
        .unwrap();
    assert!(built.status.success(), "{:?}", text(&built));

    target
}

/// Runs `diagram` (its text) for a second in `dir` with the pack libraries in `packs`, and returns the CSV
/// file it wrote (`csv`, relative to `dir`).
fn run_for_a_second(dir: &Path, packs: &Path, diagram: &str, csv: &str) -> String {
    let file = dir.join("diagram.ron");
    std::fs::write(&file, diagram).unwrap();
    let ran = kairos(
        dir,
        &[
            "--pack-path",
            packs.to_str().unwrap(),
            "run",
            file.to_str().unwrap(),
            "--for",
            "1s",
        ],
    );
    assert!(ran.status.success(), "{:?}", text(&ran));
    std::fs::read_to_string(dir.join(csv)).unwrap()
}

#[test]
fn a_generated_pack_builds_loads_and_runs() {
    let dir = tempfile::tempdir().unwrap();
    let made = kairos(dir.path(), &["new", "pack", "lab"]);
    assert!(made.status.success(), "{:?}", text(&made));
    let pack = dir.path().join("lab");
    let made = kairos(
        dir.path(),
        &[
            "new",
            "component",
            "amplify",
            "--pack",
            "lab",
            "--input",
            "in:f64",
            "--output",
            "out:f64",
            "--property",
            "gain:f64=10.0",
            "--mode",
            "reactive",
        ],
    );
    assert!(made.status.success(), "{:?}", text(&made));
    generate_components_of_every_shape(dir.path(), &pack);
    let target = build_test_and_lint(&pack);

    // The runtime loads the library and runs a constant 1.5 → lab.scale (× 2) → lab.amplify (× 10) → CSV: the
    // generated components multiply by their first number property until their algorithm is written.
    let libraries = dir.path().join("packs");
    std::fs::create_dir_all(&libraries).unwrap();
    let library = std::fs::read_dir(target.join("debug"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.file_name().is_some_and(|n| n == "libkairos_pack_lab.so"))
        .expect("the pack's shared library");
    std::fs::copy(&library, libraries.join("libkairos_pack_lab.so")).unwrap();
    let pack_path = libraries.to_str().unwrap();
    let components = kairos(dir.path(), &["--pack-path", pack_path, "components", "lab."]);
    let (stdout, stderr) = text(&components);
    assert!(
        stdout.contains("lab.scale") && stdout.contains("lab.amplify"),
        "{stdout}{stderr}"
    );
    let csv = run_for_a_second(
        dir.path(),
        &libraries,
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "lab", version: "^0.1")],
    components: [
        Component(id: "csv", type: "core.csv_writer", position: (x: 0.0, y: 0.0), properties: {"path": "lab.csv"}),
        Component(id: "amplify", type: "lab.amplify", position: (x: 0.0, y: 0.0)),
        Component(id: "scale", type: "lab.scale", position: (x: 0.0, y: 0.0)),
        Component(id: "wave", type: "core.constant", position: (x: 0.0, y: 0.0), properties: {"value": 1.5, "rate": 50.0}),
    ],
    connections: [
        Connection(from: "amplify.out", to: "csv.in1"),
        Connection(from: "scale.out", to: "amplify.in"),
        Connection(from: "wave.out", to: "scale.in"),
    ],
)
"#,
        "lab.csv",
    );
    let values: Vec<f64> = csv
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next_back()?.trim().parse().ok())
        .collect();
    assert!(!values.is_empty(), "no value: {csv}");
    assert!(
        values.iter().all(|v| (v - 30.0).abs() < 1e-9),
        "1.5 × 2 × 10 = 30: {csv}"
    );
}

#[test]
fn bad_answers_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    for (args, expected) in [
        (vec!["new", "pack", "core"], "built-in pack"),
        (vec!["new", "pack", "My-Pack"], "try 'my_pack'"),
    ] {
        let refused = kairos(dir.path(), &args);
        let (_, stderr) = text(&refused);
        assert!(!refused.status.success());
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "nothing written"
    );
    assert!(kairos(dir.path(), &["new", "pack", "lab"]).status.success());
    let before = std::fs::read_to_string(dir.path().join("lab/src/lib.rs")).unwrap();
    for (args, expected) in [
        (vec!["--input", "in:f46"], "did you mean 'f64'?"),
        (vec!["--property", "gain:f64=two"], "not a number"),
        (vec!["--property", "gain=2"], "has no type"),
        (
            vec!["--input", "a:f64", "--output", "a:f64"],
            "two ports are named 'a'",
        ),
        (vec!["--mode", "reactive"], "give it an --input"),
    ] {
        let mut full = vec!["new", "component", "thing", "--pack", "lab"];
        full.extend(args.iter());
        let refused = kairos(dir.path(), &full);
        let (_, stderr) = text(&refused);
        assert!(!refused.status.success());
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
    let refused = kairos(dir.path(), &["new", "component", "match", "--pack", "lab"]);
    assert!(text(&refused).1.contains("keyword"));
    assert!(!dir.path().join("lab/src/thing.rs").exists());
    assert_eq!(
        std::fs::read_to_string(dir.path().join("lab/src/lib.rs")).unwrap(),
        before
    );
    // The example exists: a second one is refused, and nothing is overwritten without --force.
    let again = kairos(dir.path(), &["new", "component", "scale", "--pack", "lab"]);
    assert!(text(&again).1.contains("already has a component 'scale'"));
    let again = kairos(dir.path(), &["new", "pack", "lab"]);
    assert!(text(&again).1.contains("--force"));
}

#[test]
fn a_generated_cpp_pack_builds_with_make_and_runs() {
    let dir = tempfile::tempdir().unwrap();
    let made = kairos(dir.path(), &["new", "pack", "native", "--lang", "cpp"]);
    assert!(made.status.success(), "{:?}", text(&made));
    let made = kairos(
        dir.path(),
        &[
            "new",
            "component",
            "ticks",
            "--pack",
            "native",
            "--output",
            "n:i64",
            "--mode",
            "periodic",
        ],
    );
    assert!(made.status.success(), "{:?}", text(&made));
    // The other shapes of the C++ template must build too: a pass-through with an action, a sink.
    for args in [
        &[
            "frames",
            "--input",
            "in:image",
            "--output",
            "out:image",
            "--action",
            "reset",
            "--mode",
            "reactive",
        ][..],
        &["drain", "--input", "in:any"],
    ] {
        let mut full = vec!["new", "component", "--pack", "native"];
        full.extend_from_slice(args);
        let made = kairos(dir.path(), &full);
        assert!(made.status.success(), "{args:?}: {:?}", text(&made));
    }
    let built = Command::new("make")
        .current_dir(dir.path().join("native"))
        .output()
        .expect("make (the C++ pack's build file)");
    assert!(built.status.success(), "{:?}", text(&built));
    let csv = run_for_a_second(
        dir.path(),
        &dir.path().join("native/build"),
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "native", version: "^0.1")],
    components: [
        Component(id: "csv", type: "core.csv_writer", position: (x: 0.0, y: 0.0), properties: {"path": "native.csv"}),
        Component(id: "scale", type: "native.scale", position: (x: 0.0, y: 0.0)),
        Component(id: "ticks", type: "native.ticks", position: (x: 0.0, y: 0.0)),
        Component(id: "wave", type: "core.constant", position: (x: 0.0, y: 0.0), properties: {"value": 1.5, "rate": 50.0}),
    ],
    connections: [
        Connection(from: "scale.out", to: "csv.in1"),
        Connection(from: "ticks.n", to: "csv.in2"),
        Connection(from: "wave.out", to: "scale.in"),
    ],
)
"#,
        "native.csv",
    );
    let scaled: Vec<f64> = csv
        .lines()
        .filter(|l| l.starts_with("in1,"))
        .filter_map(|l| l.split(',').next_back()?.trim().parse().ok())
        .collect();
    let ticks = csv.lines().filter(|l| l.starts_with("in2,")).count();
    assert!(
        !scaled.is_empty() && scaled.iter().all(|v| (v - 3.0).abs() < 1e-9),
        "{csv}"
    );
    assert!(ticks >= 1, "the periodic C++ component ticks: {csv}");
}

#[test]
fn a_generated_python_pack_passes_its_tests_and_runs() {
    let dir = tempfile::tempdir().unwrap();
    let made = kairos(dir.path(), &["new", "pack", "py_made", "--lang", "python"]);
    assert!(made.status.success(), "{}", text(&made).1);
    for args in [
        &[
            "smoother", "--input", "in:f64", "--output", "out:f64", "--action", "reset",
        ][..],
        &["ticker", "--mode", "periodic", "--output", "out:text"][..],
        &["sink", "--input", "in:any"][..],
        // The README's own: an image in, an image out.
        &["blur", "--input", "image:image", "--output", "blurred:image"][..],
        &["words", "--input", "in:text", "--output", "out:text"][..],
        &["gains", "--input", "in:vector", "--output", "out:vector"][..],
        &["frames", "--input", "in:can_frame", "--output", "out:can_frame"][..],
        &["fixes", "--input", "in:gnss_fix"][..],
        &["motion", "--input", "in:imu", "--output", "out:f64"][..],
        &[
            "cloud",
            "--input",
            "in:point_cloud",
            "--output",
            "out:point_cloud",
        ][..],
    ] {
        let mut command = vec!["new", "component"];
        command.extend_from_slice(args);
        command.extend_from_slice(&["--pack", "py_made", "--lang", "python"]);
        let output = kairos(dir.path(), &command);
        let (stdout, stderr) = text(&output);
        assert!(output.status.success(), "{args:?}: {stderr}");
        // How to test it, and the environment first where the pack has none yet.
        assert!(
            stdout.contains(&format!(
                "cd py_made && .venv/bin/python -m pytest test_{}.py",
                args[0]
            )) && stdout.contains("python3 -m venv .venv"),
            "{stdout}"
        );
    }
    let mismatch = kairos(
        dir.path(),
        &["new", "component", "other", "--pack", "py_made", "--lang", "rust"],
    );
    assert!(!mismatch.status.success());
    assert!(
        text(&mismatch).1.contains("is a Python pack, not Rust"),
        "{}",
        text(&mismatch).1
    );

    // The generated tests pass on the offline harness, in the environment the wizard says how to make,
    // by its printed commands as they are.
    let printed = text(&made).0;
    let steps: Vec<&str> = printed
        .lines()
        .filter_map(|line| line.strip_prefix("  cd "))
        .collect();
    assert_eq!(steps.len(), 2, "make the environment, then test: {printed}");
    let mut pytest_output = String::new();
    for step in steps {
        let output = Command::new("sh")
            .args(["-c", &format!("cd {step}")])
            .current_dir(dir.path())
            .output()
            .unwrap();
        let (stdout, stderr) = text(&output);
        assert!(output.status.success(), "cd {step}: {stdout}{stderr}");
        pytest_output = stdout;
    }
    // Every generated test pushes a sample of its first input's type: none passes by doing nothing.
    assert!(pytest_output.contains("11 passed"), "{pytest_output}");

    // A component made once the environment is there: its own printed test line, as printed.
    let extra = kairos(
        dir.path(),
        &[
            "new",
            "component",
            "extra",
            "--input",
            "in:f64",
            "--pack",
            "py_made",
            "--lang",
            "python",
        ],
    );
    let printed = text(&extra).0;
    let steps: Vec<&str> = printed
        .lines()
        .filter_map(|line| line.strip_prefix("  cd "))
        .collect();
    assert_eq!(
        steps,
        ["py_made && .venv/bin/python -m pytest test_extra.py"],
        "{printed}"
    );
    let output = Command::new("sh")
        .args(["-c", &format!("cd {}", steps[0])])
        .current_dir(dir.path())
        .output()
        .unwrap();
    let (stdout, stderr) = text(&output);
    assert!(stdout.contains("1 passed"), "{stdout}{stderr}");

    // And the pack runs in a diagram: a constant scaled by the example component, printed.
    let diagram = r#"Diagram(format: 1, components: [
        Component(id: "counter", type: "core.constant", properties: {"rate": 50.0, "value": 1.5}),
        Component(id: "scale", type: "py_made.scale"),
        Component(id: "console", type: "core.console", properties: {"every": 1}),
    ], connections: [
        Connection(from: "counter.out", to: "scale.in"),
        Connection(from: "scale.out", to: "console.in"),
    ])"#;
    std::fs::write(dir.path().join("d.ron"), diagram).unwrap();
    // Time for the Python worker to start and scale a few values, even on a slow machine.
    let run = kairos(dir.path(), &["run", "d.ron", "--pack-path", ".", "--for", "5s"]);
    let (stdout, stderr) = text(&run);
    assert!(run.status.success(), "{stderr}");
    let printed = stdout + &stderr;
    assert!(printed.contains(" 3\n"), "1.5 scaled by 2.0: {printed}");
}

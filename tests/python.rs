//! Components written in Python: packs of `.py` files found on the pack path, each instance running in a
//! worker process of its own, driven by the engine like any other component.
//!
//! These tests need `python3` with numpy first on the `PATH`: `tests/run` puts its virtual environment there.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]
#![allow(
    clippy::float_cmp,
    reason = "the values compared are small integers times exact factors: equal to the bit"
)]

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{kairos, repo_root, text};
use kairos_runtime::{ComponentState, Engine, PackScan};
use kairos_sdk_core::host::{Reader, ReaderConfig};
use kairos_sdk_core::{Payload, ReaderPolicy, RealTimeClock, Registry, RunSignal, Sample, Value};

/// Components that misbehave on purpose, and small ones to check the runtime's side.
const TEST_COMPONENTS: &str = r#"
from kairos_sdk import F64, I64, Component, Descriptor, Property

NUMBERS = (F64, I64)


class Divide(Component):
    descriptor = Descriptor("divide", doc="Fails on the fifth sample").input("in", NUMBERS).output("out", F64)

    def birth(self, ctx):
        self.count = 0

    def core(self, ctx):
        sample = ctx.read("in")
        self.count += 1
        ctx.write_processed("out", sample, sample.data / (5 - self.count))


class WritesText(Component):
    descriptor = Descriptor("writes_text").input("in", NUMBERS).output("out", F64)

    def core(self, ctx):
        ctx.read("in")
        ctx.write("out", "not a number")


class Endless(Component):
    descriptor = Descriptor("endless").input("in", NUMBERS)

    def core(self, ctx):
        ctx.read("in")
        while True:
            pass


class Waits(Component):
    descriptor = Descriptor("waits").input("in", NUMBERS)

    def core(self, ctx):
        ctx.read("in")


class Scale(Component):
    descriptor = (
        Descriptor("scale").input("in", NUMBERS).output("out", F64)
        .property(Property.f64("factor", 1.0).range(-10, 10).live())
        .action("negate")
    )

    def birth(self, ctx):
        self.sign = 1.0

    def action(self, name, ctx):
        self.sign = -self.sign

    def core(self, ctx):
        sample = ctx.read("in")
        ctx.write_processed("out", sample, self.sign * ctx.property("factor") * sample.data)


class Pair(Component):
    descriptor = Descriptor("pair").input("a", NUMBERS).input("b", NUMBERS).output("difference", F64)

    def core(self, ctx):
        a, b = ctx.read_synchronized(["a", "b"], tolerance=0.001)
        ctx.write_processed("difference", a, float(a.data - b.data))
"#;

const CONSTANT: &str = r#"
from kairos_sdk import F64, I64, Component, Descriptor

VALUE = 1.0


class Constant(Component):
    descriptor = Descriptor("constant").input("in", (F64, I64)).output("out", F64)

    def core(self, ctx):
        ctx.write_processed("out", ctx.read("in"), VALUE)
"#;

fn require_numpy() {
    let found = std::process::Command::new("python3")
        .args(["-c", "import numpy"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        found,
        "these tests need python3 with numpy first on the PATH: run them with tests/run"
    );
}

/// Writes a Python pack `name` into `dir` with `files`; its folder.
fn write_pack(dir: &Path, name: &str, files: &[(&str, &str)]) -> PathBuf {
    let folder = dir.join(name);
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(
        folder.join("kairos-pack.toml"),
        format!("[pack]\nname = \"{name}\"\nversion = \"0.1.0\"\n"),
    )
    .unwrap();
    for (file, text) in files {
        std::fs::write(folder.join(file), text).unwrap();
    }
    folder
}

/// The built-in core and sensors packs and the packs on `folders`.
fn registry_with(folders: &[PathBuf]) -> (Registry, PackScan) {
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    kairos_pack_sensors::register(&mut registry);
    let scan = kairos_runtime::load_packs(&mut registry, folders);
    (registry, scan)
}

fn engine(registry: &Registry, diagram: &str) -> Engine {
    let parsed = kairos_diagram::parse(diagram).unwrap();
    Engine::build(&parsed.diagram, registry, RealTimeClock::shared()).unwrap()
}

/// A reader of every sample (its writer waits for it when it falls behind).
fn reader(engine: &Engine, component: &str, output: &str) -> Reader {
    reader_with(engine, component, output, ReaderPolicy::NeverSkipping)
}

fn reader_with(engine: &Engine, component: &str, output: &str, policy: ReaderPolicy) -> Reader {
    engine.output_buffer(component, output).unwrap().attach(
        ReaderConfig::new(policy, format!("{component}.{output} -> test")),
        Arc::new(RunSignal::new()),
    )
}

fn state(engine: &Engine, id: &str) -> ComponentState {
    engine
        .snapshot()
        .components
        .iter()
        .find(|c| c.id == id)
        .unwrap()
        .state
        .clone()
}

fn status(engine: &Engine, id: &str) -> serde_json::Value {
    let snapshot = engine.snapshot();
    let component = snapshot.components.iter().find(|c| c.id == id).unwrap();
    component.status.clone().unwrap_or_default()
}

fn cycles(engine: &Engine, id: &str) -> u64 {
    engine
        .snapshot()
        .components
        .iter()
        .find(|c| c.id == id)
        .unwrap()
        .cycles
}

fn wait_for(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let started = Instant::now();
    while started.elapsed() < timeout {
        if done() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    done()
}

fn read_n(reader: &mut Reader, count: usize) -> Vec<Sample> {
    (0..count).map(|_| reader.read(false).unwrap()).collect()
}

/// The samples of a source, to find the one a Python component's output sample came from: the component
/// starts after its source, so the first samples may be passed over, and samples are matched by timestamp.
#[derive(Default)]
struct Originals(std::collections::HashMap<kairos_sdk_core::Timestamp, Sample>);

impl Originals {
    /// The next sample of `through` and the sample of `source` with its timestamp. `source` should be a
    /// NeverSkipping reader: every sample is then found.
    fn pair(&mut self, source: &mut Reader, through: &mut Reader) -> (Sample, Sample) {
        let through = through.read(false).unwrap();
        while !self.0.contains_key(&through.timestamp) {
            let original = source.read(false).unwrap();
            self.0.insert(original.timestamp, original);
        }
        (self.0[&through.timestamp].clone(), through)
    }
}

fn f64_of(sample: &Sample) -> f64 {
    sample.payload.as_f64().unwrap()
}

fn counter_into(component: &str, input: &str, rate: f64) -> String {
    format!(
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {{"rate": {rate:?}}}),
            Component(id: "x", type: "{component}"),
        ], connections: [Connection(from: "counter.out", to: "x.{input}")])"#
    )
}

#[test]
fn a_python_pass_through_forwards_numbers_with_their_times_and_images_without_a_copy() {
    require_numpy();
    let (registry, scan) = registry_with(&[repo_root().join("examples/python/packs")]);
    assert!(scan.refused.is_empty(), "{:?}", scan.refused);
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 200.0}),
            Component(id: "numbers", type: "py_vision.pass_through"),
            Component(id: "camera", type: "sensors.camera", properties: {"rate": 30.0, "width": 1280, "height": 720}),
            Component(id: "images", type: "py_vision.pass_through"),
            Component(id: "threshold", type: "py_vision.threshold", properties: {"green_min": 100}),
        ], connections: [
            Connection(from: "counter.out", to: "numbers.in"),
            Connection(from: "camera.image", to: "images.in"),
            Connection(from: "camera.image", to: "threshold.image"),
        ])"#,
    );
    let mut counted = reader(&engine, "counter", "out");
    let mut passed = reader(&engine, "numbers", "out");
    // Readers that never slow the camera: the test reads the three streams one after the other.
    let mut camera = reader_with(&engine, "camera", "image", ReaderPolicy::Fifo);
    let mut images = reader_with(&engine, "images", "out", ReaderPolicy::Fifo);
    let mut masks = reader_with(&engine, "threshold", "mask", ReaderPolicy::Fifo);
    engine.start().unwrap();

    let mut originals = Originals::default();
    for _ in 0..50 {
        let (original, through) = originals.pair(&mut counted, &mut passed);
        assert_eq!(
            through.payload, original.payload,
            "the timestamp travels unchanged with its value"
        );
        assert!(through.time_of_issue >= original.time_of_issue);
    }
    // The pass-through's frames are a subsequence of the camera's: walk the camera's stream up to each
    // frame that came through. A frame the camera reader has already passed (it started later, or lost
    // its oldest to the ring while the numbers were read) is skipped, never counted as a mismatch.
    let mut matched = 0;
    let mut latest = camera.read(false).unwrap();
    for _ in 0..30 {
        let through = images.read(false).unwrap();
        while latest.timestamp < through.timestamp {
            latest = camera.read(false).unwrap();
        }
        if latest.timestamp != through.timestamp {
            continue;
        }
        let (Payload::Image(original), Payload::Image(through)) = (&latest.payload, &through.payload) else {
            panic!("images in, images out");
        };
        assert!(
            original.pixels.ptr_eq(&through.pixels),
            "the pass-through writes the very pixels it read"
        );
        matched += 1;
        if matched == 10 {
            break;
        }
    }
    assert!(matched >= 5, "{matched} of 30 images found among the camera's");
    for mask in read_n(&mut masks, 5) {
        let Payload::Image(mask) = &mask.payload else {
            panic!("a mask is an image");
        };
        assert_eq!(
            (mask.width, mask.height, mask.format),
            (1280, 720, kairos_sdk_core::PixelFormat::Gray8)
        );
        assert!(mask.pixels.shared_reference().is_some(), "drawn in shared memory");
        assert!(mask.pixels.iter().all(|p| *p == 0 || *p == 255));
        assert!(
            mask.pixels.contains(&255) && mask.pixels.contains(&0),
            "the scene is partly green"
        );
    }
    assert!(wait_for(Duration::from_secs(30), || {
        status(&engine, "images")["python"]["images"]
            .as_u64()
            .is_some_and(|n| n >= 10)
    }));
    for id in ["images", "threshold"] {
        assert_eq!(
            status(&engine, id)["python"]["pixels_copied_bytes"],
            0,
            "{id}: no pixel copied either way"
        );
    }
    engine.stop();
    for id in ["numbers", "images", "threshold"] {
        assert_eq!(state(&engine, id), ComponentState::Stopped, "{id}");
    }
}

#[test]
fn properties_actions_and_synchronised_reads_reach_the_python_code() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(dir.path(), "py_test", &[("components.py", TEST_COMPONENTS)]);
    let (registry, scan) = registry_with(&[dir.path().to_owned()]);
    assert!(scan.refused.is_empty(), "{:?}", scan.refused);
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 200.0, "start": 1}),
            Component(id: "scale", type: "py_test.scale", properties: {"factor": 2.0}),
            Component(id: "pair", type: "py_test.pair"),
        ], connections: [
            Connection(from: "counter.out", to: "scale.in"),
            Connection(from: "counter.out", to: "pair.a"),
            Connection(from: "counter.out", to: "pair.b"),
        ])"#,
    );
    let mut counted = reader(&engine, "counter", "out");
    let mut scaled = reader(&engine, "scale", "out");
    let mut differences = reader(&engine, "pair", "difference");
    engine.start().unwrap();
    let mut originals = Originals::default();
    let first: Vec<(f64, f64)> = (0..5)
        .map(|_| {
            let (original, through) = originals.pair(&mut counted, &mut scaled);
            (f64_of(&original), f64_of(&through))
        })
        .collect();
    assert!(first.iter().all(|(c, s)| *s == 2.0 * c), "{first:?}");

    engine.set_property("scale", "factor", &Value::F64(3.0)).unwrap();
    engine.trigger_action("scale", "negate").unwrap();
    assert!(
        wait_for(Duration::from_secs(30), || {
            let (original, through) = originals.pair(&mut counted, &mut scaled);
            let (c, s) = (f64_of(&original), f64_of(&through));
            s == -3.0 * c
        }),
        "the new factor and the action apply"
    );
    // Readers that never skip hold the counter back once full: let go of those no longer read.
    drop((counted, scaled));
    for difference in read_n(&mut differences, 20) {
        assert_eq!(f64_of(&difference), 0.0, "matched samples of one stream");
    }
    engine.stop();
}

#[test]
fn python_components_run_inside_an_execution_group_in_order_and_lose_nothing() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(dir.path(), "py_test", &[("components.py", TEST_COMPONENTS)]);
    let (registry, scan) = registry_with(&[dir.path().to_owned()]);
    assert!(scan.refused.is_empty(), "{:?}", scan.refused);
    // The counter, a Python scale and a Python synchronised pair share one thread.
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 200.0, "start": 1}, group: "py"),
            Component(id: "scale", type: "py_test.scale", properties: {"factor": 2.0}, group: "py"),
            Component(id: "pair", type: "py_test.pair", group: "py"),
        ], connections: [
            Connection(from: "counter.out", to: "scale.in"),
            Connection(from: "counter.out", to: "pair.a"),
            Connection(from: "counter.out", to: "pair.b"),
        ])"#,
    );
    let mut scaled = reader(&engine, "scale", "out");
    engine.start().unwrap();
    // Every count, in order, twice over, from the first.
    let values: Vec<f64> = read_n(&mut scaled, 50).iter().map(f64_of).collect();
    let expected: Vec<f64> = (1..=50).map(|n| 2.0 * f64::from(n)).collect();
    assert_eq!(values, expected);
    // A NeverSkipping reader that is not read holds its writer, and with it the writer's whole group:
    // the test reads one stream at a time.
    drop(scaled);
    let mut differences = reader(&engine, "pair", "difference");
    for difference in read_n(&mut differences, 20) {
        assert_eq!(f64_of(&difference), 0.0, "matched samples of one stream");
    }
    let snapshot = engine.snapshot();
    engine.stop();
    let group = snapshot.groups.iter().find(|g| g.name == "py").unwrap();
    assert_eq!(group.members, ["counter", "scale", "pair"], "{group:?}");
    for id in ["scale", "pair"] {
        let component = snapshot.components.iter().find(|c| c.id == id).unwrap();
        assert!(
            matches!(component.state, ComponentState::Running),
            "{id}: {:?}",
            component.state
        );
        assert_eq!(component.group.as_deref(), Some("py"));
    }
    for id in ["scale", "pair"] {
        assert_eq!(state(&engine, id), ComponentState::Stopped, "{id}");
    }
}

#[test]
fn an_exception_in_core_fails_that_component_alone_with_its_traceback() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let folder = write_pack(dir.path(), "py_test", &[("components.py", TEST_COMPONENTS)]);
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 200.0}),
            Component(id: "divide", type: "py_test.divide"),
            Component(id: "text", type: "py_test.writes_text"),
            Component(id: "gain", type: "core.gain"),
        ], connections: [
            Connection(from: "counter.out", to: "divide.in"),
            Connection(from: "counter.out", to: "text.in"),
            Connection(from: "counter.out", to: "gain.in"),
        ])"#,
    );
    engine.start().unwrap();
    assert!(wait_for(Duration::from_secs(30), || {
        matches!(state(&engine, "divide"), ComponentState::Failed(_))
            && matches!(state(&engine, "text"), ComponentState::Failed(_))
    }));
    let ComponentState::Failed(error) = state(&engine, "divide") else {
        unreachable!()
    };
    let file = folder.join("components.py").canonicalize().unwrap();
    assert!(error.contains("ZeroDivisionError"), "{error}");
    assert!(error.contains("Traceback (most recent call last)"), "{error}");
    let line = line_of(TEST_COMPONENTS, "sample.data / (5 - self.count)");
    assert!(
        error.contains(&format!("{}:{line}", file.display())) && error.contains("in core"),
        "the file and line where it happened: {error}"
    );
    assert!(
        !error.contains("kairos_sdk"),
        "the SDK's own frames are left out: {error}"
    );
    let ComponentState::Failed(error) = state(&engine, "text") else {
        unreachable!()
    };
    assert!(
        error.contains("output 'out' carries f64: got str 'not a number'"),
        "the port and the type named: {error}"
    );
    let before = cycles(&engine, "gain");
    assert!(
        wait_for(Duration::from_secs(30), || cycles(&engine, "gain") > before + 20),
        "the rest keeps running"
    );
    assert_eq!(state(&engine, "gain"), ComponentState::Running);
    engine.stop();
}

#[test]
fn an_endless_loop_in_python_does_not_hold_the_stop_and_its_process_is_ended() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(dir.path(), "py_test", &[("components.py", TEST_COMPONENTS)]);
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    let mut engine = engine(&registry, &counter_into("py_test.endless", "in", 100.0));
    engine.start().unwrap();
    let pid = wait_for_pid(&engine, "x");
    std::thread::sleep(Duration::from_millis(300));
    let stopping = Instant::now();
    engine.stop();
    let took = stopping.elapsed();
    assert!(
        took < Duration::from_secs(4),
        "stopped in {took:?}: the grace period is 2 s"
    );
    assert!(
        took >= Duration::from_secs(2),
        "the code was given its grace period: {took:?}"
    );
    assert!(!process_exists(pid), "the worker process {pid} was ended");
}

#[test]
fn a_python_process_killed_fails_its_component_within_a_second() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(dir.path(), "py_test", &[("components.py", TEST_COMPONENTS)]);
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    // One sample every 10 s: the component sits waiting for data, the hardest place to notice a death.
    let mut engine = engine(&registry, &counter_into("py_test.waits", "in", 0.1));
    engine.start().unwrap();
    let pid = wait_for_pid(&engine, "x");
    std::thread::sleep(Duration::from_millis(200));
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(pid as i32),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    let killed = Instant::now();
    assert!(wait_for(Duration::from_secs(1), || matches!(
        state(&engine, "x"),
        ComponentState::Failed(_)
    )));
    let noticed = killed.elapsed();
    let ComponentState::Failed(error) = state(&engine, "x") else {
        panic!("failed within 1 s");
    };
    assert!(error.contains("was killed by SIGKILL"), "{error}");
    assert!(noticed < Duration::from_secs(1), "{noticed:?}");
    assert_eq!(state(&engine, "counter"), ComponentState::Running);
    engine.stop();
}

#[test]
fn editing_a_component_file_while_it_runs_reloads_that_component_alone() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let folder = write_pack(dir.path(), "py_live", &[("constant.py", CONSTANT)]);
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 100.0}),
            Component(id: "constant", type: "py_live.constant"),
            Component(id: "gain", type: "core.gain"),
        ], connections: [
            Connection(from: "counter.out", to: "constant.in"),
            Connection(from: "counter.out", to: "gain.in"),
        ])"#,
    );
    let mut constant = reader(&engine, "constant", "out");
    engine.start().unwrap();
    assert_eq!(f64_of(&constant.read(false).unwrap()), 1.0);
    let first_pid = wait_for_pid(&engine, "constant");
    let gain_before = cycles(&engine, "gain");

    std::fs::write(
        folder.join("constant.py"),
        CONSTANT.replace("VALUE = 1.0", "VALUE = 2.0"),
    )
    .unwrap();
    assert!(
        wait_for(Duration::from_secs(30), || f64_of(&constant.read(false).unwrap())
            == 2.0),
        "the edited code runs"
    );
    assert!(
        wait_for(Duration::from_secs(30), || wait_for_pid(&engine, "constant")
            != first_pid),
        "in a new process: {first_pid} then {}",
        status(&engine, "constant")
    );
    assert!(!process_exists(first_pid), "the old one ended");
    assert_eq!(state(&engine, "gain"), ComponentState::Running);
    assert!(cycles(&engine, "gain") > gain_before, "the rest kept running");

    // Code that does not load leaves the running code in place, and its status says where the edit
    // went wrong: the syntax error's own line, then a failing statement's, never the import machinery's.
    for (broken, line) in [
        ("VALUE = 3.0\n\nVALUE = (\n", 3),
        ("VALUE = 3.0\nVALUE = undefined_name\n", 2),
    ] {
        std::fs::write(folder.join("constant.py"), broken).unwrap();
        let place = format!("constant.py:{line}): ");
        // The test's link never skips: it is drained while waiting, or it would hold the component.
        let said = || {
            constant.skip_pending();
            status(&engine, "constant")["python"]["reload_error"]
                .as_str()
                .is_some_and(|error| error.contains(&place))
        };
        assert!(
            wait_for(Duration::from_secs(30), said),
            "{place} in {}",
            status(&engine, "constant")
        );
        assert_eq!(state(&engine, "constant"), ComponentState::Running);
        let values: Vec<f64> = read_n(&mut constant, 20).iter().map(f64_of).collect();
        assert!(values.iter().all(|v| *v == 2.0), "{values:?}");
    }
    engine.stop();
}

#[test]
fn a_file_that_does_not_import_is_listed_with_its_line_and_the_rest_of_the_pack_loads() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(
        dir.path(),
        "py_mixed",
        &[
            ("good.py", CONSTANT),
            ("broken.py", "import os\n\ndef f(:\n    pass\n"),
            ("missing.py", "import os\nimport no_such_module_here\n"),
        ],
    );
    let (registry, scan) = registry_with(&[dir.path().to_owned()]);
    assert!(registry.component("py_mixed.constant").is_some());
    let reasons: Vec<String> = scan
        .refused
        .iter()
        .map(|r| format!("{}: {}", r.path.display(), r.reason))
        .collect();
    assert_eq!(reasons.len(), 2, "{reasons:?}");
    assert!(
        reasons[0].contains("broken.py: line 3: SyntaxError"),
        "{reasons:?}"
    );
    assert!(
        reasons[1].contains("missing.py: line 2: ModuleNotFoundError: No module named 'no_such_module_here'"),
        "{reasons:?}"
    );

    // As a user sees it.
    let output = kairos(dir.path(), &["packs", "--pack-path", "."]);
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stdout.contains("py_mixed 0.1.0") && stdout.contains("    py_mixed.constant"),
        "{stdout}"
    );
    assert!(stdout.contains("broken.py: line 3: SyntaxError"), "{stdout}");
}

#[test]
fn a_name_declared_twice_names_both_classes_leaves_out_that_name_only_and_test_files_are_not_loaded() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let twice = |class: &str| {
        format!(
            "from kairos_sdk import F64, Component, Descriptor\n\n\nclass {class}(Component):\n    \
             descriptor = Descriptor(\"twice\").output(\"out\", F64)\n\n    def core(self, ctx):\n        pass\n"
        )
    };
    let (alpha, beta) = (twice("Alpha"), twice("Beta"));
    write_pack(
        dir.path(),
        "py_twice",
        &[
            ("good.py", CONSTANT),
            ("first.py", &alpha),
            ("second.py", &beta),
            // pytest's files: imported, this one would be refused for its import.
            ("test_good.py", "import pytest_only_module\n"),
            ("conftest.py", "import pytest_only_module\n"),
        ],
    );
    let (registry, scan) = registry_with(&[dir.path().to_owned()]);
    assert!(registry.component("py_twice.constant").is_some());
    assert!(registry.component("py_twice.twice").is_none());
    let reasons: Vec<String> = scan
        .refused
        .iter()
        .map(|r| format!("{}: {}", r.path.display(), r.reason))
        .collect();
    assert_eq!(reasons.len(), 2, "one per class, none for the tests: {reasons:?}");
    for reason in &reasons {
        assert!(
            reason.contains("class Alpha in first.py:4; class Beta in second.py:4")
                && reason.ends_with("(pack 'py_twice' loaded without 'py_twice.twice')"),
            "{reason}"
        );
    }
}

#[test]
fn a_diagram_needing_a_refused_pack_is_told_why_it_was_refused_not_given_another_pack_s_name() {
    let dir = tempfile::tempdir().unwrap();
    let folder = write_pack(dir.path(), "vision_extra", &[("good.py", CONSTANT)]);
    std::fs::write(
        folder.join("kairos-pack.toml"),
        "[pack]\nname = \"vision_extra\"\nversion = \"0.1.0\"\n\n[python]\ninterpreter = \"python3.99\"\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("d.ron"),
        r#"Diagram(format: 1,
            packs: [Pack(name: "core", version: "^0.1"), Pack(name: "vision_extra", version: "^0.1")],
            components: [Component(id: "c", type: "vision_extra.constant")])"#,
    )
    .unwrap();
    for command in ["run", "validate"] {
        let output = kairos(dir.path(), &[command, "d.ron", "--pack-path", "."]);
        let (_, stderr) = text(&output);
        assert!(!output.status.success(), "{stderr}");
        assert!(
            stderr.contains("pack 'vision_extra' is not in the component library")
                && stderr.contains("help: it is on the pack path but was refused: pack 'vision_extra' (")
                && stderr.contains("the Python interpreter 'python3.99' is not on the PATH"),
            "{command}: {stderr}"
        );
        assert!(!stderr.contains("did you mean"), "{command}: {stderr}");
        assert!(
            stderr.contains("note: packs were looked for"),
            "{command}: {stderr}"
        );
    }
}

#[test]
fn a_missing_interpreter_or_virtual_environment_is_named() {
    let dir = tempfile::tempdir().unwrap();
    for (name, interpreter, expected) in [
        (
            "py_venv",
            "empty_venv",
            "empty_venv' is a folder without bin/python3: not a virtual environment",
        ),
        (
            "py_path",
            ".venv/bin/python",
            "py_path/.venv/bin/python' does not exist",
        ),
        (
            "py_command",
            "python3.99",
            "the Python interpreter 'python3.99' is not on the PATH",
        ),
    ] {
        let folder = write_pack(dir.path(), name, &[("good.py", CONSTANT)]);
        std::fs::write(
            folder.join("kairos-pack.toml"),
            format!("[pack]\nname = \"{name}\"\nversion = \"0.1.0\"\n\n[python]\ninterpreter = \"{interpreter}\"\n"),
        )
        .unwrap();
        if interpreter.starts_with("empty") {
            std::fs::create_dir(folder.join(interpreter)).unwrap();
        }
        let (registry, scan) = registry_with(std::slice::from_ref(&folder));
        assert!(registry.component(&format!("{name}.constant")).is_none());
        let reason = &scan.refused.first().unwrap().reason;
        assert!(reason.contains(expected), "{reason}");
        assert!(reason.contains(&format!("pack '{name}'")), "{reason}");
        assert!(
            reason.contains("correct `interpreter` under [python] in kairos-pack.toml"),
            "the fix: {reason}"
        );
    }

    // A pack naming no interpreter: a bad KAIROS_PYTHON is named as the cause, and where it is not set the
    // pack's own `.venv` runs the pack.
    let folder = write_pack(dir.path(), "py_env", &[("good.py", CONSTANT)]);
    let packs = |variable: Option<&str>| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_kairos"));
        command.args(["packs", "--pack-path"]).arg(&folder);
        match variable {
            Some(value) => command.env("KAIROS_PYTHON", value),
            None => command.env_remove("KAIROS_PYTHON"),
        };
        let output = command.output().unwrap();
        let (stdout, stderr) = text(&output);
        format!("{stdout}{stderr}")
    };
    let said = packs(Some("/no/such/python3"));
    assert!(
        said.contains("'/no/such/python3' does not exist")
            && said.contains("named by the environment variable KAIROS_PYTHON: correct or unset it"),
        "{said}"
    );
    let python = String::from_utf8(
        std::process::Command::new("python3")
            .args(["-c", "import sys; print(sys.executable)"])
            .output()
            .unwrap()
            .stdout,
    )
    .unwrap();
    let venv = folder.join(".venv");
    std::fs::create_dir_all(venv.join("bin")).unwrap();
    std::os::unix::fs::symlink(python.trim(), venv.join("bin/python3")).unwrap();
    let said = packs(None);
    assert!(
        said.contains("py_env.constant"),
        "the pack's .venv runs it: {said}"
    );
    // One with its interpreter gone (copied from another machine, half made) is passed over.
    std::fs::remove_file(venv.join("bin/python3")).unwrap();
    let said = packs(None);
    assert!(said.contains("py_env.constant"), "python3 runs it: {said}");
}

#[test]
fn a_failing_python_component_shows_its_traceback_and_prints_in_the_log() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let source = TEST_COMPONENTS.replace(
        "        self.count += 1\n",
        "        self.count += 1\n        print(f\"dividing sample {self.count}\")\n",
    );
    write_pack(
        &dir.path().join("packs"),
        "py_test",
        &[("components.py", &source)],
    );
    std::fs::write(
        dir.path().join("d.ron"),
        counter_into("py_test.divide", "in", 100.0),
    )
    .unwrap();
    // Time for the Python worker to start and take its first samples, even on a slow machine.
    let output = kairos(dir.path(), &["run", "d.ron", "--for", "5s"]);
    let (_, stderr) = text(&output);
    assert!(
        stderr.contains("x: dividing sample 4"),
        "what Python prints is logged: {stderr}"
    );
    assert!(stderr.contains("ZeroDivisionError: division by zero"), "{stderr}");
    let line = line_of(&source, "sample.data / (5 - self.count)");
    assert!(
        stderr.contains(&format!("components.py\", line {line}, in core")),
        "{stderr}"
    );
}

/// The line of `text` (from 1) holding `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

fn wait_for_pid(engine: &Engine, id: &str) -> u32 {
    let mut pid = None;
    assert!(wait_for(Duration::from_secs(30), || {
        pid = status(engine, id)["python"]["pid"].as_u64();
        pid.is_some()
    }));
    pid.unwrap() as u32
}

fn process_exists(pid: u32) -> bool {
    // A zombie is ended too: only its exit status waits to be read.
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        !stat
            .rsplit(')')
            .next()
            .unwrap_or_default()
            .trim_start()
            .starts_with('Z')
    })
}

#[test]
fn ctrl_c_in_the_terminal_stops_python_components_in_order() {
    use std::io::{BufRead as _, BufReader, Read as _};
    use std::os::unix::process::CommandExt as _;
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let diagram = repo_root().join("examples/python/threshold.ron");
    // As in a terminal: kairos leads a process group, and Ctrl-C signals the whole group.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args([
            "run",
            diagram.to_str().unwrap(),
            "--stats",
            "--stats-interval",
            "10s",
        ])
        .current_dir(dir.path())
        .process_group(0)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let group = nix::unistd::Pid::from_raw(i32::try_from(child.id()).unwrap());
    // Until the Python component has given the console a value (it prints it): then Ctrl-C.
    let stdout = child.stdout.take().unwrap();
    let (printed_tx, printed_rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("kairos stdout".to_owned())
        .spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if line.starts_with("console:") {
                    // Told once is enough: the test may have stopped listening.
                    let _ = printed_tx.send(());
                }
            }
        })
        .unwrap();
    let printed = printed_rx.recv_timeout(Duration::from_secs(30)).is_ok();
    nix::sys::signal::killpg(group, nix::sys::signal::Signal::SIGINT).unwrap();
    let started = Instant::now();
    let exit = loop {
        if let Some(exit) = child.try_wait().unwrap() {
            break exit;
        }
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "kairos did not stop after Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    assert!(printed, "the Python component ran before Ctrl-C: {stderr}");
    assert!(exit.success(), "{stderr}");
    assert!(stderr.contains("=== final"), "{stderr}");
    assert!(
        !stderr.contains("FAILED"),
        "the worker is not killed by the terminal's signal: {stderr}"
    );
    assert!(!stderr.contains("KeyboardInterrupt"), "{stderr}");
}

/// The worker processes of the process `parent`: its children running `kairos_sdk.worker`.
fn workers_of(parent: u32) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|entry| entry.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            let ppid = stat
                .rsplit(')')
                .next()
                .and_then(|rest| rest.split_whitespace().nth(1))
                .and_then(|p| p.parse::<u32>().ok());
            ppid == Some(parent)
                && std::fs::read(format!("/proc/{pid}/cmdline"))
                    .is_ok_and(|c| String::from_utf8_lossy(&c).contains("kairos_sdk.worker"))
        })
        .collect()
}

/// `kill -9` of the runtime while its Python component spins in a loop that never reads its socket: the
/// kernel ends the worker with it (its parent-death signal), within a second, with no help from Python.
#[test]
fn a_runtime_killed_with_sigkill_takes_its_spinning_worker_with_it() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(
        &dir.path().join("packs"),
        "py_test",
        &[("components.py", TEST_COMPONENTS)],
    );
    std::fs::write(
        dir.path().join("d.ron"),
        counter_into("py_test.endless", "in", 10.0),
    )
    .unwrap();
    let mut runtime = std::process::Command::new(env!("CARGO_BIN_EXE_kairos"))
        .args(["run", "d.ron"])
        .current_dir(dir.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut worker = None;
    assert!(
        wait_for(Duration::from_secs(30), || {
            worker = workers_of(runtime.id()).first().copied();
            worker.is_some()
        }),
        "the worker started"
    );
    let worker = worker.unwrap();
    // Until it spins: its first sample read, it loops for ever.
    std::thread::sleep(Duration::from_millis(1500));
    runtime.kill().unwrap();
    runtime.wait().unwrap();
    let killed = Instant::now();
    let gone = wait_for(Duration::from_secs(1), || !process_exists(worker));
    if !gone {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(worker as i32),
            nix::sys::signal::Signal::SIGKILL,
        );
    }
    assert!(
        gone,
        "the worker {worker} outlived its runtime by {:?}",
        killed.elapsed()
    );
}

/// A component whose module takes its time to import, as one importing numpy, OpenCV or a model does.
const SLOW_TO_IMPORT: &str = r#"
import time

import numpy  # noqa: F401 - the import's own time is the point

from kairos_sdk import F64, I64, Component, Descriptor

time.sleep(0.3)


class Slow(Component):
    descriptor = Descriptor("slow").input("in", (F64, I64))

    def core(self, ctx):
        ctx.read("in")
"#;

#[test]
fn sources_start_once_every_python_worker_is_ready_so_nothing_is_lost_at_start_on_a_loaded_machine() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    write_pack(dir.path(), "py_start", &[("slow.py", SLOW_TO_IMPORT)]);
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    // Small buffers: 80 ms of samples each, far less than the worker's start.
    let mut engine = engine(
        &registry,
        r#"Diagram(format: 1, components: [
            Component(id: "counter", type: "core.counter", properties: {"rate": 100.0}),
            Component(id: "strict", type: "core.counter", properties: {"rate": 100.0}),
            Component(id: "latest", type: "py_start.slow"),
            Component(id: "every", type: "py_start.slow"),
        ], connections: [
            Connection(from: "counter.out", to: "latest.in", policy: Fifo, buffer_size: 8),
            Connection(from: "strict.out", to: "every.in", policy: NeverSkipping, buffer_size: 8),
        ])"#,
    );
    // Both cores busy while the diagram starts.
    let loaded = Arc::new(std::sync::atomic::AtomicBool::new(true));
    let load: Vec<_> = (0..2)
        .map(|_| {
            let loaded = Arc::clone(&loaded);
            std::thread::Builder::new()
                .name("load".to_owned())
                .spawn(move || {
                    while loaded.load(std::sync::atomic::Ordering::Relaxed) {
                        std::hint::spin_loop();
                    }
                })
                .unwrap()
        })
        .collect();
    engine.start().unwrap();
    std::thread::sleep(Duration::from_secs(2));
    loaded.store(false, std::sync::atomic::Ordering::Relaxed);
    for spinner in load {
        spinner.join().unwrap();
    }
    std::thread::sleep(Duration::from_millis(500));
    let snapshot = engine.snapshot();
    engine.stop();
    for link in &snapshot.links {
        assert!(link.counters.written >= 100, "{}: {:?}", link.link, link.counters);
        assert_eq!(link.counters.overwritten, 0, "{}: {:?}", link.link, link.counters);
    }
    // Started before the worker had imported (0.3 s), the NeverSkipping source would wait for its reader
    // once its 8 slots filled and miss 20 ticks or more. Two spinners on both cores may still delay a
    // 10 ms tick past its period now and then without any wait for the reader: a few are not a failure.
    let strict = snapshot.components.iter().find(|c| c.id == "strict").unwrap();
    assert!(
        strict.missed_ticks <= 5,
        "the source waited for its reader: {} ticks missed",
        strict.missed_ticks
    );
}

#[test]
fn a_python_pack_ships_its_subgraphs_which_diagrams_use_as_the_pack_s_types() {
    require_numpy();
    let dir = tempfile::tempdir().unwrap();
    let folder = write_pack(dir.path(), "py_sub", &[("constant.py", CONSTANT)]);
    std::fs::create_dir(folder.join("subgraphs")).unwrap();
    // A constant doubled: the pack's own component and core's, one subgraph.
    std::fs::write(
        folder.join("subgraphs/doubled.ron"),
        r#"Diagram(format: 1,
    exposes: Exposes(outputs: {"out": "twice.out"}, properties: {"factor": "twice.gain"}),
    components: [
        Component(id: "tick", type: "core.counter", properties: {"rate": 20.0}),
        Component(id: "source", type: "py_sub.constant"),
        Component(id: "twice", type: "core.gain", properties: {"gain": 2.0}),
    ],
    connections: [
        Connection(from: "tick.out", to: "source.in"),
        Connection(from: "source.out", to: "twice.in"),
    ],
)"#,
    )
    .unwrap();
    let (registry, _) = registry_with(&[dir.path().to_owned()]);
    assert!(
        registry.subgraphs().contains_key("py_sub.doubled"),
        "{:?}",
        registry.subgraphs().keys()
    );

    std::fs::write(
        dir.path().join("use.ron"),
        r#"Diagram(format: 1,
    components: [
        Component(id: "d", type: "py_sub.doubled", properties: {"factor": 3.0}),
        Component(id: "log", type: "core.console"),
    ],
    connections: [Connection(from: "d.out", to: "log.in")],
)"#,
    )
    .unwrap();
    let output = kairos(
        dir.path(),
        &["run", "use.ron", "--pack-path", ".", "--for", "2s", "--stats"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    for id in ["d/tick", "d/source", "d/twice"] {
        assert!(
            common::stats_cycles(&stderr, id) >= 1,
            "{id} ran no cycle
{stdout}"
        );
    }
}

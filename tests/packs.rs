//! Packs loaded at run time through the C ABI: Rust and C++ packs next to built-in components, and every
//! kind of broken library refused with its file and reason while the runtime goes on.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{kairos, repo_root, text};

/// Where cargo put the workspace's build products (the `kairos` binary's folder).
fn build_dir() -> PathBuf {
    Path::new(env!("CARGO_BIN_EXE_kairos"))
        .parent()
        .unwrap()
        .to_owned()
}

fn library_name(stem: &str) -> String {
    format!(
        "{}{stem}{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    )
}

/// Copies a Rust pack built by this workspace (a cdylib) into `dir`.
fn copy_rust_pack(crate_stem: &str, dir: &Path) -> PathBuf {
    let name = library_name(crate_stem);
    // Uplifted next to the binaries when built directly, left in deps/ when built as a dev-dependency.
    let candidates = [build_dir().join(&name), build_dir().join("deps").join(&name)];
    // Both may be there, one of them stale: the newer is the build of this source.
    let built = candidates
        .iter()
        .filter_map(|p| Some((std::fs::metadata(p).ok()?.modified().ok()?, p)))
        .max()
        .map_or_else(|| candidates[0].clone(), |(_, p)| p.clone());
    assert!(
        built.exists(),
        "{} is missing: build it with `cargo build -p {}`",
        built.display(),
        crate_stem.replace('_', "-")
    );
    let target = dir.join(&name);
    std::fs::copy(&built, &target).unwrap();
    target
}

/// Compiles C or C++ sources into a shared library with the system compiler.
fn compile(compiler: &str, sources: &[PathBuf], defines: &[&str], output: &Path) {
    let include = repo_root().join("component-sdk/include");
    let mut command = Command::new(compiler);
    command
        .args(["-shared", "-fPIC", "-O1"])
        .arg("-I")
        .arg(&include)
        .args(sources)
        .arg("-o")
        .arg(output);
    if compiler == "c++" {
        command.arg("-std=c++17");
    }
    for define in defines {
        command.arg(format!("-D{define}"));
    }
    let status = command
        .status()
        .unwrap_or_else(|e| panic!("running {compiler}: {e}"));
    assert!(status.success(), "{compiler} failed on {sources:?}");
}

fn cpp_pack(dir: &Path) -> PathBuf {
    let output = dir.join(library_name("kairos_pack_cpp"));
    compile(
        "c++",
        &[repo_root().join("component-packs/cpp-clamp/clamp.cpp")],
        &[],
        &output,
    );
    output
}

/// A C pack linked against a library that is not there when it is loaded.
fn needs_a_missing_library(packs: &Path, scratch: &Path) {
    let dependency = scratch.join("libkairos_missing_dependency.so");
    std::fs::write(
        scratch.join("dependency.c"),
        "int kairos_missing_dependency(void) { return 1; }\n",
    )
    .unwrap();
    compile("cc", &[scratch.join("dependency.c")], &[], &dependency);
    let output = packs.join(library_name("needs_missing"));
    let status = Command::new("cc")
        .args(["-shared", "-fPIC"])
        .arg("-I")
        .arg(repo_root().join("component-sdk/include"))
        .arg(repo_root().join("tests/packs/c/broken.c"))
        .arg("-DPACK_NAME=\"needs_missing\"")
        .arg("-L")
        .arg(scratch)
        .args(["-Wl,--no-as-needed", "-lkairos_missing_dependency", "-o"])
        .arg(&output)
        .status()
        .unwrap();
    assert!(status.success());
    std::fs::remove_file(&dependency).unwrap();
}

fn broken_pack(dir: &Path, name: &str, defines: &[&str]) -> PathBuf {
    let output = dir.join(library_name(name));
    compile(
        "cc",
        &[repo_root().join("tests/packs/c/broken.c")],
        defines,
        &output,
    );
    output
}

/// Every kind of broken C pack the loader must refuse, each in a library of its own in `packs`.
fn broken_packs(packs: &Path, scratch: &Path) {
    broken_pack(packs, "bad_magic", &["PACK_MAGIC=0x1234ULL"]);
    broken_pack(packs, "abi_too_new", &["PACK_ABI=99u"]);
    broken_pack(packs, "abi_too_old", &["PACK_ABI=0u"]);
    broken_pack(packs, "bad_layout", &["PACK_SAMPLE_SIZE=8"]);
    for function in ["DEATH_FN", "PROPERTY_FN", "ACTION_FN"] {
        let name = format!("null_{}", function.to_lowercase());
        let pack_name = format!("PACK_NAME=\"{name}\"");
        let type_name = format!("TYPE_NAME=\"{name}.idle\"");
        let null = format!("{function}=0");
        broken_pack(packs, &name, &["WITH_COMPONENT", &pack_name, &type_name, &null]);
    }
    broken_pack(
        packs,
        "foreign",
        &[
            "WITH_COMPONENT",
            "PACK_NAME=\"foreign\"",
            "TYPE_NAME=\"other.thing\"",
        ],
    );
    needs_a_missing_library(packs, scratch);
    compile(
        "cc",
        &[repo_root().join("tests/packs/c/no_entry.c")],
        &[],
        &packs.join(library_name("no_entry")),
    );
}

#[test]
fn packs_lists_loaded_packs_and_every_refused_library_with_its_reason() {
    let dir = tempfile::tempdir().unwrap();
    let packs = dir.path().join("packs");
    std::fs::create_dir(&packs).unwrap();
    let filters = copy_rust_pack("kairos_pack_filters", &packs);
    copy_rust_pack("kairos_test_pack_faulty", &packs);
    cpp_pack(&packs);
    std::fs::write(
        packs.join(library_name("not_a_library")),
        "this is text, not a library\n",
    )
    .unwrap();
    let whole = std::fs::read(&filters).unwrap();
    std::fs::write(packs.join(library_name("truncated")), &whole[..whole.len() / 3]).unwrap();
    broken_packs(&packs, dir.path());

    let output = kairos(
        dir.path(),
        &["--pack-path", packs.to_str().unwrap(), "packs", "--json"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let json: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let loaded: Vec<&str> = json["packs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    for name in ["core", "sensors", "filters", "faulty", "cpp"] {
        assert!(loaded.contains(&name), "{name} not loaded: {loaded:?}");
    }
    let filters_entry = json["packs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "filters")
        .unwrap();
    assert!(
        filters_entry["origin"]
            .as_str()
            .unwrap()
            .ends_with(&library_name("kairos_pack_filters"))
    );
    let refused = |stem: &str| -> String {
        json["refused"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["path"].as_str().unwrap().ends_with(&library_name(stem)))
            .map_or_else(
                || panic!("{stem} was not refused: {stdout}"),
                |r| r["reason"].as_str().unwrap().to_owned(),
            )
    };
    assert!(refused("not_a_library").contains("not an ELF file"));
    assert!(refused("truncated").contains("truncated"));
    assert!(refused("bad_magic").contains("magic"));
    assert!(refused("abi_too_new").contains("version 99 is newer"));
    assert!(refused("abi_too_old").contains("version 0 is older"));
    assert!(refused("bad_layout").contains("layout mismatch: the sample struct is 8 bytes"));
    assert!(refused("no_entry").contains("kairos_pack_entry"));
    assert!(refused("null_death_fn").contains("has no `death` function"));
    assert!(refused("null_property_fn").contains("has no `property_changed` function"));
    assert!(refused("null_action_fn").contains("has no `action` function"));
    assert!(
        refused("needs_missing").contains("libkairos_missing_dependency.so"),
        "the dynamic loader's cause is kept: {}",
        refused("needs_missing")
    );
    // A type outside the pack's own name is refused alone; the rest of its pack loads.
    assert!(
        refused("foreign").contains("pack 'foreign' may register only types named 'foreign.…'"),
        "{}",
        refused("foreign")
    );
    assert!(
        refused("kairos_test_pack_faulty").contains("'core.gain' is refused (name it 'faulty.gain')"),
        "{}",
        refused("kairos_test_pack_faulty")
    );
    assert!(loaded.contains(&"foreign"), "{loaded:?}");
    assert_eq!(
        json["duplicates"],
        serde_json::json!([]),
        "no pack can take a built-in type"
    );

    // Loaded components are listed exactly like built-in ones.
    let output = kairos(
        dir.path(),
        &["--pack-path", packs.to_str().unwrap(), "components", "--json"],
    );
    let json: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let components = json["components"].as_array().unwrap();
    let low_pass = components
        .iter()
        .find(|c| c["type_name"] == "filters.low_pass")
        .unwrap();
    assert_eq!(low_pass["pack"], "filters");
    assert_eq!(low_pass["properties"][0]["name"], "time_constant_s");
    let clamp = components.iter().find(|c| c["type_name"] == "cpp.clamp").unwrap();
    assert_eq!(clamp["inputs"][0]["filter"]["one_of"][0], "f64");
    // The name people read, from the C++ descriptor's optional label.
    assert_eq!(clamp["label"], "Clamp");
}

fn write_diagram(dir: &Path, name: &str, body: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, body).unwrap();
    path
}

#[test]
fn a_pack_that_aborts_in_its_entry_point_is_named_by_the_last_line_of_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let packs = dir.path().join("packs");
    std::fs::create_dir(&packs).unwrap();
    let library = broken_pack(&packs, "aborts", &["ABORT_IN_ENTRY"]);
    let output = kairos(dir.path(), &["--pack-path", packs.to_str().unwrap(), "packs"]);
    let (_, stderr) = text(&output);
    assert!(!output.status.success(), "the process cannot survive an abort");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.contains("loading pack library") && last.contains(library.to_str().unwrap()),
        "{stderr}"
    );
}

#[test]
fn rust_and_cpp_packs_from_a_folder_beside_the_diagram_run_with_built_in_components() {
    let dir = tempfile::tempdir().unwrap();
    let packs = dir.path().join("packs");
    std::fs::create_dir(&packs).unwrap();
    copy_rust_pack("kairos_pack_filters", &packs);
    cpp_pack(&packs);
    let text = r#"Diagram(
    format: 1,
    packs: [
        Pack(name: "core", version: "^0.1"),
        Pack(name: "cpp", version: "^0.1"),
        Pack(name: "filters", version: "^0.1"),
    ],
    components: [
        Component(id: "clamp", type: "cpp.clamp", properties: {"max": 0.5, "min": -0.5}),
        Component(id: "console", type: "core.console"),
        Component(id: "lp", type: "filters.low_pass", properties: {"time_constant_s": 0.02}),
        Component(id: "sine", type: "core.sine", properties: {"rate": 200.0, "frequency": 2.0}),
    ],
    connections: [
        Connection(from: "clamp.out", to: "lp.in"),
        Connection(from: "lp.out", to: "console.in"),
        Connection(from: "sine.out", to: "clamp.in"),
    ],
)
"#;
    // The same diagram with a thread per component, then in one thread (loaded components called by
    // their group rather than waiting in threads of their own).
    for sequential in [false, true] {
        let diagram = write_diagram(
            dir.path(),
            "mixed.ron",
            &text.replace("format: 1,", &format!("format: 1, sequential: {sequential},")),
        );
        run_mixed(dir.path(), &diagram, sequential);
    }
}

fn run_mixed(dir: &Path, diagram: &Path, sequential: bool) {
    let output = kairos(
        dir,
        &["run", diagram.to_str().unwrap(), "--for", "1500ms", "--stats"],
    );
    let (stdout, stderr) = text(&output);
    assert!(output.status.success(), "{stderr}");
    let values: Vec<f64> = stdout
        .lines()
        .filter(|l| l.starts_with("console:"))
        .filter_map(|l| l.rsplit(' ').next()?.parse().ok())
        .collect();
    assert!(!values.is_empty(), "no value:\n{stdout}");
    assert!(
        values.iter().all(|v| v.abs() <= 0.5 + 1e-12),
        "clamped to ±0.5 by the C++ component"
    );
    assert!(
        values.iter().any(|v| *v > 0.4) && values.iter().any(|v| *v < -0.4),
        "the filter follows the clamp"
    );
    assert!(
        stderr.contains("clamped"),
        "the C++ component logs through the host: {stderr}"
    );
    assert!(stderr.contains("lp.out -> console.in"), "{stderr}");
    // The statistics' group table has a row for the sequential group, its four members.
    let group_row = stderr
        .lines()
        .find(|l| l.starts_with("sequential "))
        .map(|l| l.split_whitespace().nth(1).unwrap_or_default().to_owned());
    assert_eq!(group_row.as_deref(), sequential.then_some("4"), "{stderr}");
}

#[test]
fn a_pack_that_panics_fails_only_its_components() {
    let dir = tempfile::tempdir().unwrap();
    let packs = dir.path().join("packs");
    std::fs::create_dir(&packs).unwrap();
    copy_rust_pack("kairos_test_pack_faulty", &packs);
    let diagram = write_diagram(
        dir.path(),
        "faulty.ron",
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "core", version: "^0.1"), Pack(name: "faulty", version: "^0.1")],
    components: [
        Component(id: "broken", type: "faulty.bad_constructor"),
        Component(id: "console", type: "core.console"),
        Component(id: "gain", type: "core.gain", properties: {"gain": 3.0}),
        Component(id: "third", type: "faulty.panics_on_third"),
        Component(id: "sine", type: "core.sine", properties: {"rate": 100.0}),
    ],
    connections: [
        Connection(from: "gain.out", to: "console.in"),
        Connection(from: "sine.out", to: "gain.in"),
        Connection(from: "sine.out", to: "third.in"),
    ],
)
"#,
    );
    let output = kairos(dir.path(), &["run", diagram.to_str().unwrap(), "--for", "1s"]);
    let (stdout, stderr) = text(&output);
    assert_eq!(
        output.status.code(),
        Some(2),
        "a failed component makes the exit code 2: {stderr}"
    );
    assert!(
        stderr.contains("component 'broken' failed") && stderr.contains("constructor failed"),
        "{stderr}"
    );
    assert!(
        stderr.contains("component 'third' failed") && stderr.contains("the third sample is one too many"),
        "{stderr}"
    );
    // 'third' fails on its third sample; the healthy chain prints more than that (about 100 lines in 1 s).
    let lines = stdout.lines().filter(|l| l.starts_with("console:")).count();
    assert!(lines > 3, "the healthy chain kept running: {lines} lines");
}

#[test]
fn a_missing_or_mismatched_pack_names_both_versions_and_where_it_looked() {
    let dir = tempfile::tempdir().unwrap();
    let packs = dir.path().join("elsewhere");
    std::fs::create_dir(&packs).unwrap();
    copy_rust_pack("kairos_pack_filters", &packs);
    let diagram = write_diagram(
        dir.path(),
        "needs.ron",
        r#"Diagram(
    format: 1,
    packs: [Pack(name: "filters", version: "^0.2"), Pack(name: "lidar", version: "^1")],
    components: [],
    connections: [],
)
"#,
    );
    let output = kairos(
        dir.path(),
        &[
            "--pack-path",
            packs.to_str().unwrap(),
            "validate",
            diagram.to_str().unwrap(),
        ],
    );
    let (_, stderr) = text(&output);
    assert_eq!(output.status.code(), Some(1));
    assert!(
        stderr.contains("'filters' is required at version ^0.2, but the library has version 0.1.0"),
        "{stderr}"
    );
    assert!(stderr.contains("'lidar'"), "{stderr}");
    assert!(
        stderr.contains("looked for") && stderr.contains("elsewhere"),
        "{stderr}"
    );
}

#[test]
fn the_c_header_matches_the_rust_abi() {
    use kairos_sdk_core::abi;
    let dir = tempfile::tempdir().unwrap();
    let program = dir.path().join("layout");
    let status = Command::new("cc")
        .arg("-I")
        .arg(repo_root().join("component-sdk/include"))
        .arg(repo_root().join("tests/packs/c/layout.c"))
        .arg("-o")
        .arg(&program)
        .status()
        .unwrap();
    assert!(status.success());
    let output = Command::new(&program).output().unwrap();
    let printed = String::from_utf8(output.stdout).unwrap();
    let expected = format!(
        "magic {:x}\nabi {}\nsdk {}\nstr {}\nsample {}\nvalue {}\nerror {}\nhost {}\ncounters {}\nvtable {}\ndescriptor {}\n",
        abi::ABI_MAGIC,
        abi::ABI_VERSION,
        kairos_sdk_core::SDK_VERSION,
        size_of::<abi::KStr>(),
        size_of::<abi::KSample>(),
        size_of::<abi::KValue>(),
        size_of::<abi::KError>(),
        size_of::<abi::KHost>(),
        size_of::<abi::KLinkCounters>(),
        size_of::<abi::KComponentVTable>(),
        size_of::<abi::KPackDescriptor>(),
    );
    assert_eq!(printed, expected);
}

/// Runs `sine → probe` on an engine built from `registry` and returns the first reports the probe
/// writes, and whether its status at the end counts every cycle it ran.
fn probe_reports(registry: &kairos_sdk_core::Registry) -> (Vec<String>, bool) {
    use kairos_diagram::{ComponentInstance, Connection, Diagram, PackRequirement, PortRef, ReaderPolicy};
    use kairos_sdk_core::host::ReaderConfig;
    use kairos_sdk_core::{Payload, RealTimeClock, RunSignal};

    let mut sine = ComponentInstance::new("sine", "core.sine");
    sine.properties
        .insert("rate".to_owned(), kairos_diagram::Value::F64(200.0));
    let mut link = Connection::new(
        PortRef::parse("sine.out").unwrap(),
        PortRef::parse("probe.in").unwrap(),
    );
    link.policy = Some(ReaderPolicy::NeverSkipping);
    let diagram = Diagram {
        packs: ["core", "faulty"]
            .map(|name| PackRequirement {
                name: name.to_owned(),
                version: "^0.1".to_owned(),
            })
            .to_vec(),
        components: vec![ComponentInstance::new("probe", "faulty.context_probe"), sine],
        connections: vec![link],
        ..Diagram::default()
    };
    let mut engine = kairos_runtime::Engine::build(&diagram, registry, RealTimeClock::shared()).unwrap();
    let mut reader = engine.output_buffer("probe", "out").unwrap().attach(
        ReaderConfig::new(ReaderPolicy::NeverSkipping, "probe.out -> test"),
        std::sync::Arc::new(RunSignal::new()),
    );
    engine.start().unwrap();
    let mut reports = Vec::new();
    while reports.len() < 20 {
        let sample = reader.read(false).unwrap();
        let Payload::Text(text) = &sample.payload else {
            panic!("a report is text");
        };
        reports.push(text.to_string());
    }
    engine.stop();
    let snapshot = engine.snapshot();
    let probe = snapshot.components.iter().find(|c| c.id == "probe").unwrap();
    let counted = probe.status.as_ref().and_then(|s| s["handled"].as_u64()) == Some(probe.cycles);
    assert!(probe.cycles >= 20, "{probe:?}");
    (reports, counted)
}

#[test]
fn a_component_sees_the_same_context_built_in_and_loaded_from_its_library() {
    let mut built_in = kairos_sdk_core::Registry::new();
    kairos_pack_core::register(&mut built_in);
    kairos_test_pack_faulty::register(&mut built_in);

    let dir = tempfile::tempdir().unwrap();
    copy_rust_pack("kairos_test_pack_faulty", dir.path());
    let mut loaded = kairos_sdk_core::Registry::new();
    kairos_pack_core::register(&mut loaded);
    let scan = kairos_runtime::load_packs(&mut loaded, &[dir.path().to_owned()]);
    assert!(scan.refused.is_empty(), "{:?}", scan.refused);
    assert!(
        loaded
            .packs()
            .any(|p| p.name == "faulty" && p.origin.ends_with(&library_name("kairos_test_pack_faulty")))
    );

    let (expected, counted_built_in) = probe_reports(&built_in);
    let (reports, counted_loaded) = probe_reports(&loaded);
    assert!(
        expected[0].starts_with("probe reads sine.out: 1 read; diagram of ")
            && expected[0].ends_with("bytes; clock real time"),
        "{}",
        expected[0]
    );
    assert!(!expected[0].contains("diagram of 0 bytes"), "{}", expected[0]);
    assert_eq!(
        reports, expected,
        "loaded from its library, the probe says the same"
    );
    assert!(
        counted_built_in && counted_loaded,
        "both statuses count every cycle at the end: built in {counted_built_in}, loaded {counted_loaded}"
    );
}

//! Architecture invariants on dependencies: which crate of ours may depend on which (a rule table that
//! names every crate of the workspace), no GUI crate in the dependency tree of the SDK, the diagram
//! format, the runtime, the CLI or the packs, and packs that use the pack-author API alone.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::process::Command;

const GUI_CRATES: [&str; 5] = ["egui", "eframe", "wgpu", "winit", "glutin"];

/// The crates of ours that may link a GUI: the studio, and the benchmarks (its benchmarks only, behind a
/// feature). Every other crate of the workspace, found by `cargo metadata`, must not.
const GUI_ALLOWED: [&str; 2] = ["kairos-studio", "kairos-benches"];

#[test]
fn headless_crates_depend_on_no_gui_crate() {
    let metadata = workspace_metadata();
    let headless: Vec<&str> = package_names(&metadata)
        .into_iter()
        .filter(|name| !GUI_ALLOWED.contains(name))
        .collect();
    assert!(headless.contains(&"kairos") && headless.contains(&"kairos-pack-core"));
    for package in headless {
        let output = Command::new(env!("CARGO"))
            .args([
                "tree",
                "--offline",
                "-e",
                "normal,build",
                "--prefix",
                "none",
                "-p",
                package,
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("running cargo tree");
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        let tree = String::from_utf8_lossy(&output.stdout);
        for line in tree.lines() {
            let name = line.split_whitespace().next().unwrap_or_default();
            assert!(
                !GUI_CRATES
                    .iter()
                    .any(|gui| name == *gui || name.starts_with(&format!("{gui}-"))),
                "{package} depends on the GUI crate {name}"
            );
        }
    }
}

/// The floors, bottom up, and what each crate of ours may depend on (normal and build dependencies). The
/// first rule whose name matches applies; `kairos-pack-*` stands for every pack. A crate no rule matches
/// fails the test: a new crate takes its place here first.
const RULES: &[(&str, &[&str])] = &[
    // Bottom floor: plain data, and the shared-memory layout both the runtime side and clients need.
    ("kairos-diagram", &[]),
    ("kairos-shm", &[]),
    // The SDK's implementation, both halves; then what pack authors program against (part of it), and
    // what protocol clients do.
    ("kairos-sdk-core", &["kairos-diagram", "kairos-shm"]),
    ("kairos-sdk", &["kairos-sdk-core"]),
    ("kairos-protocol", &["kairos-diagram", "kairos-shm"]),
    // Whole samples as bytes: socket components, links between hosts and the protocol's subscriptions.
    ("kairos-sample-frame", &["kairos-sdk", "kairos-protocol"]),
    // The one protocol client.
    ("kairos-client", &["kairos-protocol"]),
    // Packs see the SDK alone, but for these:
    // the video pack converts camera frames with the vision pack's kernels;
    ("kairos-pack-video", &["kairos-sdk", "kairos-pack-vision"]),
    // the network pack carries whole samples in the sample frame;
    ("kairos-pack-net", &["kairos-sdk", "kairos-sample-frame"]),
    // the link pack too, and joins the Zenoh network a deployment describes (protocol types);
    (
        "kairos-pack-link",
        &[
            "kairos-sdk",
            "kairos-diagram",
            "kairos-protocol",
            "kairos-sample-frame",
            "kairos-pack-net",
        ],
    ),
    // a sensor pack reads through the serial pack's links.
    ("kairos-pack-gnss", &["kairos-sdk", "kairos-pack-serial"]),
    // ROS 2 messages, their definitions and type hashes are the recording pack's, for bags and live alike.
    ("kairos-pack-ros2", &["kairos-sdk", "kairos-pack-recording"]),
    // The simulator's world travels as the sensors pack's `sim_world`, which its sensors render.
    ("kairos-pack-sim", &["kairos-sdk", "kairos-pack-sensors"]),
    ("kairos-pack-*", &["kairos-sdk"]),
    ("kairos-test-pack-*", &["kairos-sdk"]),
    // The engine, and the clock synchronisation between runtimes: the SDK's runtime half.
    ("kairos-runtime", &["kairos-sdk-core", "kairos-diagram"]),
    ("kairos-clock-sync", &["kairos-sdk-core"]),
    // A diagram over hosts: reaches them through the client, joins their links.
    (
        "kairos-coordinator",
        &[
            "kairos-client",
            "kairos-diagram",
            "kairos-protocol",
            "kairos-sdk-core",
            "kairos-runtime",
            "kairos-pack-link",
        ],
    ),
    // The protocol server: the engine, clocks, coordination of a diagram over hosts for its client, the
    // recording pack's encodings for Foxglove, and the ROS 2 pack's view of a live graph (`ros2_topics`).
    (
        "kairos-server",
        &[
            "kairos-runtime",
            "kairos-sdk-core",
            "kairos-diagram",
            "kairos-protocol",
            "kairos-sample-frame",
            "kairos-clock-sync",
            "kairos-coordinator",
            "kairos-pack-link",
            "kairos-pack-recording",
            "kairos-pack-ros2",
        ],
    ),
    // The binary links the roles and every built-in pack.
    (
        "kairos",
        &[
            "kairos-runtime",
            "kairos-sdk-core",
            "kairos-diagram",
            "kairos-protocol",
            "kairos-clock-sync",
            "kairos-coordinator",
            "kairos-server",
            "kairos-pack-*",
        ],
    ),
    // The studio speaks the protocol (through the one client) and edits diagrams; it never links the
    // engine or a pack.
    (
        "kairos-studio",
        &["kairos-client", "kairos-protocol", "kairos-diagram"],
    ),
    // Benchmarks measure everything against everything.
    ("kairos-benches", &["kairos*"]),
];

/// Whether `name` matches `pattern` (a name, or a prefix ending in `*`).
fn matches(pattern: &str, name: &str) -> bool {
    match pattern.strip_suffix('*') {
        Some(prefix) => name.starts_with(prefix),
        None => pattern == name,
    }
}

fn package_names(metadata: &serde_json::Value) -> Vec<&str> {
    metadata["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect()
}

fn workspace_metadata() -> serde_json::Value {
    let output = Command::new(env!("CARGO"))
        .args(["metadata", "--format-version", "1", "--no-deps", "--offline"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("running cargo metadata");
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("cargo metadata prints JSON")
}

#[test]
fn every_crate_depends_only_on_the_crates_its_floor_allows() {
    let metadata = workspace_metadata();
    let ours = package_names(&metadata);
    let mut broken = Vec::new();
    for package in metadata["packages"].as_array().unwrap() {
        let name = package["name"].as_str().unwrap();
        let Some((_, allowed)) = RULES.iter().find(|(pattern, _)| matches(pattern, name)) else {
            broken.push(format!("{name} is not in the rule table of tests/layering.rs"));
            continue;
        };
        for dependency in package["dependencies"].as_array().unwrap() {
            let target = dependency["name"].as_str().unwrap();
            let development = dependency["kind"].as_str() == Some("dev");
            if development || !ours.contains(&target) {
                continue;
            }
            if !allowed.iter().any(|pattern| matches(pattern, target)) {
                broken.push(format!(
                    "{name} depends on {target}, which its floor does not allow"
                ));
            }
        }
    }
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

#[test]
fn no_pack_depends_on_the_runtime_half_of_the_sdk() {
    // The rule table keeps kairos-sdk-core out of a pack's dependencies; this keeps it out of its tests
    // and build scripts too, so that every pack builds and tests as an outside one would. That an outside
    // pack cannot reach the runtime's half through kairos-sdk is compiled in component-sdk/tests/sealed.rs.
    let metadata = workspace_metadata();
    for package in metadata["packages"].as_array().unwrap() {
        let name = package["name"].as_str().unwrap();
        if !(name.starts_with("kairos-pack-") || name.starts_with("kairos-test-pack-")) {
            continue;
        }
        for dependency in package["dependencies"].as_array().unwrap() {
            assert_ne!(
                dependency["name"], "kairos-sdk-core",
                "{name} depends on kairos-sdk-core, the runtime's half of the SDK: use kairos-sdk"
            );
        }
    }
}

/// The modules allowed `unsafe` (ARCHITECTURE.md names each and why); the lint denies it everywhere else.
const UNSAFE_MODULES: [&str; 14] = [
    "component-packs/kairos-pack-recording/src/ros2/sqlite.rs",
    "component-packs/kairos-pack-vision/src/kernels/linear.rs",
    "component-packs/kairos-pack-vision/src/kernels/turbojpeg.rs",
    "component-sdk/kairos-sdk-core/src/abi/types.rs",
    "component-sdk/kairos-sdk-core/src/abi/convert.rs",
    "component-sdk/kairos-sdk-core/src/abi/pack_side.rs",
    "component-sdk/kairos-sdk-core/src/buffer.rs",
    "component-sdk/kairos-sdk-core/src/sync.rs",
    "runtime/kairos-runtime/src/pack_host/loader.rs",
    "runtime/kairos-runtime/src/pack_host/functions.rs",
    "runtime/kairos-runtime/src/pack_host/dynamic.rs",
    "runtime/kairos-runtime/src/python_host/worker.rs",
    "runtime/kairos-server/src/shm.rs",
    "runtime/kairos-shm/src/lib.rs",
];

/// Every Rust file of the workspace's own code: the SDK, packs, diagram format, runtime, studio, tests and
/// benchmarks (build outputs left out).
fn workspace_rust_files() -> Vec<(String, String)> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut files = Vec::new();
    let mut folders = [
        "benches",
        "component-sdk",
        "component-packs",
        "diagram-format",
        "runtime",
        "studio",
        "tests",
    ]
    .map(|folder| root.join(folder))
    .to_vec();
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                if !path.ends_with("target") {
                    folders.push(path);
                }
                continue;
            }
            if path.extension().is_some_and(|e| e == "rs") {
                let relative = path.strip_prefix(&root).unwrap().to_string_lossy().into_owned();
                files.push((relative, std::fs::read_to_string(&path).unwrap_or_default()));
            }
        }
    }
    files
}

#[test]
fn unsafe_code_is_allowed_only_in_the_modules_architecture_md_names() {
    let mut allowing = Vec::new();
    for (path, text) in workspace_rust_files() {
        // The `export_pack!` macro allows it on the entry point it generates, in the pack's crate.
        let is_macro_definition = path.ends_with("component-sdk/kairos-sdk-core/src/abi/mod.rs");
        if text
            .split_whitespace()
            .collect::<String>()
            .contains(&["allow(", "unsafe_code"].concat())
            && !is_macro_definition
        {
            allowing.push(path);
        }
    }
    allowing.sort();
    let mut expected = UNSAFE_MODULES.map(str::to_owned).to_vec();
    expected.sort();
    assert_eq!(allowing, expected);
}

/// The error type of each `Result<..>` written in `text`: its last generic argument at the top level.
fn result_error_types(text: &str) -> Vec<String> {
    let opening = ["Result", "<"].concat();
    let mut found = Vec::new();
    for (start, _) in text.match_indices(&opening) {
        let preceded_by_name = text[..start]
            .chars()
            .next_back()
            .is_some_and(|c| c.is_alphanumeric() || c == '_');
        if preceded_by_name {
            continue;
        }
        let mut depth = 0_usize;
        let mut last_comma = None;
        let inside = start + opening.len();
        for (offset, c) in text[inside..].char_indices() {
            match c {
                '<' | '(' | '[' => depth += 1,
                ')' | ']' => depth = depth.saturating_sub(1),
                '>' if depth == 0 => {
                    if let Some(comma) = last_comma {
                        found.push(text[comma + 1..inside + offset].trim().to_owned());
                    }
                    break;
                }
                '>' => depth -= 1,
                ',' if depth == 0 => last_comma = Some(inside + offset),
                ';' | '{' if depth == 0 => break,
                _ => {}
            }
        }
    }
    found
}

/// The only functions whose error is a `String`: their signature is another crate's, which they implement.
const STRING_ERRORS_SET_ELSEWHERE: [(&str, &str); 1] = [
    // egui's `DroppedFile::bytes`.
    ("studio/tests/editor.rs", "fn bytes(&self)"),
];

#[test]
fn no_error_is_a_bare_string() {
    // A caller can only print a String: errors are types whose variants carry what went wrong, and text is
    // made where it is shown. (`Result<_, String>` is written split here so that this file passes.)
    let mut bare = Vec::new();
    for (path, text) in workspace_rust_files() {
        for (line_number, line) in text.lines().enumerate() {
            let set_elsewhere = STRING_ERRORS_SET_ELSEWHERE
                .iter()
                .any(|(file, signature)| path == *file && line.contains(signature));
            if line.trim_start().starts_with("//") || set_elsewhere {
                continue;
            }
            if result_error_types(line).iter().any(|error| error == "String") {
                bare.push(format!("{path}:{}: {}", line_number + 1, line.trim()));
            }
        }
    }
    assert!(
        bare.is_empty(),
        "errors as bare strings (give them an error type):\n{}",
        bare.join("\n")
    );
}

#[test]
fn the_error_finder_sees_bare_strings_and_nothing_else() {
    let bare = ["fn f() -> Result", "<u8, String> {"].concat();
    assert_eq!(result_error_types(&bare), ["String"]);
    let nested = ["Result", "<Result", "<Payload, String>, WireError>"].concat();
    assert_eq!(result_error_types(&nested), ["WireError", "String"]);
    let typed = ["Result", "<Vec<(String, u8)>, std::io::Error>"].concat();
    assert_eq!(result_error_types(&typed), ["std::io::Error"]);
    let array = ["Result", "<[u8; N], String>"].concat();
    assert_eq!(result_error_types(&array), ["String"]);
}

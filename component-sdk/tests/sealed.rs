//! The pack-author API is sealed: a pack outside this workspace, depending on `kairos-sdk` the way the
//! wizard's stand-alone packs do, builds against the pack author's half and cannot name, call or enable
//! the runtime's half. Each attempt is compiled by cargo and must fail with the error that says why.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// A component as a pack author writes it: the control that the outside pack builds at all.
const ALLOWED: &str = r#"
use kairos_sdk::descriptor::Descriptor;
use kairos_sdk::{Component, ComponentResult, Context, DataType, Payload, Registry, TypeFilter};

#[derive(Default)]
pub struct Double;

impl Component for Double {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = sample.payload.as_f64().unwrap_or_default();
        ctx.write_processed("out", &sample, Payload::F64(2.0 * value))
    }
}

pub fn register(registry: &mut Registry) {
    registry.pack("outside", "0.1.0", "outside").component::<Double>(
        Descriptor::new("outside.double", "math", "Doubles")
            .input("in", TypeFilter::only(DataType::F64), "")
            .output("out", DataType::F64, "")
            .build(),
    );
}

kairos_sdk::export_pack!(register);
"#;

/// What a pack might try, and the words of the error that must stop it.
const ATTEMPTS: &[(&str, &str, &str)] = &[
    (
        "an output buffer's reader",
        "use kairos_sdk::host::Reader;",
        "could not find `host` in `kairos_sdk`",
    ),
    (
        "the run signal",
        "pub fn stop(signal: &kairos_sdk::RunSignal) { signal.request_stop(); }",
        "`RunSignal` in crate `kairos_sdk`",
    ),
    (
        "the runtime's disciplined clock",
        "use kairos_sdk::DisciplinedClock;",
        "no `DisciplinedClock` in the root",
    ),
    (
        "the runtime's panic reporting",
        "pub fn report() -> String { kairos_sdk::panic_message(&0_u8) }",
        "`panic_message` in crate `kairos_sdk`",
    ),
    (
        "the parts a context is built from",
        "use kairos_sdk::component::ContextParts;",
        "`component` in `kairos_sdk`",
    ),
    (
        "a component's status cell",
        "use kairos_sdk::StatusCell;",
        "no `StatusCell` in the root",
    ),
    (
        "a context's run signal",
        "pub fn stop(ctx: &kairos_sdk::Context) { let _ = ctx.signal(); }",
        "method `signal` is private",
    ),
    (
        "the registry's validation",
        "pub fn check(registry: &kairos_sdk::Registry, diagram: &kairos_diagram::Diagram) { \
         let _ = registry.validate(diagram, None); }",
        "method `validate` is private",
    ),
    (
        "the loader's C conversions",
        "pub use kairos_sdk::abi::ExportedPack;",
        "could not find `abi` in `kairos_sdk`",
    ),
];

struct OutsidePack {
    folder: PathBuf,
    target: PathBuf,
}

impl OutsidePack {
    /// A pack in a folder of its own (`name`), depending on kairos-sdk with `features` added to its entry.
    fn new(name: &str, features: &str) -> OutsidePack {
        let sdk = Path::new(env!("CARGO_MANIFEST_DIR"));
        let folder = std::env::temp_dir().join(format!("kairos-{name}-{}", std::process::id()));
        std::fs::create_dir_all(folder.join("src")).unwrap();
        std::fs::write(
            folder.join("Cargo.toml"),
            format!(
                "[package]\nname = \"outside-pack\"\nversion = \"0.1.0\"\nedition = \"2024\"\n\n\
                 [dependencies]\nkairos-sdk = {{ path = \"{sdk}\"{features} }}\n\
                 kairos-diagram = {{ path = \"{diagram}\" }}\n\n[workspace]\n",
                sdk = sdk.display(),
                diagram = sdk.join("../diagram-format").display(),
            ),
        )
        .unwrap();
        // The workspace's lock file, so that the outside pack builds the same versions, offline.
        std::fs::copy(sdk.join("../Cargo.lock"), folder.join("Cargo.lock")).unwrap();
        OutsidePack {
            folder,
            // Kept between runs, so only the outside pack itself is checked again.
            target: sdk.join("../target/outside-pack"),
        }
    }

    /// `cargo check` of the pack with `source` as its library: its success and its errors.
    fn check(&self, source: &str) -> (bool, String) {
        std::fs::write(self.folder.join("src/lib.rs"), source).unwrap();
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned());
        let output = Command::new(cargo)
            .args(["check", "--offline", "--quiet", "--message-format", "short"])
            .current_dir(&self.folder)
            .env("CARGO_TARGET_DIR", &self.target)
            .env_remove("RUSTFLAGS")
            .output()
            .unwrap();
        (
            output.status.success(),
            String::from_utf8_lossy(&output.stderr).into_owned(),
        )
    }
}

impl Drop for OutsidePack {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.folder);
    }
}

#[test]
fn an_outside_pack_builds_on_the_pack_api_and_cannot_reach_the_runtime_s_half() {
    let pack = OutsidePack::new("outside-pack", "");
    let (built, errors) = pack.check(ALLOWED);
    assert!(built, "a pack written against kairos-sdk alone builds:\n{errors}");
    for (what, attempt, expected) in ATTEMPTS {
        let (built, errors) = pack.check(&format!("{ALLOWED}\n{attempt}\n"));
        assert!(!built, "a pack reached {what} with `{attempt}`");
        assert!(
            errors.contains(expected),
            "{what}: `{attempt}` failed, but not with \"{expected}\":\n{errors}"
        );
    }
}

#[test]
fn the_sdk_has_no_feature_that_opens_the_runtime_s_half() {
    let pack = OutsidePack::new("outside-pack-with-host", ", features = [\"host\"]");
    let (built, errors) = pack.check(ALLOWED);
    assert!(!built, "kairos-sdk accepted a `host` feature");
    assert!(
        errors.contains("does not have that feature") || errors.contains("does not have feature"),
        "{errors}"
    );
}

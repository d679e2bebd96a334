//! `kairos new`: a pack or a component from the templates, through the wizard.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Subcommand;
use kairos_sdk_core::Registry;

/// What `kairos new` generates.
#[derive(Debug, Subcommand)]
pub enum NewCommand {
    /// A pack crate (built in or loaded at run time) with an example component and its unit test.
    Pack {
        /// The pack's name (lower case, digits and _): the prefix of its component types.
        name: String,
        /// The folder to create the pack in (it goes in PATH/NAME).
        #[arg(long, default_value = ".")]
        path: PathBuf,
        /// The kairos-sdk to depend on (default: this installation's).
        #[arg(long, value_name = "PATH")]
        sdk: Option<PathBuf>,
        /// The pack's language: a Rust crate, C++ against the C header of the pack ABI, or Python
        /// (`.py` files, nothing to build).
        #[arg(long, value_enum, default_value = "rust")]
        lang: crate::wizard::Lang,
        /// Overwrite files that exist.
        #[arg(long)]
        force: bool,
    },
    /// A component in a pack made by `kairos new pack`, registered in it. Without a name, it asks.
    Component {
        /// The component's name in the pack (lower case, digits and _); none: ask for every answer.
        name: Option<String>,
        /// The pack's folder.
        #[arg(long, value_name = "DIR", default_value = ".")]
        pack: PathBuf,
        /// An input, NAME:TYPE (TYPE: f64, i64, bool, vector, matrix, text, bytes, image, `point_cloud`, imu,
        /// `gnss_fix`, `can_frame`, pose or any); repeatable.
        #[arg(long = "input", value_name = "NAME:TYPE")]
        inputs: Vec<String>,
        /// An output, NAME:TYPE; repeatable.
        #[arg(long = "output", value_name = "NAME:TYPE")]
        outputs: Vec<String>,
        /// A property, NAME:TYPE=DEFAULT (TYPE: f64, i64, bool, text, path); repeatable.
        #[arg(long = "property", value_name = "NAME:TYPE=DEFAULT")]
        properties: Vec<String>,
        /// An action (a button in the studio); repeatable.
        #[arg(long = "action", value_name = "NAME")]
        actions: Vec<String>,
        /// How it runs.
        #[arg(long, value_enum, default_value = "threaded")]
        mode: crate::wizard::Mode,
        /// The pack's language, checked against the pack (which decides it).
        #[arg(long, value_enum)]
        lang: Option<crate::wizard::Lang>,
        /// Overwrite the component's file if it exists.
        #[arg(long)]
        force: bool,
        /// Check the answers and say what is wrong, writing nothing.
        #[arg(long)]
        dry_run: bool,
    },
}

/// How to make a Python pack's environment. Its tests need numpy, pytest and the SDK's harness, which a
/// system Python seldom has: a virtual environment in the pack's `.venv`, which the runtime then uses to
/// run the pack too.
fn print_venv_step(folder: &std::path::Path, sdk: &std::path::Path) {
    println!(
        "  cd {} && python3 -m venv .venv && .venv/bin/pip install '{}[test]'",
        folder.display(),
        sdk.join("python").display()
    );
}

/// What to do with a pack `kairos new pack` made.
fn print_pack_next_steps(
    lang: crate::wizard::Lang,
    name: &str,
    folder: &std::path::Path,
    path: &std::path::Path,
    sdk: &std::path::Path,
) {
    if lang == crate::wizard::Lang::Python {
        print_venv_step(folder, sdk);
        println!("  cd {} && .venv/bin/python -m pytest", folder.display());
        println!(
            "  kairos --pack-path {} components {name}.     (the pack's .venv runs its components)",
            path.display()
        );
    } else if lang == crate::wizard::Lang::Cpp {
        println!("  cd {} && make", folder.display());
        println!(
            "  kairos --pack-path {}/build components {name}.",
            folder.display()
        );
    } else if crate::wizard::is_workspace_member(folder) {
        let crate_name = folder
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        println!("  cargo test -p {crate_name}        (a member of this workspace, with its lints)");
        println!(
            "  to build it into kairos: three lines, in docs/components.md, \"Adding a pack to this repository\"."
        );
    } else {
        println!("  cd {} && cargo test && cargo build --release", folder.display());
        println!(
            "  kairos --pack-path {}/target/release components {name}.",
            folder.display()
        );
    }
}

/// How to test a component `kairos new component` made in `pack`.
fn print_component_next_steps(pack: &std::path::Path, name: &str) {
    match crate::wizard::pack_lang(pack) {
        Some(crate::wizard::Lang::Python) => {
            if !pack.join(".venv").is_dir() {
                print_venv_step(pack, &crate::wizard::default_sdk_path());
            }
            println!(
                "  cd {} && .venv/bin/python -m pytest test_{name}.py",
                pack.display()
            );
        }
        Some(crate::wizard::Lang::Cpp) => println!("  cd {} && make", pack.display()),
        _ => println!("  cd {} && cargo test", pack.display()),
    }
}

/// `kairos new`: prints what was made, or why nothing was.
pub(super) fn new(what: NewCommand, registry: &Registry) -> ExitCode {
    let result = match what {
        NewCommand::Pack {
            name,
            path,
            sdk,
            lang,
            force,
        } => {
            let sdk = sdk.unwrap_or_else(crate::wizard::default_sdk_path);
            let library = registry.library_info();
            crate::wizard::new_pack(&name, &path, &sdk, &library, lang, force).map(|(folder, notes)| {
                println!("made the pack '{name}' in {}", folder.display());
                print_pack_next_steps(lang, &name, &folder, &path, &sdk);
                notes
            })
        }
        NewCommand::Component {
            name,
            pack,
            inputs,
            outputs,
            properties,
            actions,
            mode,
            lang,
            force,
            dry_run,
        } => {
            let (spec, pack) = match name {
                Some(name) => (
                    crate::wizard::ComponentSpec {
                        name,
                        inputs,
                        outputs,
                        properties,
                        actions,
                        mode,
                    },
                    pack,
                ),
                None => match crate::wizard::ask(&mut std::io::stdin().lock(), &mut std::io::stdout()) {
                    Ok(answers) => answers,
                    Err(error) => {
                        eprintln!("error: {error}");
                        return ExitCode::from(1);
                    }
                },
            };
            let name = spec.name.clone();
            if let (Some(wanted), Some(found)) = (lang, crate::wizard::pack_lang(&pack))
                && wanted != found
            {
                eprintln!(
                    "error: the pack at {} is a {} pack, not {}: make a {} pack with `kairos new pack NAME --lang {}`",
                    pack.display(),
                    found.name(),
                    wanted.name(),
                    wanted.name(),
                    format!("{wanted:?}").to_lowercase()
                );
                return ExitCode::from(1);
            }
            if dry_run {
                return match crate::wizard::check_component(&spec, &pack, &registry.library_info(), force) {
                    Ok(()) => {
                        println!("ok: {name} can be made in {}", pack.display());
                        ExitCode::SUCCESS
                    }
                    Err(error) => {
                        eprintln!("error: {error}");
                        ExitCode::from(1)
                    }
                };
            }
            crate::wizard::new_component(&spec, &pack, &registry.library_info(), force).inspect(|_| {
                let file = match crate::wizard::pack_lang(&pack) {
                    Some(crate::wizard::Lang::Python) => pack.join(format!("{name}.py")),
                    Some(crate::wizard::Lang::Cpp) => pack.join("src").join(format!("{name}.cpp")),
                    _ => pack.join("src").join(format!("{name}.rs")),
                };
                println!("made the component '{name}' in {}", file.display());
                print_component_next_steps(&pack, &name);
            })
        }
    };
    match result {
        Ok(notes) => {
            for note in notes {
                eprintln!("note: {note}");
            }
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::from(1)
        }
    }
}

//! The "New component…" dialog: the answers `kairos new component` takes, checked by it (one source of
//! truth for what is valid), then the component generated, its pack built (cargo or make) and loaded into
//! the local runtime, so it appears in the palette. Build errors are listed with their file and line.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc::{Receiver, channel};

/// One compiler error or warning, where it is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BuildMessage {
    /// `file:line:column` as the compiler wrote it.
    pub place: String,
    /// The message.
    pub text: String,
}

/// Errors in a build's output (rustc's `--message-format short` and gcc both write
/// `file:line:column: error: message`).
pub fn build_errors(output: &str) -> Vec<BuildMessage> {
    output
        .lines()
        .filter_map(|line| {
            let (place, text) = line.split_once(": error")?;
            let mut parts = place.rsplitn(3, ':');
            let (column, row) = (parts.next()?, parts.next()?);
            (column.parse::<u32>().is_ok() && row.parse::<u32>().is_ok()).then(|| BuildMessage {
                place: place.to_owned(),
                text: format!("error{text}"),
            })
        })
        .collect()
}

/// Why `kairos new` made nothing: it could not be run, or it refused the answers (what it said).
#[derive(Debug, thiserror::Error)]
pub enum KairosNewError {
    /// The binary would not start.
    #[error("cannot run {}: {source}", .binary.display())]
    Start {
        /// The `kairos` binary.
        binary: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// It refused: its error lines, as it printed them.
    #[error("{0}")]
    Refused(String),
    /// Making the new pack (to check the component against) was refused.
    #[error("the pack: {0}")]
    Pack(Box<KairosNewError>),
    /// Nothing to ask about yet.
    #[error("give the component a name")]
    NoName,
    /// The check or the generation could not get its thread.
    #[error("cannot start a thread for it: {0}")]
    Thread(#[source] std::io::Error),
}

/// Where the dialog is.
#[derive(Debug)]
pub enum Stage {
    /// Taking answers.
    Editing,
    /// `kairos new --dry-run` checks the answers, on a thread of its own.
    Checking(Receiver<Result<String, KairosNewError>>),
    /// `kairos new` generates the pack and the component, on a thread of its own; then the pack is built.
    Generating(Receiver<Result<PathBuf, KairosNewError>>),
    /// Building the pack in the background.
    Building(Receiver<Result<PathBuf, (String, Vec<BuildMessage>)>>),
    /// The build failed: the compiler's errors.
    Failed(String, Vec<BuildMessage>),
}

/// The dialog's answers and state.
#[derive(Debug)]
pub struct NewComponentDialog {
    /// The pack's folder; made with `kairos new pack` when it does not exist.
    pub pack: String,
    /// A new pack's language: `rust`, `cpp` or `python`.
    pub lang: String,
    /// The component's name.
    pub name: String,
    /// `threaded`, `reactive` or `periodic`.
    pub mode: String,
    /// Comma-separated `name:type`.
    pub inputs: String,
    /// Comma-separated `name:type`.
    pub outputs: String,
    /// Comma-separated `name:type=default`.
    pub properties: String,
    /// Comma-separated names.
    pub actions: String,
    /// What `kairos new` said about the answers, when it refused them, or that they are fine.
    pub verdict: Option<Result<String, KairosNewError>>,
    /// Where the dialog is.
    pub stage: Stage,
}

impl Default for NewComponentDialog {
    fn default() -> Self {
        NewComponentDialog {
            pack: "my_pack".to_owned(),
            lang: "rust".to_owned(),
            name: String::new(),
            mode: "threaded".to_owned(),
            inputs: "in:f64".to_owned(),
            outputs: "out:f64".to_owned(),
            properties: String::new(),
            actions: String::new(),
            verdict: None,
            stage: Stage::Editing,
        }
    }
}

/// What the dialog asks the studio to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// Nothing yet.
    Open,
    /// Closed.
    Closed,
    /// Built: load the library in this folder into the local runtime.
    Load(PathBuf),
}

fn list(text: &str) -> Vec<String> {
    text.split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(str::to_owned)
        .collect()
}

/// What checking the answers runs (see [`NewComponentDialog::check_plan`]).
#[derive(Debug)]
struct CheckPlan {
    args: Vec<String>,
    new_pack: Option<(String, String)>,
}

/// Runs `kairos new component --dry-run`; a pack that does not exist yet is made in a scratch folder
/// first, so that the component is checked against a real one, and removed again after.
fn check_answers(binary: &Path, plan: CheckPlan) -> Result<String, KairosNewError> {
    let CheckPlan { mut args, new_pack } = plan;
    let scratch = std::env::temp_dir().join(format!("kairos-studio-check-{}", std::process::id()));
    if let Some((name, lang)) = new_pack {
        // A scratch copy left by an earlier check, if any; `kairos new pack` says if one is in the way.
        let _ = std::fs::remove_dir_all(&scratch);
        let made = run(
            binary,
            &[
                "new".to_owned(),
                "pack".to_owned(),
                name.clone(),
                "--path".to_owned(),
                scratch.display().to_string(),
                "--lang".to_owned(),
                lang,
            ],
        );
        if let Err(problem) = made {
            return Err(KairosNewError::Pack(Box::new(problem)));
        }
        if let Some(value) = args
            .iter()
            .position(|a| a == "--pack")
            .and_then(|flag| args.get_mut(flag + 1))
        {
            *value = scratch.join(&name).display().to_string();
        }
    }
    let verdict = run(binary, &args).map(|_| "the answers are fine".to_owned());
    // Scratch space in the temporary directory; the next check removes it again.
    let _ = std::fs::remove_dir_all(&scratch);
    verdict
}

fn run(binary: &Path, args: &[String]) -> Result<String, KairosNewError> {
    let output = Command::new(binary)
        .args(args)
        .output()
        .map_err(|source| KairosNewError::Start {
            binary: binary.to_owned(),
            source,
        })?;
    let stdout = String::from_utf8_lossy(&output.stdout).trim().to_owned();
    let stderr = String::from_utf8_lossy(&output.stderr);
    if output.status.success() {
        Ok(stdout)
    } else {
        let errors: Vec<&str> = stderr.lines().filter_map(|l| l.strip_prefix("error: ")).collect();
        Err(KairosNewError::Refused(if errors.is_empty() {
            stderr.trim().to_owned()
        } else {
            errors.join("\n")
        }))
    }
}

impl NewComponentDialog {
    fn component_args(&self, dry_run: bool) -> Vec<String> {
        let mut args = vec![
            "new".to_owned(),
            "component".to_owned(),
            self.name.trim().to_owned(),
            "--pack".to_owned(),
            self.pack.trim().to_owned(),
            "--mode".to_owned(),
            self.mode.clone(),
        ];
        for (flag, values) in [
            ("--input", &self.inputs),
            ("--output", &self.outputs),
            ("--property", &self.properties),
            ("--action", &self.actions),
        ] {
            for value in list(values) {
                args.push(flag.to_owned());
                args.push(value);
            }
        }
        if dry_run {
            args.push("--dry-run".to_owned());
        }
        args
    }

    fn pack_exists(&self) -> bool {
        let folder = Path::new(self.pack.trim());
        folder.join("src/lib.rs").is_file()
            || folder.join("src/pack.cpp").is_file()
            || folder.join(PYTHON_MANIFEST).is_file()
    }

    /// What checking the answers runs: the dry-run arguments, and the pack to make in a scratch folder
    /// first when it does not exist yet (its name and language).
    fn check_plan(&self) -> CheckPlan {
        let pack = (!self.pack_exists()).then(|| {
            let name = Path::new(self.pack.trim())
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            (name, self.lang.clone())
        });
        CheckPlan {
            args: self.component_args(true),
            new_pack: pack,
        }
    }

    /// Asks `kairos new component --dry-run` about the answers, on a thread of its own: the verdict
    /// shows when it comes. A pack that does not exist yet is checked in a scratch copy.
    pub fn check(&mut self, binary: &Path, ctx: &egui::Context) {
        if self.name.trim().is_empty() {
            self.verdict = Some(Err(KairosNewError::NoName));
            return;
        }
        let (plan, binary, ctx) = (self.check_plan(), binary.to_owned(), ctx.clone());
        let (sender, receiver) = channel();
        self.start("studio:check", move || {
            let _ = sender.send(check_answers(&binary, plan));
            ctx.request_repaint();
        });
        self.stage = Stage::Checking(receiver);
    }

    /// Checks the answers, then generates the component (and its pack when new), on a thread of its
    /// own; the pack is built once that is done.
    pub fn create(&mut self, binary: &Path, ctx: &egui::Context) {
        if self.name.trim().is_empty() {
            self.verdict = Some(Err(KairosNewError::NoName));
            return;
        }
        let check = self.check_plan();
        let folder = PathBuf::from(self.pack.trim());
        let new_pack = (!self.pack_exists()).then(|| {
            let parent = folder
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .to_owned();
            let name = folder
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            vec![
                "new".to_owned(),
                "pack".to_owned(),
                name,
                "--path".to_owned(),
                parent.display().to_string(),
                "--lang".to_owned(),
                self.lang.clone(),
            ]
        });
        let component = self.component_args(false);
        let (binary, ctx) = (binary.to_owned(), ctx.clone());
        let (sender, receiver) = channel();
        self.start("studio:generate", move || {
            let generated = check_answers(&binary, check).and_then(|_| {
                if let Some(args) = new_pack {
                    run(&binary, &args).map_err(|problem| KairosNewError::Pack(Box::new(problem)))?;
                }
                run(&binary, &component)?;
                Ok(folder)
            });
            let _ = sender.send(generated);
            ctx.request_repaint();
        });
        self.stage = Stage::Generating(receiver);
    }

    /// Runs `work` on a thread named `name`; a thread that cannot be started is said as the verdict.
    fn start(&mut self, name: &str, work: impl FnOnce() + Send + 'static) {
        if let Err(error) = std::thread::Builder::new().name(name.to_owned()).spawn(work) {
            self.verdict = Some(Err(KairosNewError::Thread(error)));
        }
    }

    /// Builds the generated pack in the background.
    fn build_in_background(&mut self, pack: PathBuf) {
        let (sender, receiver) = channel();
        std::thread::Builder::new()
            .name("studio:build".to_owned())
            .spawn(move || {
                let _ = sender.send(build(&pack));
            })
            .ok();
        self.stage = Stage::Building(receiver);
    }

    /// Takes what a thread of the dialog finished with, if anything; a load to do is returned.
    fn poll(&mut self) -> Option<PathBuf> {
        match &self.stage {
            Stage::Checking(receiver) => {
                if let Ok(verdict) = receiver.try_recv() {
                    self.verdict = Some(verdict);
                    self.stage = Stage::Editing;
                }
            }
            Stage::Generating(receiver) => match receiver.try_recv() {
                Ok(Ok(pack)) => {
                    self.verdict = Some(Ok("generated; building the pack".to_owned()));
                    self.build_in_background(pack);
                }
                Ok(Err(problem)) => {
                    self.verdict = Some(Err(problem));
                    self.stage = Stage::Editing;
                }
                Err(_) => {}
            },
            Stage::Building(receiver) => match receiver.try_recv() {
                Ok(Ok(library_folder)) => {
                    self.stage = Stage::Editing;
                    self.verdict = Some(Ok("built; loading it into the local runtime".to_owned()));
                    return Some(library_folder);
                }
                Ok(Err((summary, errors))) => self.stage = Stage::Failed(summary, errors),
                Err(_) => {}
            },
            Stage::Editing | Stage::Failed(..) => {}
        }
        None
    }

    /// The answers, one field each.
    fn answers(&mut self, ui: &mut egui::Ui) {
        egui::Grid::new("new component").num_columns(2).show(ui, |ui| {
            for (label, value, hint) in [
                ("Pack folder", &mut self.pack, "made if it does not exist"),
                ("Name", &mut self.name, "lower case, digits and _"),
                ("Inputs", &mut self.inputs, "name:type, comma-separated"),
                ("Outputs", &mut self.outputs, "name:type, comma-separated"),
                (
                    "Properties",
                    &mut self.properties,
                    "name:type=default, comma-separated",
                ),
                ("Actions", &mut self.actions, "names, comma-separated"),
            ] {
                let label = ui.label(label);
                ui.add(
                    egui::TextEdit::singleline(value)
                        .hint_text(hint)
                        .desired_width(280.0),
                )
                .labelled_by(label.id);
                ui.end_row();
            }
            let mode_label = ui.label("Mode");
            let _ = egui::ComboBox::new("new component mode", "")
                .selected_text(&self.mode)
                .show_ui(ui, |ui| {
                    for mode in ["threaded", "reactive", "periodic"] {
                        ui.selectable_value(&mut self.mode, mode.to_owned(), mode);
                    }
                })
                .response
                .labelled_by(mode_label.id);
            ui.end_row();
            let language_label = ui.label("New pack in");
            let _ = egui::ComboBox::new("new pack language", "")
                .selected_text(match self.lang.as_str() {
                    "cpp" => "C++",
                    "python" => "Python",
                    _ => "Rust",
                })
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut self.lang, "rust".to_owned(), "Rust");
                    ui.selectable_value(&mut self.lang, "cpp".to_owned(), "C++");
                    ui.selectable_value(&mut self.lang, "python".to_owned(), "Python");
                })
                .response
                .labelled_by(language_label.id);
            ui.end_row();
        });
    }

    /// Shows the dialog; `binary` is the `kairos` that generates.
    pub fn show(&mut self, ctx: &egui::Context, binary: Option<&Path>) -> Outcome {
        let mut open = true;
        let mut outcome = self.poll().map_or(Outcome::Open, Outcome::Load);
        egui::Window::new("New component")
            .collapsible(false)
            .open(&mut open)
            .show(ctx, |ui| {
                let Some(binary) = binary else {
                    ui.colored_label(
                        egui::Color32::LIGHT_RED,
                        "the `kairos` program is not beside the studio or on PATH: it generates the code",
                    );
                    return;
                };
                self.answers(ui);
                ui.horizontal(|ui| {
                    let working = match self.stage {
                        Stage::Checking(_) => Some("checking the answers…"),
                        Stage::Generating(_) => Some("generating the code…"),
                        Stage::Building(_) => Some("building the pack…"),
                        Stage::Editing | Stage::Failed(..) => None,
                    };
                    if ui
                        .add_enabled(working.is_none(), egui::Button::new("Check"))
                        .clicked()
                    {
                        self.check(binary, ctx);
                    }
                    if ui
                        .add_enabled(working.is_none(), egui::Button::new("Create, build and load"))
                        .clicked()
                    {
                        self.create(binary, ctx);
                    }
                    if let Some(working) = working {
                        ui.spinner();
                        ui.label(working);
                    }
                });
                match &self.verdict {
                    Some(Ok(fine)) => {
                        ui.colored_label(egui::Color32::LIGHT_GREEN, fine);
                    }
                    Some(Err(problem)) => {
                        ui.colored_label(egui::Color32::LIGHT_RED, problem.to_string());
                    }
                    None => {}
                }
                if let Stage::Failed(summary, errors) = &self.stage {
                    ui.colored_label(egui::Color32::LIGHT_RED, summary);
                    egui::ScrollArea::vertical().max_height(200.0).show(ui, |ui| {
                        for error in errors {
                            ui.horizontal_wrapped(|ui| {
                                ui.monospace(&error.place);
                                ui.label(&error.text);
                            });
                        }
                    });
                }
            });
        if !open {
            outcome = Outcome::Closed;
        }
        outcome
    }
}

/// A Python pack's manifest: such a pack has nothing to build, and its own folder goes on the pack path.
const PYTHON_MANIFEST: &str = "kairos-pack.toml";

/// Builds the pack at `pack`: `cargo build --release` for a Rust pack, `make` for a C++ one, nothing for a
/// Python one. Returns the folder to put on the pack path, or the errors with their places.
fn build(pack: &Path) -> Result<PathBuf, (String, Vec<BuildMessage>)> {
    if pack.join(PYTHON_MANIFEST).is_file() {
        return Ok(pack.to_owned());
    }
    let cpp = pack.join("Makefile").is_file();
    let mut command = if cpp {
        Command::new("make")
    } else {
        let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned()));
        cargo.args(["build", "--release", "--message-format", "short"]);
        cargo
    };
    let output = command
        .current_dir(pack)
        .output()
        .map_err(|e| (format!("cannot start the build: {e}"), Vec::new()))?;
    if output.status.success() {
        let target = std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| pack.join("target"), PathBuf::from);
        return Ok(if cpp {
            pack.join("build")
        } else {
            target.join("release")
        });
    }
    let stderr = String::from_utf8_lossy(&output.stderr);
    let errors = build_errors(&stderr);
    let summary = if errors.is_empty() {
        stderr.lines().last().unwrap_or("the build failed").to_owned()
    } else {
        format!("the build failed with {} errors", errors.len())
    };
    Err((summary, errors))
}

#[cfg(test)]
mod tests {
    #[test]
    fn build_errors_keep_their_place() {
        let output = "warning: unused\nsrc/blur.rs:12:5: error[E0425]: cannot find value `x`\n\
                      src/pack.cpp:7:3: error: expected ';'\nerror: could not compile";
        let errors = super::build_errors(output);
        assert_eq!(errors.len(), 2);
        assert_eq!(errors[0].place, "src/blur.rs:12:5");
        assert!(errors[0].text.contains("cannot find value"));
        assert_eq!(errors[1].place, "src/pack.cpp:7:3");
    }
}

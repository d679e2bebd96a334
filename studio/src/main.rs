//! `kairos-studio [FILE] [--connect ws://HOST:PORT --token-file FILE] [--certificate FILE]
//! [--allow-clear-text-tokens] [--view OUTPUT]... [--run]`: the studio. Without `--connect` it starts a local
//! runtime (`kairos serve` on loopback with a fresh token) and drives that.

use std::path::PathBuf;
use std::process::ExitCode;

use kairos_studio::client::RuntimeClient;
use kairos_studio::local::LocalRuntime;
use kairos_studio::{Document, StudioApp};

struct Arguments {
    file: Option<PathBuf>,
    connect: Option<String>,
    token_file: Option<PathBuf>,
    reach: kairos_studio::connection::Reach,
    views: Vec<String>,
    run: bool,
}

/// The usage, printed for --help.
const USAGE: &str = "usage: kairos-studio [FILE] [--connect ws://HOST:PORT --token-file FILE] \
                     [--certificate FILE] [--allow-clear-text-tokens] [--view OUTPUT]... [--run]\n  \
                     --connect wss://HOST:PORT  a runtime served over TLS: give --certificate, its certificate \
                     or its authority's (PEM)\n  \
                     --allow-clear-text-tokens  send tokens over plain ws:// to another machine: the runtime's, \
                     and the hosts' of a diagram spread over them (a network you trust)\n  \
                     --view camera.image        opens a viewer on that output\n  \
                     --run                      deploys and starts the diagram once connected";

/// Why the command line is not one the studio takes (or asks for its usage).
#[derive(Debug, thiserror::Error)]
enum ArgumentsError {
    /// `--help`: the usage, printed as it is.
    #[error("{USAGE}")]
    Help,
    /// An option without its value.
    #[error("{0}")]
    Missing(&'static str),
    /// An option the studio does not know.
    #[error("unknown option {0}")]
    Unknown(String),
}

fn arguments() -> Result<Arguments, ArgumentsError> {
    let mut parsed = Arguments {
        file: None,
        connect: None,
        token_file: None,
        reach: kairos_studio::connection::Reach::default(),
        views: Vec::new(),
        run: false,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--connect" => {
                parsed.connect = Some(
                    args.next()
                        .ok_or(ArgumentsError::Missing("--connect needs ws://HOST:PORT"))?,
                );
            }
            "--token-file" => {
                parsed.token_file = Some(
                    args.next()
                        .ok_or(ArgumentsError::Missing("--token-file needs a file"))?
                        .into(),
                );
            }
            "--certificate" => {
                parsed.reach.certificate = Some(
                    args.next()
                        .ok_or(ArgumentsError::Missing("--certificate needs a PEM file"))?
                        .into(),
                );
            }
            // The plural as `kairos deploy` and `kairos serve` spell it, the singular as studios before.
            "--allow-clear-text-tokens" | "--allow-clear-text-token" => {
                parsed.reach.allow_clear_text_token = true;
                kairos_studio::local::trust_the_network();
            }
            "--view" => parsed.views.push(
                args.next()
                    .ok_or(ArgumentsError::Missing("--view needs an output (component.port)"))?,
            ),
            "--run" => parsed.run = true,
            "-h" | "--help" => return Err(ArgumentsError::Help),
            other if other.starts_with('-') => return Err(ArgumentsError::Unknown(other.to_owned())),
            file => parsed.file = Some(file.into()),
        }
    }
    Ok(parsed)
}

/// Without a display there is no window: the diagram runs headless instead (`kairos run FILE --stats`).
fn headless(file: Option<&std::path::Path>) -> ExitCode {
    let Some(file) = file else {
        eprintln!(
            "no display (neither DISPLAY nor WAYLAND_DISPLAY is set): give a diagram file to run it headless"
        );
        return ExitCode::from(2);
    };
    let Some(kairos) = kairos_studio::local::kairos_binary() else {
        eprintln!(
            "no display, and no `kairos` runtime beside the studio or on PATH to run {} headless",
            file.display()
        );
        return ExitCode::from(2);
    };
    eprintln!(
        "no display: running {} headless with `kairos run --stats` (Ctrl-C stops it)",
        file.display()
    );
    match std::process::Command::new(kairos)
        .arg("run")
        .arg(file)
        .arg("--stats")
        .status()
    {
        Ok(status) => ExitCode::from(u8::try_from(status.code().unwrap_or(1)).unwrap_or(1)),
        Err(error) => {
            eprintln!("cannot run kairos: {error}");
            ExitCode::from(1)
        }
    }
}

fn main() -> ExitCode {
    let arguments = match arguments() {
        Ok(arguments) => arguments,
        Err(message) => {
            eprintln!("{message}");
            return ExitCode::from(2);
        }
    };
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        return headless(arguments.file.as_deref());
    }
    // What went wrong before the window opens, said in its log once it does.
    let mut notes: Vec<String> = Vec::new();
    let document = match &arguments.file {
        Some(path) => Document::open(path).unwrap_or_else(|error| {
            notes.push(error.to_string());
            Document::default()
        }),
        None => Document::default(),
    };
    let (local, url, token) = match &arguments.connect {
        Some(url) => {
            // An unreadable token file is said in the log; the connection is tried without a token (a
            // runtime that needs one refuses it, and says so too).
            let token = arguments.token_file.as_ref().and_then(|f| {
                kairos_studio::settings::read_token(f)
                    .map_err(|e| notes.push(e.to_string()))
                    .ok()
            });
            (None, Some(url.clone()), token)
        }
        None => match LocalRuntime::start_for(arguments.file.as_deref()) {
            Ok(local) => {
                let (url, token) = (local.url.clone(), local.token.clone());
                (Some(local), Some(url), Some(token))
            }
            Err(error) => {
                notes.push(error.to_string());
                (None, None, None)
            }
        },
    };
    let label = match (&local, &url) {
        (Some(_), Some(url)) => format!("local runtime {url}"),
        (None, Some(url)) => format!("runtime {url}"),
        _ => "no runtime".to_owned(),
    };
    let mut options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default().with_inner_size([1280.0, 800.0]),
        ..Default::default()
    };
    options.wgpu_options.wgpu_setup =
        eframe::egui_wgpu::WgpuSetup::CreateNew(eframe::egui_wgpu::WgpuSetupCreateNew {
            // eframe takes the refusal as text, which it reports.
            native_adapter_selector: Some(std::sync::Arc::new(
                |adapters: &[eframe::wgpu::Adapter], surface: Option<&eframe::wgpu::Surface<'_>>| {
                    kairos_studio::cloud3d::choose_adapter(adapters, surface).map_err(|e| e.to_string())
                },
            )),
            ..eframe::egui_wgpu::WgpuSetupCreateNew::without_display_handle()
        });
    let result = eframe::run_native(
        "Kairos studio",
        options,
        Box::new(move |creation| {
            let (views, run, reach) = (arguments.views, arguments.run, arguments.reach);
            if let Some(render_state) = &creation.wgpu_render_state {
                kairos_studio::cloud3d::install(render_state);
            }
            let ctx = creation.egui_ctx.clone();
            let client = url.map(|url| {
                let options = reach.options(token);
                RuntimeClient::connect_with(&url, options, kairos_studio::connection::repaint_once(&ctx))
            });
            let mut app = StudioApp::new(
                document,
                kairos_diagram::LibraryInfo::default(),
                client,
                label,
                local,
            )
            .with_startup(views, run)
            .with_reach(reach);
            for note in notes {
                app.session.note(kairos_protocol::LogLevel::Error, note);
            }
            Ok(Box::new(app))
        }),
    );
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("the studio could not open its window: {error}");
            ExitCode::from(1)
        }
    }
}

//! `kairos validate`, `kairos packs`, `kairos components` and `kairos devices`: what this installation has.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use kairos_diagram::LibraryInfo;
use kairos_runtime::PackScan;
use kairos_sdk_core::Registry;
use kairos_sdk_core::host::RegistryValidation as _;

/// What `kairos validate` takes.
#[derive(Debug, clap::Args)]
pub struct ValidateArgs {
    /// The diagram files.
    #[arg(required = true)]
    pub diagrams: Vec<PathBuf>,
}

impl ValidateArgs {
    /// Exit 0 when every diagram is valid.
    pub(super) fn execute(&self, registry: &Registry, scan: &PackScan) -> ExitCode {
        validate(registry, &self.diagrams, scan)
    }
}

/// What `kairos packs` takes.
#[derive(Debug, clap::Args)]
pub struct PacksArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

impl PacksArgs {
    /// Lists the packs.
    pub(super) fn execute(&self, registry: &Registry, scan: &PackScan) -> anyhow::Result<ExitCode> {
        crate::packs::list(registry, scan, self.json)?;
        Ok(ExitCode::SUCCESS)
    }
}

/// What `kairos components` takes.
#[derive(Debug, clap::Args)]
pub struct ComponentsArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Show only types containing this text.
    pub filter: Option<String>,
}

impl ComponentsArgs {
    /// Lists the component library.
    pub(super) fn execute(&self, registry: &Registry) -> anyhow::Result<ExitCode> {
        components(&registry.library_info(), self.json, self.filter.as_deref())?;
        Ok(ExitCode::SUCCESS)
    }
}

/// What `kairos devices` takes.
#[derive(Debug, clap::Args)]
pub struct DevicesArgs {
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

impl DevicesArgs {
    /// Lists this machine's devices.
    pub(super) fn execute(&self) -> anyhow::Result<ExitCode> {
        let devices = kairos_server::devices::list(std::path::Path::new("/"));
        if self.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&devices).context("encoding the devices as JSON")?
            );
        } else {
            print!("{}", kairos_server::devices::text(&devices));
        }
        Ok(ExitCode::SUCCESS)
    }
}

fn validate(registry: &Registry, paths: &[PathBuf], scan: &PackScan) -> ExitCode {
    let mut all_valid = true;
    for path in paths {
        match kairos_diagram::load_flattened(path, registry.subgraphs()) {
            Err(error) => {
                all_valid = false;
                eprint!("{}", error.render());
            }
            Ok((source, flattened)) => {
                let parsed = flattened.parsed;
                let mut diagnostics = registry.validate(&parsed.diagram, Some(&parsed.source_map));
                flattened.origins.annotate(&mut diagnostics);
                crate::packs::say_refused(&mut diagnostics, &scan.refused);
                let name = path.display().to_string();
                if diagnostics.is_empty() {
                    println!("{name}: valid");
                } else {
                    eprint!("{}", kairos_diagram::render_all(&diagnostics, &name, &source));
                    crate::packs::explain_missing(&diagnostics, &scan.searched);
                    if diagnostics.iter().any(kairos_diagram::Diagnostic::is_error) {
                        all_valid = false;
                    } else {
                        println!("{name}: valid (with warnings)");
                    }
                }
            }
        }
    }
    if all_valid {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

fn components(library: &LibraryInfo, json: bool, filter: Option<&str>) -> anyhow::Result<()> {
    let selected: Vec<_> = library
        .components
        .values()
        .filter(|c| filter.is_none_or(|f| c.type_name.contains(f)))
        .collect();
    if json {
        let document = serde_json::json!({
            "packs": library.packs.values().collect::<Vec<_>>(),
            "components": selected,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&document).context("encoding the library as JSON")?
        );
        return Ok(());
    }
    let mut out = String::new();
    for component in selected {
        let _ = writeln!(
            out,
            "{} ({})  [{} / {}, {:?}]",
            component.type_name,
            component.display_name(),
            component.pack,
            component.category,
            component.mode
        );
        let _ = writeln!(out, "    {}", component.doc);
        for input in &component.inputs {
            let _ = writeln!(
                out,
                "    in   {:<12} {} (default {})  {}",
                input.name, input.filter, input.default_policy, input.doc
            );
        }
        for output in &component.outputs {
            let data_type = output.follows_input.as_ref().map_or_else(
                || output.data_type.to_string(),
                |i| format!("same as input '{i}'"),
            );
            let _ = writeln!(
                out,
                "    out  {:<12} {} (buffer {})  {}",
                output.name, data_type, output.default_buffer_size, output.doc
            );
        }
        for property in &component.properties {
            let _ = writeln!(
                out,
                "    prop {:<12} {} = {}{}  {}",
                property.name,
                property.kind.describe(),
                property.default,
                if property.live { " (live)" } else { "" },
                property.doc
            );
        }
        for action in &component.actions {
            let _ = writeln!(out, "    act  {:<12} {}", action.name, action.doc);
        }
        out.push('\n');
    }
    print!("{out}");
    Ok(())
}

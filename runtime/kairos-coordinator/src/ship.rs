//! Shipping packs: what a host lacks of the packs its part needs, sent before the part is deployed.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail};
use kairos_protocol::RequestBody;

use crate::host::Host;
use crate::plan::PackNeed;

/// Sends `host` every pack of `needs` it lacks, or fails naming the pack and the reason: another version
/// loaded there, a pack built into `kairos` missing there (another build of `kairos`), or another platform.
pub fn ship_packs(host: &mut Host, needs: &[PackNeed]) -> anyhow::Result<()> {
    if needs.is_empty() {
        return Ok(());
    }
    let library: kairos_diagram::LibraryInfo = serde_json::from_value(host.call(RequestBody::Library)?)
        .with_context(|| format!("host '{}': its component library is unreadable", host.name()))?;
    for need in needs {
        let (name, version) = (&need.name, &need.version);
        if let Some(there) = library.packs.get(name) {
            if there.version == *version {
                continue;
            }
            bail!(
                "host '{}' has pack '{name}' {} (from {}), and this diagram needs {version}{}: put {version} on \
                 that host's pack path and restart its kairos serve",
                host.name(),
                there.version,
                there.origin,
                need.library
                    .as_ref()
                    .map(|p| format!(" (from {} here)", p.display()))
                    .unwrap_or_default()
            );
        }
        let Some(path) = &need.library else {
            bail!(
                "host '{}' lacks pack '{name}', which is built into this kairos {}: it runs another build of \
                 kairos; install the same kairos there",
                host.name(),
                env!("CARGO_PKG_VERSION")
            );
        };
        if kairos_runtime::python_host::is_python_pack(path) {
            let archive = python_pack_archive(path)
                .with_context(|| format!("pack '{name}': cannot pack its folder {}", path.display()))?;
            send_pack(host, need, kairos_protocol::PYTHON_PACK_PLATFORM, &archive)?;
            println!(
                "shipped Python pack {name} {version} to host '{}' ({} KiB)",
                host.name(),
                archive.len().div_ceil(1024)
            );
            continue;
        }
        let platform = kairos_protocol::this_platform();
        if let Some(theirs) = host.platform().filter(|p| *p != platform) {
            bail!(
                "host '{}' lacks pack '{name}' {version}, and the library here ({}) was built for {platform}, \
                 which cannot load on that host ({theirs}): build the pack for {theirs} and put it on that \
                 host's pack path",
                host.name(),
                path.display()
            );
        }
        let bytes = std::fs::read(path)
            .with_context(|| format!("pack '{name}': cannot read its library {}", path.display()))?;
        send_pack(host, need, &platform, &bytes)?;
        println!(
            "shipped pack {name} {version} to host '{}' ({} KiB)",
            host.name(),
            bytes.len().div_ceil(1024)
        );
    }
    Ok(())
}

/// The files of the Python pack in `folder` as a tar archive: its manifest, code and data, without what
/// belongs to this machine alone (virtual environments, `__pycache__`, hidden folders such as `.venv` or
/// `.git`). The host runs it with its own interpreter, as the manifest names it there.
fn python_pack_archive(folder: &Path) -> std::io::Result<Vec<u8>> {
    let mut archive = tar::Builder::new(Vec::new());
    archive.follow_symlinks(true);
    let mut pending = vec![PathBuf::new()];
    while let Some(relative) = pending.pop() {
        let mut entries: Vec<std::fs::DirEntry> =
            std::fs::read_dir(folder.join(&relative))?.collect::<Result<_, _>>()?;
        entries.sort_by_key(std::fs::DirEntry::file_name);
        for entry in entries {
            let name = entry.file_name();
            let inside = relative.join(&name);
            let path = entry.path();
            let hidden = name.to_string_lossy().starts_with('.');
            if path.is_dir() {
                let environment = path.join("pyvenv.cfg").is_file();
                if !hidden && !environment && name != "__pycache__" {
                    pending.push(inside);
                }
            } else if path.is_file() && !hidden {
                archive.append_path_with_name(&path, &inside)?;
            }
        }
    }
    archive.into_inner()
}

/// Sends one pack library to `host` in `install_pack` chunks.
fn send_pack(host: &mut Host, need: &PackNeed, platform: &str, bytes: &[u8]) -> anyhow::Result<()> {
    use base64::Engine as _;
    let mut offset = 0;
    // An empty library still takes one (empty) chunk, which the host then refuses as no library.
    loop {
        let end = bytes.len().min(offset + kairos_protocol::PACK_CHUNK_BYTES);
        host.call(RequestBody::InstallPack {
            name: need.name.clone(),
            version: need.version.clone(),
            platform: platform.to_owned(),
            size: bytes.len() as u64,
            offset: offset as u64,
            data: base64::engine::general_purpose::STANDARD.encode(&bytes[offset..end]),
        })
        .with_context(|| format!("shipping pack '{}' {}", need.name, need.version))?;
        offset = end;
        if offset >= bytes.len() {
            return Ok(());
        }
    }
}

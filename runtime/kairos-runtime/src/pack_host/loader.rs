//! Loading a pack library: every check made before any call into it, and what a loaded pack offers.

#![allow(
    unsafe_code,
    reason = "opening a shared library and reading the descriptor its entry point returns"
)]

use std::path::{Path, PathBuf};

use kairos_sdk_core::abi::{
    ABI_MAGIC, ABI_VERSION, ENTRY_SYMBOL, KComponentVTable, KHost, KPackDescriptor, KSample, KStr, KValue,
    types::size_u32,
};
use kairos_sdk_core::{ComponentInfo, Registry};

use super::dynamic::{CheckedVTable, DynamicComponent};

/// Why a pack library was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PackLoadError {
    /// The file could not be opened as a shared library (not a library, truncated, wrong architecture).
    #[error("not a loadable shared library: {0}")]
    NotALibrary(String),
    /// The library has no entry symbol.
    #[error("no `{ENTRY_SYMBOL}` symbol: not a Kairos pack (build it with kairos_sdk::export_pack!)")]
    NoEntrySymbol,
    /// The entry returned null (the pack failed to describe itself).
    #[error("`{ENTRY_SYMBOL}` returned no descriptor (the pack failed while describing itself)")]
    NullDescriptor,
    /// Wrong magic number.
    #[error("wrong magic number {found:#018x}: not a Kairos pack descriptor")]
    BadMagic {
        /// What was found.
        found: u64,
    },
    /// Another ABI version.
    #[error("pack ABI version {found} is {}; this runtime speaks version {ABI_VERSION}: rebuild the pack against this SDK", if *.found > ABI_VERSION { "newer" } else { "older" })]
    AbiVersion {
        /// The pack's version.
        found: u32,
    },
    /// A struct size differs: the pack was built from another header.
    #[error(
        "layout mismatch: {what} is {found} bytes in the pack, {expected} here; rebuild the pack against this SDK"
    )]
    Layout {
        /// Which struct.
        what: &'static str,
        /// Its size in the pack.
        found: u32,
        /// Its size here.
        expected: u32,
    },
    /// A string field is not UTF-8 or the name is empty.
    #[error("invalid {0} in the pack descriptor")]
    BadField(&'static str),
    /// The pack's version is not a semantic version.
    #[error(
        "the pack descriptor's `version` field is {value:?}, not a semantic version ({reason}); write \
         MAJOR.MINOR.PATCH, e.g. \"0.1.0\", in the pack's Cargo.toml or export_pack! call"
    )]
    BadVersion {
        /// The version text found.
        value: String,
        /// Why it does not read.
        reason: String,
    },
    /// A component descriptor could not be read.
    #[error("component {index}: descriptor is not valid JSON for this SDK: {reason}")]
    BadComponent {
        /// Position in the table.
        index: usize,
        /// Why.
        reason: String,
    },
    /// A component table has a null function: calling it would crash the runtime.
    #[error(
        "component {index} ('{type_name}') has no `{function}` function (a null pointer in its component table): fill every function of kairos_component_vtable"
    )]
    NullFunction {
        /// Position in the table.
        index: usize,
        /// The component's type name.
        type_name: String,
        /// The C name of the missing function.
        function: &'static str,
    },
    /// The pack was built against an incompatible SDK.
    #[error("built against kairos-sdk {found}, incompatible with this runtime's {expected}")]
    SdkVersion {
        /// The pack's SDK version.
        found: String,
        /// This SDK's version.
        expected: &'static str,
    },
}

/// A pack library that passed every check; its code stays loaded for the life of the process.
#[derive(Debug, Clone)]
pub struct LoadedPack {
    /// Where it was loaded from.
    pub path: PathBuf,
    /// The pack's name.
    pub name: String,
    /// The pack's version.
    pub version: String,
    /// The SDK version it was built with.
    pub sdk_version: String,
    components: Vec<(ComponentInfo, CheckedVTable)>,
}

impl LoadedPack {
    /// The component types it offers.
    pub fn component_infos(&self) -> impl Iterator<Item = &ComponentInfo> {
        self.components.iter().map(|(info, _)| info)
    }

    /// Adds the pack and its components to `registry`.
    pub fn register(&self, registry: &mut Registry) {
        let origin = self.path.display().to_string();
        let mut pack = registry.pack(&self.name, &self.version, &origin);
        if let Some(folder) = self.path.parent() {
            crate::packs::register_subgraphs(&mut pack, &folder.join(format!("{}.subgraphs", self.name)));
        }
        for (info, vtable) in &self.components {
            let vtable = *vtable;
            pack.component_with(info.clone(), move || Box::new(DynamicComponent::new(vtable)));
        }
    }
}

/// Whether a pack built with SDK `version` can run here: the same major version, and for 0.x the same
/// minor version (semantic versioning's rule for pre-1.0 releases).
fn sdk_compatible(version: &str) -> bool {
    let (Ok(theirs), Ok(ours)) = (
        semver::Version::parse(version),
        semver::Version::parse(kairos_sdk_core::SDK_VERSION),
    ) else {
        return false;
    };
    theirs.major == ours.major && (ours.major > 0 || theirs.minor == ours.minor)
}

/// Checks that an ELF file is a complete shared object before handing it to the dynamic loader, which
/// maps a truncated file and then dies of SIGBUS touching the missing pages.
#[cfg(target_os = "linux")]
fn check_elf(path: &Path) -> Result<(), PackLoadError> {
    fn field(bytes: &[u8], at: usize, size: usize) -> Option<u64> {
        let slice = bytes.get(at..at.checked_add(size)?)?;
        let mut value = [0_u8; 8];
        value.get_mut(..size)?.copy_from_slice(slice);
        Some(u64::from_le_bytes(value))
    }
    let refuse = |why: &str| PackLoadError::NotALibrary(why.to_owned());
    let bytes =
        std::fs::read(path).map_err(|e| PackLoadError::NotALibrary(format!("cannot read it: {e}")))?;
    if bytes.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err(refuse("not an ELF file"));
    }
    // 64-bit, little-endian: what this runtime is built for.
    if bytes.get(4) != Some(&2) || bytes.get(5) != Some(&1) {
        return Err(refuse("not a 64-bit little-endian ELF file"));
    }
    if field(&bytes, 16, 2) != Some(3) {
        return Err(refuse(
            "an ELF file, but not a shared library (build the pack with crate-type cdylib, or -shared)",
        ));
    }
    let len = bytes.len() as u64;
    let truncated = || refuse("truncated: the file ends before the data its headers describe");
    let table_end = |offset: u64, entry: u64, count: u64| offset.checked_add(entry.checked_mul(count)?);
    let (phoff, phentsize, phnum) = (field(&bytes, 32, 8), field(&bytes, 54, 2), field(&bytes, 56, 2));
    let (shoff, shentsize, shnum) = (field(&bytes, 40, 8), field(&bytes, 58, 2), field(&bytes, 60, 2));
    let (Some(phoff), Some(phentsize), Some(phnum), Some(shoff), Some(shentsize), Some(shnum)) =
        (phoff, phentsize, phnum, shoff, shentsize, shnum)
    else {
        return Err(truncated());
    };
    if table_end(phoff, phentsize, phnum).is_none_or(|end| end > len)
        || table_end(shoff, shentsize, shnum).is_none_or(|end| end > len)
    {
        return Err(truncated());
    }
    for index in 0..phnum {
        let header = usize::try_from(phoff + index * phentsize).map_err(|_| truncated())?;
        let (offset, file_size) = (field(&bytes, header + 8, 8), field(&bytes, header + 32, 8));
        let (Some(offset), Some(file_size)) = (offset, file_size) else {
            return Err(truncated());
        };
        if offset.checked_add(file_size).is_none_or(|end| end > len) {
            return Err(truncated());
        }
    }
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn check_elf(_path: &Path) -> Result<(), PackLoadError> {
    Ok(())
}

/// A pack names itself and gives a semantic version.
fn check_identity(name: &str, version: &str) -> Result<(), PackLoadError> {
    if name.is_empty() {
        return Err(PackLoadError::BadField("pack name (it is empty)"));
    }
    semver::Version::parse(version)
        .map(|_| ())
        .map_err(|error| PackLoadError::BadVersion {
            value: version.to_owned(),
            reason: error.to_string(),
        })
}

/// Opens `path`, checks its descriptor entirely, and keeps the library loaded for good.
pub fn load_pack(path: &Path) -> Result<LoadedPack, PackLoadError> {
    check_elf(path)?;
    // Said before the first call into the library (its initialisers, then its entry point), so that a
    // pack that aborts the process there is named by the last line of the log.
    tracing::info!("loading pack library {}", path.display());
    // SAFETY: loading a library runs its initialisers. Pack libraries are trusted code chosen by the user
    // (a pack path); everything after this is checked before it is called.
    let library =
        unsafe { libloading::Library::new(path) }.map_err(|e| PackLoadError::NotALibrary(cause_of(&e)))?;
    // Never unloaded: component code and static data may be referenced for the rest of the process.
    let library: &'static libloading::Library = Box::leak(Box::new(library));
    let symbol = format!("{ENTRY_SYMBOL}\0");
    // SAFETY: the symbol, if present, is the pack entry with this signature (the ABI contract); a wrong
    // signature is caught by the magic and layout checks before any further call.
    let entry: libloading::Symbol<'static, unsafe extern "C" fn() -> *const KPackDescriptor> =
        unsafe { library.get(symbol.as_bytes()) }.map_err(|_| PackLoadError::NoEntrySymbol)?;
    // SAFETY: calling the entry is the first call into the pack; it returns a pointer to static data.
    let descriptor = unsafe { entry() };
    // SAFETY: non-null pointers from the entry point to a descriptor that lives as long as the library.
    let descriptor: &'static KPackDescriptor =
        unsafe { descriptor.as_ref() }.ok_or(PackLoadError::NullDescriptor)?;
    check_descriptor(descriptor)?;
    let text = |field: KStr, what: &'static str| {
        // SAFETY: the layout check passed, so the string fields are KStr pointing into the library's data.
        unsafe { field.as_str() }
            .map(str::to_owned)
            .ok_or(PackLoadError::BadField(what))
    };
    let name = text(descriptor.name, "pack name")?;
    let version = text(descriptor.version, "pack version")?;
    let sdk_version = text(descriptor.sdk_version, "SDK version")?;
    check_identity(&name, &version)?;
    if !sdk_compatible(&sdk_version) {
        return Err(PackLoadError::SdkVersion {
            found: sdk_version,
            expected: kairos_sdk_core::SDK_VERSION,
        });
    }
    let vtables: &'static [KComponentVTable] = if descriptor.component_count == 0 {
        &[]
    } else if descriptor.components.is_null() {
        return Err(PackLoadError::BadField("component table"));
    } else {
        // SAFETY: the descriptor promises `component_count` vtables at `components`, static in the library.
        unsafe { std::slice::from_raw_parts(descriptor.components, descriptor.component_count) }
    };
    let mut components = Vec::new();
    for (index, vtable) in vtables.iter().enumerate() {
        let bad = |reason: String| PackLoadError::BadComponent { index, reason };
        // SAFETY: as for the pack's own strings.
        let json = unsafe { vtable.descriptor_json.as_str() }.ok_or_else(|| bad("not UTF-8".to_owned()))?;
        let mut info: ComponentInfo = serde_json::from_str(json).map_err(|e| bad(e.to_string()))?;
        info.pack.clone_from(&name);
        let checked = CheckedVTable::of(vtable).map_err(|function| PackLoadError::NullFunction {
            index,
            type_name: info.type_name.clone(),
            function,
        })?;
        components.push((info, checked));
    }
    Ok(LoadedPack {
        path: path.to_owned(),
        name,
        version,
        sdk_version,
        components,
    })
}

fn check_descriptor(descriptor: &KPackDescriptor) -> Result<(), PackLoadError> {
    if descriptor.magic != ABI_MAGIC {
        return Err(PackLoadError::BadMagic {
            found: descriptor.magic,
        });
    }
    if descriptor.abi_version != ABI_VERSION {
        return Err(PackLoadError::AbiVersion {
            found: descriptor.abi_version,
        });
    }
    let checks = [
        (
            "the pack descriptor",
            descriptor.descriptor_size,
            size_u32::<KPackDescriptor>(),
        ),
        ("the sample struct", descriptor.sample_size, size_u32::<KSample>()),
        ("the host table", descriptor.host_size, size_u32::<KHost>()),
        (
            "the component table",
            descriptor.vtable_size,
            size_u32::<KComponentVTable>(),
        ),
        ("the value struct", descriptor.value_size, size_u32::<KValue>()),
    ];
    for (what, found, expected) in checks {
        if found != expected {
            return Err(PackLoadError::Layout {
                what,
                found,
                expected,
            });
        }
    }
    Ok(())
}

/// What the dynamic loader said, with its cause: `dlopen failed` alone would hide which file or which
/// missing dependency library is at fault.
fn cause_of(error: &libloading::Error) -> String {
    let mut text = error.to_string();
    let mut source = std::error::Error::source(error);
    while let Some(cause) = source {
        text.push_str(": ");
        text.push_str(&cause.to_string());
        source = cause.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::check_identity;

    #[test]
    fn a_bad_pack_version_is_named_with_its_field_and_value() {
        assert!(check_identity("vision", "0.1.0").is_ok());
        let error = check_identity("vision", "v1").unwrap_err().to_string();
        assert!(
            error.starts_with("the pack descriptor's `version` field is \"v1\", not a semantic version"),
            "{error}"
        );
        assert!(
            check_identity("", "0.1.0")
                .unwrap_err()
                .to_string()
                .contains("pack name")
        );
    }
}

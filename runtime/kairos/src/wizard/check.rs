//! Checking: names, port and property specifications read and refused with a reason and a fix.

use kairos_diagram::DataType;
use serde::Serialize;

use super::{KEYWORDS, Refusal, refuse};

/// `smoother_2` from `Smoother-2`: a name as it could be written.
pub(super) fn snake(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_ascii_uppercase() {
            if i > 0 && !out.ends_with('_') {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
        } else if c.is_ascii_alphanumeric() {
            out.push(c);
        } else if !out.ends_with('_') {
            out.push('_');
        }
    }
    let out = out.trim_matches('_').to_owned();
    if out.starts_with(|c: char| c.is_ascii_digit()) {
        format!("n{out}")
    } else {
        out
    }
}

/// Checks a name for a pack, component, port, property or action: lower-case letters, digits and `_`,
/// starting with a letter; a component's name (a Rust module and type) may not be a Rust keyword.
pub fn check_name(what: &str, name: &str) -> Result<(), Refusal> {
    let well_formed = name.starts_with(|c: char| c.is_ascii_lowercase())
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    if !well_formed {
        let better = snake(name);
        return Err(refuse(
            format!(
                "'{name}' is not a valid {what} name (lower-case letters, digits and _, starting with a letter)"
            ),
            (!better.is_empty() && !KEYWORDS.contains(&better.as_str())).then(|| format!("try '{better}'")),
        ));
    }
    if what == "component" && KEYWORDS.contains(&name) {
        return Err(refuse(
            format!("'{name}' is a Rust keyword and cannot name a {what}"),
            Some(format!("try '{name}_'")),
        ));
    }
    Ok(())
}

/// A built-in data type (what `--input` and `--output` take: `DataType::BUILT_IN`'s names), or `any` for an
/// input when `any_allowed`.
pub(super) fn parse_type(what: &str, text: &str, any_allowed: bool) -> Result<Option<DataType>, Refusal> {
    if any_allowed && text == "any" {
        return Ok(None);
    }
    if let Some(data_type) = DataType::BUILT_IN.iter().find(|t| t.name() == text) {
        return Ok(Some(data_type.clone()));
    }
    let names: Vec<&str> = DataType::BUILT_IN
        .iter()
        .map(DataType::name)
        .chain(any_allowed.then_some("any"))
        .collect();
    Err(refuse(
        format!("unknown type '{text}' for {what} (one of {})", names.join(", ")),
        kairos_diagram::did_you_mean(text, names.iter().copied()),
    ))
}

/// `name:type` into its two halves, both checked.
pub(super) fn parse_port(
    kind: &str,
    text: &str,
    any_allowed: bool,
) -> Result<(String, Option<DataType>), Refusal> {
    let Some((name, type_name)) = text.split_once(':') else {
        return Err(refuse(
            format!("{kind} '{text}' has no type"),
            Some(format!("write it name:type, e.g. '{text}:f64'")),
        ));
    };
    check_name(kind, name)?;
    Ok((
        name.to_owned(),
        parse_type(&format!("{kind} '{name}'"), type_name, any_allowed)?,
    ))
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct PortView {
    pub(super) name: String,
    #[serde(rename = "type")]
    pub(super) type_expr: String,
    pub(super) filter: String,
    pub(super) type_name: String,
    pub(super) test_payload: Option<String>,
    pub(super) empty: Option<String>,
}

#[derive(Debug, Serialize)]
pub(super) struct PropertyView {
    pub(super) name: String,
    pub(super) builder: String,
    pub(super) getter: String,
    /// The same property with the Python SDK's builder.
    pub(super) python: String,
}

pub(super) fn type_expr(data_type: &DataType) -> String {
    let variant = match data_type {
        DataType::F64 => "F64",
        DataType::I64 => "I64",
        DataType::Bool => "Bool",
        DataType::Vector => "Vector",
        DataType::Matrix => "Matrix",
        DataType::Text => "Text",
        DataType::Bytes => "Bytes",
        DataType::Image => "Image",
        DataType::PointCloud => "PointCloud",
        DataType::Imu => "Imu",
        DataType::GnssFix => "GnssFix",
        DataType::CanFrame => "CanFrame",
        DataType::Pose => "Pose",
        // A pack-defined type travels as bytes.
        DataType::Custom(_) => return "DataType::Bytes".to_owned(),
    };
    format!("DataType::{variant}")
}

/// A value of the type for a unit test's input, for the simple types.
pub(super) fn test_payload(data_type: Option<&DataType>) -> Option<String> {
    Some(
        match data_type {
            None | Some(DataType::F64) => "Payload::F64(1.5)",
            Some(DataType::I64) => "Payload::I64(3)",
            Some(DataType::Bool) => "Payload::Bool(true)",
            Some(DataType::Text) => "Payload::Text(\"hello\".into())",
            _ => return None,
        }
        .to_owned(),
    )
}

/// The type's empty value, for the simple types.
pub(super) fn empty_payload(data_type: &DataType) -> Option<String> {
    Some(
        match data_type {
            DataType::F64 => "Payload::F64(0.0)",
            DataType::I64 => "Payload::I64(0)",
            DataType::Bool => "Payload::Bool(false)",
            DataType::Text => "Payload::Text(\"\".into())",
            _ => return None,
        }
        .to_owned(),
    )
}

/// What a source with this output type writes each cycle, for the simple types.
pub(super) fn source_payload(data_type: &DataType) -> Option<String> {
    Some(match data_type {
        DataType::F64 => "Payload::F64(self.count as f64)".to_owned(),
        DataType::I64 => "Payload::I64(i64::try_from(self.count).unwrap_or(i64::MAX))".to_owned(),
        DataType::Bool => "Payload::Bool(self.count % 2 == 0)".to_owned(),
        DataType::Text => "Payload::Text(format!(\"sample {}\", self.count).into())".to_owned(),
        _ => return None,
    })
}

pub(super) fn property_view(text: &str) -> Result<PropertyView, Refusal> {
    let Some((head, default)) = text.split_once('=') else {
        return Err(refuse(
            format!("property '{text}' has no default"),
            Some("write it name:type=default, e.g. 'gain:f64=2.0'".to_owned()),
        ));
    };
    let Some((name, kind)) = head.split_once(':') else {
        return Err(refuse(
            format!("property '{text}' has no type"),
            Some(format!("write it name:type=default, e.g. '{head}:f64={default}'")),
        ));
    };
    check_name("property", name)?;
    let malformed = |expected: &str| {
        refuse(
            format!("the default '{default}' of property '{name}' is not {expected}"),
            None,
        )
    };
    let (builder, getter) = match kind {
        "f64" => {
            let value: f64 = default.parse().map_err(|_| malformed("a number"))?;
            if !value.is_finite() {
                return Err(malformed("a finite number"));
            }
            (format!("Property::f64(\"{name}\", {value:?})"), "f64_property")
        }
        "i64" => {
            let value: i64 = default.parse().map_err(|_| malformed("a whole number"))?;
            (format!("Property::i64(\"{name}\", {value})"), "i64_property")
        }
        "bool" => {
            let value: bool = default.parse().map_err(|_| malformed("true or false"))?;
            (format!("Property::bool(\"{name}\", {value})"), "bool_property")
        }
        "text" | "path" => (
            format!("Property::{kind}(\"{name}\", {default:?})"),
            "text_property",
        ),
        other => {
            return Err(refuse(
                format!("unknown property type '{other}' for '{name}' (f64, i64, bool, text or path)"),
                kairos_diagram::did_you_mean(other, ["f64", "i64", "bool", "text", "path"]),
            ));
        }
    };
    let python = match kind {
        "bool" => format!(
            "Property.bool(\"{name}\", {})",
            if default.trim() == "true" { "True" } else { "False" }
        ),
        _ => builder.replacen("Property::", "Property.", 1),
    };
    Ok(PropertyView {
        name: name.to_owned(),
        builder,
        getter: getter.to_owned(),
        python,
    })
}

/// Refuses a new pack's name that a pack of `library` (the built-in ones and those on the pack path)
/// already has: both could not be loaded together.
pub(super) fn check_pack_name_free(name: &str, library: &kairos_diagram::LibraryInfo) -> Result<(), Refusal> {
    match library.packs.get(name) {
        None => Ok(()),
        Some(pack) if pack.origin == "built-in" => Err(refuse(
            format!("'{name}' is the name of a built-in pack"),
            Some("choose another".to_owned()),
        )),
        Some(pack) => Err(refuse(
            format!(
                "'{name}' is the name of a pack on the pack path ({})",
                pack.origin
            ),
            Some("choose another".to_owned()),
        )),
    }
}

//! Writing a component into a pack of each language, and registering it there.

use std::collections::BTreeSet;

use minijinja::context;

use super::check::PortView;
use super::plan::{Plan, Target, cpp_descriptor, doc_line};
use super::render::{format, render, write_new};
use super::{
    CPP_COMPONENTS_MARKER, CPP_DECLARATIONS_MARKER, ComponentSpec, Lang, MODULES_MARKER, Mode,
    REGISTER_MARKER, Refusal, WizardError, refuse,
};

/// Writes a Rust component and registers it in the pack's `lib.rs`.
pub(super) fn write_rust(
    spec: &ComponentSpec,
    target: &Target,
    plan: &Plan,
    force: bool,
) -> Result<Vec<String>, WizardError> {
    let mut sdk_uses = vec![
        "Component",
        "ComponentInfo",
        "ComponentResult",
        "Context",
        "ExecutionMode",
        "Value",
    ];
    if !plan.outputs.is_empty() || plan.inputs.iter().any(|i| i.type_name != "any") {
        sdk_uses.push("DataType");
    }
    let todo = !plan.pass_through
        && plan.numeric.is_none()
        && plan.first_input().is_some()
        && plan.first_output().is_some_and(|o| o.empty.is_some());
    if plan.numeric.is_some() || plan.source.is_some() || todo {
        sdk_uses.push("Payload");
    }
    if !plan.inputs.is_empty() {
        sdk_uses.push("TypeFilter");
    }
    sdk_uses.sort_unstable();
    let mode = match spec.mode {
        Mode::Threaded => "Threaded",
        Mode::Reactive => "Reactive",
        Mode::Periodic => "Periodic",
    };
    let values = context! {
        name => spec.name,
        type_name => target.type_name,
        struct_name => plan.struct_name,
        category => target.pack_name,
        doc => doc_line(spec),
        mode => mode,
        inputs => plan.inputs,
        outputs => plan.outputs,
        properties => plan.properties,
        actions => spec.actions,
        first_input => plan.first_input(),
        first_output => plan.first_output(),
        pass_through => plan.pass_through,
        numeric => plan.numeric,
        source_payload => plan.source,
        sdk_uses => sdk_uses.join(", "),
        descriptor_uses => if plan.properties.is_empty() { "Descriptor" } else { "{Descriptor, Property}" },
    };
    write_new(&target.module_path, &render("component.rs", values)?, force)?;
    if !target.registered {
        let index = target
            .index
            .replacen(
                MODULES_MARKER,
                &format!("pub mod {};\n{MODULES_MARKER}", spec.name),
                1,
            )
            .replacen(
                REGISTER_MARKER,
                &format!(
                    "pack.component::<{name}::{struct_name}>({name}::descriptor());\n    {REGISTER_MARKER}",
                    name = spec.name,
                    struct_name = plan.struct_name
                ),
                1,
            );
        std::fs::write(&target.index_path, index).map_err(|source| WizardError::Write {
            path: target.index_path.clone(),
            source,
        })?;
    }
    Ok(format(&[target.module_path.clone(), target.index_path.clone()])
        .into_iter()
        .collect())
}

pub(super) fn check_python_mode(spec: &ComponentSpec, target: &Target) -> Result<(), Refusal> {
    if target.lang == Lang::Python && spec.mode == Mode::Reactive {
        return Err(refuse(
            "a Python component runs threaded or periodic (a reactive one would run Python in its producer's \
             thread): use --mode threaded",
            None,
        ));
    }
    Ok(())
}

/// The SDK constant naming a data type in Python (`F64`, `POINT_CLOUD`, `ANY`).
pub(super) fn python_type(type_name: &str) -> String {
    type_name.to_ascii_uppercase()
}

/// What a Python source writes, by type.
pub(super) fn python_source(type_name: &str) -> Option<&'static str> {
    Some(match type_name {
        "f64" => "float(self.count)",
        "i64" => "self.count",
        "bool" => "self.count % 2 == 0",
        "text" => "f\"sample {self.count}\"",
        "bytes" => "bytes([self.count % 256])",
        "vector" => "[float(self.count)] * 3",
        _ => return None,
    })
}

/// Writes a Python component and its pytest test beside it: the pack reads every `.py` file, so nothing
/// else changes.
pub(super) fn write_python(
    spec: &ComponentSpec,
    target: &Target,
    plan: &Plan,
    force: bool,
) -> Result<Vec<String>, WizardError> {
    check_python_mode(spec, target)?;
    let mut imports = BTreeSet::from(["Component".to_owned(), "Descriptor".to_owned()]);
    if !plan.properties.is_empty() {
        imports.insert("Property".to_owned());
    }
    let port = |p: &PortView| {
        let py_type = python_type(&p.type_name);
        serde_json::json!({"name": p.name, "py_type": py_type})
    };
    let inputs: Vec<_> = plan.inputs.iter().map(port).collect();
    let outputs: Vec<_> = plan.outputs.iter().map(port).collect();
    for view in plan.inputs.iter().chain(&plan.outputs) {
        imports.insert(python_type(&view.type_name));
    }
    let input_type = plan.first_input().map(|i| i.type_name.as_str());
    // A sample of the first input's type for the generated test, and what the test must import for it.
    let (test_value, test_import) = match input_type {
        Some("f64" | "any") => (Some("1.5"), None),
        Some("i64") => (Some("3"), None),
        Some("bool") => (Some("True"), None),
        Some("text") => (Some("\"hello\""), None),
        Some("bytes") => (Some("b\"\\x01\\x02\""), None),
        Some("vector") => (Some("[1.0, 2.0, 3.0]"), None),
        Some("matrix") => (Some("[[1.0, 2.0], [3.0, 4.0]]"), None),
        Some("image") => (Some("np.zeros((4, 6, 3), np.uint8)"), Some("import numpy as np")),
        Some("point_cloud") => (Some("np.zeros((5, 3), np.float32)"), Some("import numpy as np")),
        Some("imu") => (
            Some("Imu((0.0, 0.0, 0.1), (0.0, 0.0, 9.81))"),
            Some("from kairos_sdk import Imu"),
        ),
        Some("gnss_fix") => (
            Some("GnssFix(48.8584, 2.2945, 35.0)"),
            Some("from kairos_sdk import GnssFix"),
        ),
        Some("can_frame") => (
            Some("CanFrame(0x123, b\"\\x01\\x02\")"),
            Some("from kairos_sdk import CanFrame"),
        ),
        Some("pose") => (Some("Pose((1.0, 2.0, 0.0))"), Some("from kairos_sdk import Pose")),
        _ => (None, None),
    };
    // Compared as they are only where Python's `==` says yes or no (not numpy arrays).
    let comparable = matches!(
        input_type,
        Some("f64" | "any" | "i64" | "bool" | "text" | "bytes")
    );
    let factor_default = plan.factor.as_ref().and_then(|name| {
        spec.properties
            .iter()
            .find_map(|p| p.strip_prefix(&format!("{name}:f64=")))
            .and_then(|v| v.parse::<f64>().ok())
    });
    let input_value = match input_type {
        Some("i64") => 3.0,
        Some("bool") => 1.0,
        _ => 1.5,
    };
    let numeric = plan.numeric.as_ref().map(|_| match &plan.factor {
        Some(name) => format!("float(sample.data) * ctx.property(\"{name}\")"),
        None => "float(sample.data)".to_owned(),
    });
    let expected = if plan.pass_through {
        test_value.filter(|_| comparable).map(str::to_owned)
    } else if numeric.is_some() {
        Some(format!("{:?}", input_value * factor_default.unwrap_or(1.0)))
    } else {
        None
    };
    let source = plan
        .first_output()
        .and_then(|o| python_source(&o.type_name))
        .filter(|_| plan.first_input().is_none());
    let values = context! {
        name => spec.name,
        type_name => target.type_name,
        class_name => plan.struct_name,
        category => target.pack_name,
        doc => doc_line(spec),
        periodic => spec.mode == Mode::Periodic,
        inputs => inputs,
        outputs => outputs,
        properties => plan.properties,
        actions => spec.actions,
        first_input => plan.first_input().map(port),
        first_output => plan.first_output().map(port),
        pass_through => plan.pass_through,
        numeric => numeric,
        source => source,
        test_value => test_value,
        test_import => test_import,
        expected => expected,
        imports => imports.into_iter().collect::<Vec<_>>().join(", "),
    };
    write_new(
        &target.module_path,
        &render("python/component.py", values.clone())?,
        force,
    )?;
    let test_path = target
        .module_path
        .with_file_name(format!("test_{}.py", spec.name));
    write_new(&test_path, &render("python/test_component.py", values)?, force)?;
    Ok(Vec::new())
}

/// Writes a C++ component and lists it in the pack's `pack.cpp`.
pub(super) fn write_cpp(
    spec: &ComponentSpec,
    target: &Target,
    plan: &Plan,
    force: bool,
) -> Result<Vec<String>, WizardError> {
    let descriptor = cpp_descriptor(spec, &target.type_name, &target.pack_name)?;
    let factor_default = plan
        .factor
        .as_ref()
        .and_then(|name| {
            spec.properties
                .iter()
                .find(|p| p.starts_with(&format!("{name}:")))
        })
        .and_then(|p| p.split_once('=').map(|(_, d)| d.to_owned()))
        .unwrap_or_else(|| "1.0".to_owned());
    let source = plan
        .first_output()
        .filter(|o| plan.first_input().is_none() && ["f64", "i64", "bool"].contains(&o.type_name.as_str()))
        .map(|o| o.type_name.clone());
    let code = render(
        "cpp/component.cpp",
        context! {
            name => spec.name,
            type_name => target.type_name,
            struct_name => plan.struct_name,
            doc => doc_line(spec),
            descriptor_json => descriptor,
            mode => format!("{:?}", spec.mode).to_lowercase(),
            first_input => plan.first_input(),
            first_output => plan.first_output(),
            numeric => plan.numeric.is_some(),
            factor => plan.factor,
            factor_default => factor_default,
            source => source,
            actions => spec.actions,
        },
    )?;
    write_new(&target.module_path, &code, force)?;
    if !target.registered {
        let index = target
            .index
            .replacen(
                CPP_DECLARATIONS_MARKER,
                &format!(
                    "kairos_component_vtable {}_component();\n{CPP_DECLARATIONS_MARKER}",
                    spec.name
                ),
                1,
            )
            .replacen(
                CPP_COMPONENTS_MARKER,
                &format!("{}_component(),\n        {CPP_COMPONENTS_MARKER}", spec.name),
                1,
            );
        std::fs::write(&target.index_path, index).map_err(|source| WizardError::Write {
            path: target.index_path.clone(),
            source,
        })?;
    }
    Ok(Vec::new())
}

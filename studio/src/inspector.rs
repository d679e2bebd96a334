//! The inspector: the selected connection's reader settings, or the selected component's description,
//! properties (one widget per kind, each labelled by the property's name), actions and failure. Edits are
//! pushed as [`Command`]s.

use egui::{Color32, RichText};
use kairos_diagram::{
    ComponentInfo, ComponentInstance, Connection, PropertyInfo, PropertyKind, ReaderPolicy, Value,
};

use crate::canvas::{Canvas, ConnectionRef};
use crate::commands::Command;
use crate::session::{NodeState, ReaderSettings, Session};

/// What the policy menu says for a connection that uses its input's default.
const INPUTS_DEFAULT: &str = "input's default";

/// The inspector of whatever the canvas has selected.
pub fn inspector_ui(ui: &mut egui::Ui, session: &Session, canvas: &Canvas, commands: &mut Vec<Command>) {
    ui.heading("Inspector");
    if let Some(selected) = &canvas.selected_connection {
        ui.label(format!("{} → {}", selected.from, selected.to));
        if let Some(connection) = session
            .document
            .diagram()
            .connections
            .iter()
            .find(|c| selected.is(c))
        {
            connection_ui(ui, selected, connection, commands);
        }
        return;
    }
    let selected: Vec<&String> = canvas.selected.iter().collect();
    let [id] = selected.as_slice() else {
        ui.label("Select a component or a connection.");
        return;
    };
    let Some(instance) = session.document.diagram().component(id) else {
        return;
    };
    component_ui(ui, session, instance, commands);
}

/// A connection's reader policy (every [`ReaderPolicy`], or the input's default), buffer share and
/// subsampling.
fn connection_ui(
    ui: &mut egui::Ui,
    selected: &ConnectionRef,
    connection: &Connection,
    commands: &mut Vec<Command>,
) {
    let mut policy = connection.policy;
    egui::ComboBox::from_label("reader policy")
        .selected_text(policy.map_or(INPUTS_DEFAULT, ReaderPolicy::name))
        .show_ui(ui, |ui| {
            ui.selectable_value(&mut policy, None, INPUTS_DEFAULT);
            for choice in ReaderPolicy::ALL {
                ui.selectable_value(&mut policy, Some(choice), choice.name());
            }
        });
    let mut buffer = connection.buffer_size.unwrap_or(0);
    ui.horizontal(|ui| {
        ui.label("buffer size (0: the output's)");
        ui.add(egui::DragValue::new(&mut buffer).range(0..=kairos_diagram::MAX_BUFFER_SIZE));
    });
    let mut subsampling = connection.subsampling.unwrap_or(1);
    ui.horizontal(|ui| {
        ui.label("keep one sample in");
        ui.add(egui::DragValue::new(&mut subsampling).range(1..=1_000_000));
    });
    let settings = ReaderSettings {
        policy,
        buffer_size: (buffer > 0).then_some(buffer),
        subsampling: (subsampling > 1).then_some(subsampling),
    };
    let before = ReaderSettings {
        policy: connection.policy,
        buffer_size: connection.buffer_size.filter(|b| *b > 0),
        subsampling: connection.subsampling.filter(|s| *s > 1),
    };
    if settings != before {
        commands.push(Command::SetReader {
            from: selected.from.clone(),
            to: selected.to.clone(),
            settings,
        });
    }
}

/// A component's description, properties, actions and failure.
fn component_ui(
    ui: &mut egui::Ui,
    session: &Session,
    instance: &ComponentInstance,
    commands: &mut Vec<Command>,
) {
    ui.label(RichText::new(&instance.id).strong());
    let Some(info) = session.library.component_of(instance) else {
        ui.colored_label(Color32::LIGHT_RED, format!("unknown type {}", instance.type_name));
        return;
    };
    ui.label(RichText::new(&info.type_name).weak());
    ui.label(&info.doc);
    ui.separator();
    for property in &info.properties {
        property_ui(ui, instance, property, commands);
    }
    actions_ui(ui, &instance.id, info, commands);
    if let Some(NodeState::Failed(error)) = session.node_state(&instance.id) {
        ui.separator();
        ui.colored_label(Color32::LIGHT_RED, format!("failed: {error}"));
    }
}

/// One property: its name (hover: its description), a widget for its kind, `live` when it changes in a
/// running diagram, and what is wrong with its value.
fn property_ui(
    ui: &mut egui::Ui,
    instance: &ComponentInstance,
    property: &PropertyInfo,
    commands: &mut Vec<Command>,
) {
    let current = instance
        .properties
        .get(&property.name)
        .cloned()
        .unwrap_or_else(|| property.default.clone());
    let mut edited = current.clone();
    ui.horizontal(|ui| {
        let name_label = ui.label(&property.name).on_hover_text(&property.doc).id;
        if let Some(current) = value_ui(ui, property, name_label, &mut edited) {
            commands.push(Command::ChoosePath {
                component: instance.id.clone(),
                property: property.name.clone(),
                current,
            });
        }
        if property.live {
            ui.label(RichText::new("live").small().weak())
                .on_hover_text("changes apply at once while the diagram runs");
        }
    });
    if let Err(error) = property.kind.check(&edited) {
        ui.colored_label(Color32::LIGHT_RED, error.to_string());
    }
    if edited != current {
        commands.push(Command::SetProperty {
            component: instance.id.clone(),
            property: property.name.clone(),
            value: edited,
        });
    }
}

/// The widget editing `value` for the property's kind, labelled by `name_label`; returns the path typed
/// so far when the file chooser was asked for (a path property's "…").
fn value_ui(
    ui: &mut egui::Ui,
    property: &PropertyInfo,
    name_label: egui::Id,
    value: &mut Value,
) -> Option<String> {
    match &property.kind {
        PropertyKind::F64 { min, max } => {
            let mut number = value.as_f64().unwrap_or(0.0);
            let mut drag = egui::DragValue::new(&mut number).speed(0.1);
            if let (Some(min), Some(max)) = (min, max) {
                drag = drag.range(*min..=*max);
            }
            if ui.add(drag).labelled_by(name_label).changed() {
                *value = Value::F64(number);
            }
        }
        PropertyKind::I64 { min, max } => {
            let mut number = value.as_i64().unwrap_or(0);
            let mut drag = egui::DragValue::new(&mut number);
            if let (Some(min), Some(max)) = (min, max) {
                drag = drag.range(*min..=*max);
            }
            if ui.add(drag).labelled_by(name_label).changed() {
                *value = Value::I64(number);
            }
        }
        PropertyKind::Bool => {
            let mut flag = value.as_bool().unwrap_or(false);
            if ui.checkbox(&mut flag, "").labelled_by(name_label).changed() {
                *value = Value::Bool(flag);
            }
        }
        PropertyKind::Choice(choices) => {
            let mut chosen = value.as_text().unwrap_or("").to_owned();
            egui::ComboBox::from_id_salt(("choice", &property.name))
                .selected_text(&chosen)
                .show_ui(ui, |ui| {
                    for choice in choices {
                        ui.selectable_value(&mut chosen, choice.clone(), choice);
                    }
                });
            if Some(chosen.as_str()) != value.as_text() {
                *value = Value::Text(chosen);
            }
        }
        kind @ (PropertyKind::Text | PropertyKind::Path) => {
            let mut text = value.as_text().unwrap_or("").to_owned();
            let edit = egui::TextEdit::singleline(&mut text).desired_width(160.0);
            if ui.add(edit).labelled_by(name_label).changed() {
                *value = Value::Text(text.clone());
            }
            if *kind == PropertyKind::Path && ui.button("…").on_hover_text("Choose a file").clicked() {
                return Some(text);
            }
        }
    }
    None
}

/// A button per action.
fn actions_ui(ui: &mut egui::Ui, component: &str, info: &ComponentInfo, commands: &mut Vec<Command>) {
    if info.actions.is_empty() {
        return;
    }
    ui.separator();
    for action in &info.actions {
        if ui.button(&action.name).on_hover_text(&action.doc).clicked() {
            commands.push(Command::TriggerAction {
                component: component.to_owned(),
                action: action.name.clone(),
            });
        }
    }
}

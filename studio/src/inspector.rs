//! The inspector: the selected connection's reader settings, or the selected component's description,
//! properties (one widget per kind, each labelled by the property's name), actions, status while it runs
//! and failure. Edits are pushed as [`Command`]s.

use egui::{Color32, RichText};
use kairos_diagram::{
    ComponentInfo, ComponentInstance, Connection, ExposedKind, Exposes, PortRef, PropertyInfo, PropertyKind,
    ReaderPolicy, Value,
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
        ui.label(format!("{} -> {}", selected.from, selected.to));
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
        if selected.is_empty() {
            ui.label("Select a component or a connection.");
            if let Some(exposes) = &session.document.diagram().exposes {
                exposes_overview_ui(ui, exposes, commands);
            }
        } else {
            ui.label(format!(
                "{} components selected: select one alone to see its properties.",
                selected.len()
            ));
            ui.separator();
            let ids: Vec<String> = selected.iter().map(|id| (*id).clone()).collect();
            execution_ui(ui, session, &ids, None, commands);
        }
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
            ui.selectable_value(&mut policy, None, INPUTS_DEFAULT)
                .on_hover_text("The policy the input's component asks for");
            for choice in ReaderPolicy::ALL {
                ui.selectable_value(&mut policy, Some(choice), choice.name())
                    .on_hover_text(choice.explanation());
            }
        });
    // What the chosen policy does, in words, where it is chosen.
    ui.label(
        RichText::new(policy.map_or(
            "The policy the input's component asks for",
            ReaderPolicy::explanation,
        ))
        .weak(),
    );
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
    name_ui(ui, session, &instance.id, commands);
    let Some(info) = session.library.component_of(instance) else {
        ui.colored_label(Color32::LIGHT_RED, format!("unknown type {}", instance.type_name));
        return;
    };
    ui.horizontal_wrapped(|ui| {
        ui.label(RichText::new(info.display_name()).strong());
        ui.label(RichText::new(&info.type_name).weak());
    });
    ui.label(&info.doc);
    if info.time_source {
        let follows = session.document.diagram().clock_source.as_deref() == Some(instance.id.as_str());
        let mut checked = follows;
        if info.simulated_time {
            ui.checkbox(&mut checked, "The runtime clock is its simulated time")
                .on_hover_text(
                    "The diagram's clock source: every component runs on the simulation's time, from its \
                     start_time, at its time_scale (1: real time; 0: as fast as the diagram computes, with \
                     the diagram sequential)",
                );
        } else {
            ui.checkbox(&mut checked, "The runtime clock follows its time")
                .on_hover_text(
                    "The diagram's clock source: the runtime clock is set to this component's time when the \
                     diagram starts (a GNSS receiver's UTC), then slewed to follow it, never going backwards",
                );
        }
        if checked != follows {
            commands.push(Command::SetClockSource(checked.then(|| instance.id.clone())));
        }
    }
    execution_ui(
        ui,
        session,
        std::slice::from_ref(&instance.id),
        info.blocking_reason(),
        commands,
    );
    ui.separator();
    for property in &info.properties {
        property_ui(ui, session, instance, &info.properties, property, commands);
    }
    actions_ui(ui, &instance.id, info, commands);
    inside_ui(ui, session, &instance.id, commands);
    exposed_ui(ui, session, &instance.id, info, commands);
    status_ui(ui, session, &instance.id);
    if let Some(NodeState::Failed(error)) = session.node_state(&instance.id) {
        ui.separator();
        ui.colored_label(Color32::LIGHT_RED, format!("failed: {error}"));
    }
}

/// What an execution group is, for whoever hovers over the choice.
const GROUP_EXPLANATION: &str = "An execution group runs its members in one thread, one after the other in \
     the order of their links: many light components use far less CPU. A slow member delays its whole group, \
     and a group uses one core at most.";

/// The diagram-wide switch, shown with any component's execution: every component in one thread.
fn sequential_ui(ui: &mut egui::Ui, session: &Session, commands: &mut Vec<Command>) {
    let mut sequential = session.document.diagram().sequential;
    ui.checkbox(&mut sequential, "Sequential (the whole diagram)")
        .on_hover_text(
            "Every component in one thread, RTMaps' sequential behaviour: components run one after the \
             other in the order of their \
             links, so replaying the same data gives the same outputs every run. A slow component delays \
             all the others.",
        );
    if sequential != session.document.diagram().sequential {
        commands.push(Command::SetSequential(sequential));
    }
}

/// The execution settings, folded by default: most diagrams never need them, and open they would widen
/// the inspector over the canvas.
fn execution_ui(
    ui: &mut egui::Ui,
    session: &Session,
    ids: &[String],
    waits: Option<String>,
    commands: &mut Vec<Command>,
) {
    egui::CollapsingHeader::new("Execution")
        .id_salt("execution")
        .show(ui, |ui| {
            group_ui(ui, session, ids, waits, commands);
            sequential_ui(ui, session, commands);
        })
        .header_response
        .on_hover_text(GROUP_EXPLANATION);
}

/// Where the components `ids` run: each in a thread of its own, or an execution group (one the diagram
/// has, or a new one named here). `waits` says why a single component would drive its group.
fn group_ui(
    ui: &mut egui::Ui,
    session: &Session,
    ids: &[String],
    waits: Option<String>,
    commands: &mut Vec<Command>,
) {
    let diagram = session.document.diagram();
    if diagram.sequential {
        ui.label(RichText::new("The diagram is sequential: every component runs in one thread.").weak());
        return;
    }
    let current: std::collections::BTreeSet<Option<&str>> = ids
        .iter()
        .filter_map(|id| diagram.component(id))
        .map(|c| c.group.as_deref())
        .collect();
    let known: std::collections::BTreeSet<&str> = diagram
        .components
        .iter()
        .filter_map(|c| c.group.as_deref())
        .collect();
    let shown = match current.iter().collect::<Vec<_>>().as_slice() {
        [None] => "a thread of its own".to_owned(),
        [Some(group)] => format!("group {group}"),
        _ => "(several)".to_owned(),
    };
    let mut chosen: Option<Option<String>> = None;
    ui.horizontal(|ui| {
        ui.label("runs in").on_hover_text(GROUP_EXPLANATION);
        egui::ComboBox::from_id_salt(("group", ids.first()))
            .selected_text(shown)
            .show_ui(ui, |ui| {
                if ui
                    .selectable_label(
                        current.len() == 1 && current.contains(&None),
                        "a thread of its own",
                    )
                    .clicked()
                {
                    chosen = Some(None);
                }
                for group in &known {
                    let on = current.len() == 1 && current.contains(&Some(*group));
                    if ui.selectable_label(on, format!("group {group}")).clicked() {
                        chosen = Some(Some((*group).to_owned()));
                    }
                }
            });
    });
    let edit_id = egui::Id::unique(("new group", ids.first()));
    let mut name = ui.data(|d| d.get_temp::<String>(edit_id)).unwrap_or_default();
    ui.horizontal(|ui| {
        let label = ui.label("new group").id;
        let response = ui
            .add(egui::TextEdit::singleline(&mut name).desired_width(110.0))
            .labelled_by(label)
            .on_hover_text(GROUP_EXPLANATION);
        if response.changed() {
            ui.data_mut(|d| d.insert_temp(edit_id, name.clone()));
        }
        let valid = kairos_diagram::is_valid_id(name.trim());
        let enter = response.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
        if ui
            .add_enabled(valid, egui::Button::new("Put in it"))
            .on_disabled_hover_text("a group's name: letters, digits, _ and -")
            .clicked()
            || (enter && valid)
        {
            chosen = Some(Some(name.trim().to_owned()));
            ui.data_mut(|d| d.remove_temp::<String>(edit_id));
        }
    });
    if let Some(reason) = waits {
        ui.label(
            RichText::new(format!(
                "It waits ({reason}): in a group it is the group's driver, one per group, run first."
            ))
            .weak(),
        );
    }
    if let Some(group) = chosen
        && !(current.len() == 1 && current.contains(&group.as_deref()))
    {
        commands.push(Command::SetGroup {
            components: ids.to_vec(),
            group,
        });
    }
}

/// What the running component says about itself (its counters, its file, a reload that failed), one
/// line per value, nested names joined by dots as `kairos run --stats` prints them.
fn status_ui(ui: &mut egui::Ui, session: &Session, id: &str) {
    let Some(status) = session
        .monitor
        .components
        .get(id)
        .and_then(|component| component.latest.status.as_ref())
        .filter(|status| !status.is_null())
    else {
        return;
    };
    ui.separator();
    ui.label(RichText::new("Status").strong());
    let mut lines = Vec::new();
    crate::viewers::flatten_fields("", status, &mut lines);
    egui::Grid::new(("status", id)).num_columns(2).show(ui, |ui| {
        for (name, value) in lines {
            ui.label(RichText::new(name).weak());
            ui.monospace(value);
            ui.end_row();
        }
    });
}

/// The component's name, edited in place: a rename is asked for when editing ends.
fn name_ui(ui: &mut egui::Ui, session: &Session, id: &str, commands: &mut Vec<Command>) {
    let edit_id = egui::Id::unique(("rename", id));
    let mut text = ui
        .data(|d| d.get_temp::<String>(edit_id))
        .unwrap_or_else(|| id.to_owned());
    ui.horizontal(|ui| {
        let label = ui.label("name").id;
        let response = ui
            .add(egui::TextEdit::singleline(&mut text).desired_width(160.0))
            .labelled_by(label)
            .on_hover_text("Rename the component; its connections follow");
        if response.changed() {
            ui.data_mut(|d| d.insert_temp(edit_id, text.clone()));
        }
        if response.lost_focus() {
            ui.data_mut(|d| d.remove_temp::<String>(edit_id));
            if text.trim() != id && !ui.input(|i| i.key_pressed(egui::Key::Escape)) {
                commands.push(Command::Rename {
                    from: id.to_owned(),
                    to: text.trim().to_owned(),
                });
            }
        }
    });
    if let Some(note) = session.field_note(id, "name") {
        ui.colored_label(crate::log_panel::WARN_COLOR, note);
    }
}

/// One property: its name (hover: its description), a widget for its kind with its unit and range,
/// `live` when it changes in a running diagram, and what is wrong with its value or was refused lately.
fn property_ui(
    ui: &mut egui::Ui,
    session: &Session,
    instance: &ComponentInstance,
    siblings: &[PropertyInfo],
    property: &PropertyInfo,
    commands: &mut Vec<Command>,
) {
    let current = instance
        .properties
        .get(&property.name)
        .cloned()
        .unwrap_or_else(|| property.default.clone());
    let mut edited = current.clone();
    let mut refused = None;
    ui.horizontal(|ui| {
        let name_label = ui.label(&property.name).on_hover_text(&property.doc).id;
        match value_ui(ui, property, name_label, &mut edited) {
            FieldEvent::None => {}
            FieldEvent::ChooseFile(current) => commands.push(Command::ChoosePath {
                component: instance.id.clone(),
                property: property.name.clone(),
                current,
            }),
            FieldEvent::Refused(why) => refused = Some(why),
        }
        if let Some(bounds) = bounds_in_words(property) {
            ui.label(RichText::new(bounds).small().weak());
        }
        if property.live {
            ui.label(RichText::new("live").small().weak())
                .on_hover_text("changes apply at once while the diagram runs");
        }
        match property.device {
            // On a line of its own: a topic's name and type are long.
            Some(kairos_diagram::DeviceKind::Ros2Topic | kairos_diagram::DeviceKind::Ros2Service) | None => {}
            Some(kind) => device_picker(ui, session, kind, &mut edited, commands),
        }
    });
    if let Some(kind @ (kairos_diagram::DeviceKind::Ros2Topic | kairos_diagram::DeviceKind::Ros2Service)) =
        property.device
    {
        let services = kind == kairos_diagram::DeviceKind::Ros2Service;
        ui.horizontal(|ui| {
            ros2_graph_picker(ui, session, instance, siblings, services, &mut edited, commands);
        });
    }
    if let Err(error) = property.kind.check(&edited) {
        ui.colored_label(Color32::LIGHT_RED, error.to_string());
    } else if let Some(note) = session.field_note(&instance.id, &property.name) {
        ui.colored_label(crate::log_panel::WARN_COLOR, note);
    }
    if edited != current {
        commands.push(Command::SetProperty {
            component: instance.id.clone(),
            property: property.name.clone(),
            value: edited,
        });
    }
    if let Some(why) = refused {
        commands.push(Command::FieldRefused {
            component: instance.id.clone(),
            property: property.name.clone(),
            why,
        });
    }
}

/// The devices of `kind` on the runtime's machine, to pick one for a property naming such a device; asked
/// of the runtime the first time one is shown, and again with the refresh button.
fn device_picker(
    ui: &mut egui::Ui,
    session: &Session,
    kind: kairos_diagram::DeviceKind,
    edited: &mut Value,
    commands: &mut Vec<Command>,
) {
    let Some(devices) = session.devices() else {
        if session.runtime().is_some_and(|r| r.connected) {
            commands.push(Command::RefreshDevices);
        }
        return;
    };
    let present: Vec<_> = devices.iter().filter(|d| d.kind == kind).collect();
    let label = if present.is_empty() {
        format!("no {kind} here")
    } else {
        format!("{} present", present.len())
    };
    egui::ComboBox::from_id_salt(("devices", kind))
        .selected_text(label)
        .show_ui(ui, |ui| {
            for device in &present {
                let chosen = matches!(edited, Value::Text(text) if *text == device.path);
                let text = if device.description.is_empty() {
                    device.path.clone()
                } else {
                    format!("{} — {}", device.path, device.description)
                };
                if ui.selectable_label(chosen, text).clicked() {
                    *edited = Value::Text(device.path.clone());
                }
            }
        })
        .response
        .on_hover_text(format!("The {kind} devices of the runtime's machine"));
    if ui
        .small_button("refresh")
        .on_hover_text("Look for devices again")
        .clicked()
    {
        commands.push(Command::RefreshDevices);
    }
}

/// The value of `instance`'s property `name`: as set, or its type's default.
fn value_of(instance: &ComponentInstance, siblings: &[PropertyInfo], name: &str) -> Option<Value> {
    instance.properties.get(name).cloned().or_else(|| {
        siblings
            .iter()
            .find(|property| property.name == name)
            .map(|property| property.default.clone())
    })
}

/// One thing the picker offers: a topic's or a service's name, type, and what it has, in words.
struct GraphEntry<'a> {
    name: &'a str,
    type_name: &'a str,
    counts: String,
}

/// The topics (or, with `services`, the services) of the live ROS 2 graph the component reaches through
/// its `router` in its `domain_id`, asked of the runtime (which reaches ROS 2 from the machine the
/// component runs on) when the button is pressed: picking one sets the name and, where the component has
/// a `type` that can carry it, the type.
fn ros2_graph_picker(
    ui: &mut egui::Ui,
    session: &Session,
    instance: &ComponentInstance,
    siblings: &[PropertyInfo],
    services: bool,
    edited: &mut Value,
    commands: &mut Vec<Command>,
) {
    let what = if services { "services" } else { "topics" };
    let router = match value_of(instance, siblings, "router") {
        Some(Value::Text(router)) => router,
        _ => String::new(),
    };
    let domain = match value_of(instance, siblings, "domain_id") {
        Some(Value::I64(domain)) => domain,
        _ => 0,
    };
    let refresh = |commands: &mut Vec<Command>| {
        commands.push(Command::RefreshRos2Topics {
            router: router.clone(),
            domain,
        });
    };
    let connected = session.runtime().is_some_and(|r| r.connected);
    match session.ros2_topics(&router, domain) {
        None => {
            let asked = ui
                .add_enabled(connected, egui::Button::new(format!("{what}…")).small())
                .on_hover_text(format!(
                    "List the {what} of the ROS 2 graph at {router}, domain {domain}"
                ))
                .on_disabled_hover_text("Connect to a runtime: it reaches the ROS 2 graph");
            if asked.clicked() {
                refresh(commands);
            }
        }
        Some(crate::session::Ros2Listing::Refused(why)) => {
            ui.colored_label(crate::log_panel::WARN_COLOR, "graph out of reach")
                .on_hover_text(why);
            if ui.small_button("retry").clicked() {
                refresh(commands);
            }
        }
        Some(crate::session::Ros2Listing::Graph(graph)) => {
            let entries: Vec<GraphEntry<'_>> = if services {
                graph
                    .services
                    .iter()
                    .map(|service| GraphEntry {
                        name: &service.name,
                        type_name: &service.type_name,
                        counts: format!("{} server, {} client", service.servers, service.clients),
                    })
                    .collect()
            } else {
                graph
                    .topics
                    .iter()
                    .map(|topic| GraphEntry {
                        name: &topic.name,
                        type_name: &topic.type_name,
                        counts: format!("{} pub, {} sub", topic.publishers, topic.subscriptions),
                    })
                    .collect()
            };
            let carried: Vec<String> = siblings
                .iter()
                .find(|property| property.name == "type")
                .and_then(|property| match &property.kind {
                    PropertyKind::Choice(options) => Some(options.clone()),
                    _ => None,
                })
                .unwrap_or_default();
            let has_type = siblings.iter().any(|property| property.name == "type");
            let label = if entries.is_empty() {
                format!("no {} on the graph", if services { "service" } else { "topic" })
            } else {
                format!("{} on the graph", entries.len())
            };
            egui::ComboBox::from_id_salt(("ros2 graph", &instance.id, services))
                .selected_text(label)
                .show_ui(ui, |ui| {
                    for entry in &entries {
                        let chosen = matches!(edited, Value::Text(text) if text == entry.name);
                        let text = format!("{} — {} ({})", entry.name, entry.type_name, entry.counts);
                        let readable = !has_type || carried.iter().any(|t| t == entry.type_name);
                        let item = ui.add_enabled(readable, egui::Button::selectable(chosen, text));
                        let item = item.on_disabled_hover_text(format!(
                            "Kairos does not carry {} (docs/ros2.md lists the types it does)",
                            entry.type_name
                        ));
                        if item.clicked() {
                            *edited = Value::Text(entry.name.to_owned());
                            if has_type {
                                commands.push(Command::SetProperty {
                                    component: instance.id.clone(),
                                    property: "type".to_owned(),
                                    value: Value::Text(entry.type_name.to_owned()),
                                });
                            }
                        }
                    }
                })
                .response
                .on_hover_text(format!(
                    "The {what} of the ROS 2 graph at {router}, domain {domain}"
                ));
            if ui
                .small_button("refresh")
                .on_hover_text(format!("List the {what} again"))
                .clicked()
            {
                refresh(commands);
            }
        }
    }
}

/// A number's unit and range, in words ("Hz, 0.001 to 100000"); none when it has neither.
fn bounds_in_words(property: &PropertyInfo) -> Option<String> {
    let range = match &property.kind {
        PropertyKind::F64 { min, max } => range_in_words(*min, *max),
        PropertyKind::I64 { min, max } => range_in_words(min.map(|v| v as f64), max.map(|v| v as f64)),
        _ => None,
    };
    match (property.unit.is_empty(), range) {
        (true, None) => None,
        (false, None) => Some(property.unit.clone()),
        (true, Some(range)) => Some(range),
        (false, Some(range)) => Some(format!("{}, {range}", property.unit)),
    }
}

fn range_in_words(min: Option<f64>, max: Option<f64>) -> Option<String> {
    match (min, max) {
        (Some(min), Some(max)) => Some(format!("{min} to {max}")),
        (Some(min), None) => Some(format!("at least {min}")),
        (None, Some(max)) => Some(format!("at most {max}")),
        (None, None) => None,
    }
}

/// What a property's widget asks for besides a new value.
enum FieldEvent {
    None,
    /// The file chooser, on the path typed so far (a path property's "…").
    ChooseFile(String),
    /// What was typed was refused or clamped: why, to say at the field and in the log.
    Refused(String),
}

/// The widget editing `value` for the property's kind, labelled by `name_label`.
fn value_ui(
    ui: &mut egui::Ui,
    property: &PropertyInfo,
    name_label: egui::Id,
    value: &mut Value,
) -> FieldEvent {
    match &property.kind {
        PropertyKind::F64 { min, max } => {
            let mut number = value.as_f64().unwrap_or(0.0);
            let bounds = NumberBounds {
                min: *min,
                max: *max,
                whole: false,
                unit: &property.unit,
            };
            let (changed, event) = number_ui(ui, name_label, &mut number, &bounds);
            if changed {
                *value = Value::F64(number);
            }
            return event;
        }
        PropertyKind::I64 { min, max } => {
            let mut number = value.as_i64().unwrap_or(0) as f64;
            let bounds = NumberBounds {
                min: min.map(|v| v as f64),
                max: max.map(|v| v as f64),
                whole: true,
                unit: &property.unit,
            };
            let (changed, event) = number_ui(ui, name_label, &mut number, &bounds);
            if changed {
                *value = Value::I64(number as i64);
            }
            return event;
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
                return FieldEvent::ChooseFile(text);
            }
        }
    }
    FieldEvent::None
}

/// What a number may be.
struct NumberBounds<'a> {
    min: Option<f64>,
    max: Option<f64>,
    /// Whole numbers only.
    whole: bool,
    unit: &'a str,
}

impl NumberBounds<'_> {
    /// `value` with its unit (`0.001 Hz`).
    fn with_unit(&self, value: f64) -> String {
        if self.unit.is_empty() {
            value.to_string()
        } else {
            format!("{value} {}", self.unit)
        }
    }

    /// Why a typed text is refused or changed once editing ends, if it is.
    fn judge(&self, text: &str, parsed: Option<f64>, kept: f64) -> Option<String> {
        let text = text.trim();
        let Some(typed) = parsed else {
            let what = if self.whole { "a whole number" } else { "a number" };
            return Some(format!("\"{text}\" is not {what}: kept {}", self.with_unit(kept)));
        };
        if let Some(min) = self.min.filter(|min| typed < *min) {
            return Some(format!(
                "{typed} is below the least value, {}: set to {min}",
                self.with_unit(min)
            ));
        }
        if let Some(max) = self.max.filter(|max| typed > *max) {
            return Some(format!(
                "{typed} is above the largest value, {}: set to {max}",
                self.with_unit(max)
            ));
        }
        None
    }
}

/// A number field that clamps to the bounds as the user types, and says so (or that the text is no
/// number) when editing ends, instead of changing or reverting the value silently. Returns whether the
/// value changed and what to say.
fn number_ui(
    ui: &mut egui::Ui,
    name_label: egui::Id,
    number: &mut f64,
    bounds: &NumberBounds<'_>,
) -> (bool, FieldEvent) {
    // The text typed last, and what it parsed to, kept across frames until editing ends.
    let typed_id = name_label.with("typed");
    let whole = bounds.whole;
    let ctx = ui.ctx().clone();
    let parse = move |text: &str| {
        let parsed = text
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && (!whole || v.fract() == 0.0));
        ctx.data_mut(|d| d.insert_temp(typed_id, (text.to_owned(), parsed)));
        parsed
    };
    let mut drag = egui::DragValue::new(number)
        .range(bounds.min.unwrap_or(f64::MIN)..=bounds.max.unwrap_or(f64::MAX))
        .custom_parser(parse);
    drag = if whole {
        drag.speed(1.0).max_decimals(0)
    } else {
        drag.speed(0.1)
    };
    let response = ui.add(drag).labelled_by(name_label);
    let mut event = FieldEvent::None;
    let escaped = ui.input(|i| i.key_pressed(egui::Key::Escape));
    if response.gained_focus() || (response.lost_focus() && escaped) {
        // A new edit, or one given up: nothing typed before counts.
        ui.data_mut(|d| d.remove_temp::<(String, Option<f64>)>(typed_id));
    } else if response.lost_focus()
        && let Some((text, parsed)) = ui.data_mut(|d| d.remove_temp::<(String, Option<f64>)>(typed_id))
        && let Some(why) = bounds.judge(&text, parsed, *number)
    {
        event = FieldEvent::Refused(why);
    }
    (response.changed(), event)
}

/// Inside a subgraph instance: each inner component with a button per output to view it and per action
/// to trigger it (ids under the instance's, as the runtime runs them).
fn inside_ui(ui: &mut egui::Ui, session: &Session, instance: &str, commands: &mut Vec<Command>) {
    let parts = session.inside_subgraph(instance);
    if parts.is_empty() {
        return;
    }
    ui.separator();
    egui::CollapsingHeader::new("Inside")
        .id_salt(("inside", instance))
        .show(ui, |ui| {
            ui.weak("its outputs, to view; its actions; double-click the node to edit it");
            for part in parts {
                let flat = format!("{instance}/{}", part.id);
                ui.horizontal_wrapped(|ui| {
                    for (output, data_type) in &part.outputs {
                        if ui
                            .small_button(format!("{}.{output}", part.id))
                            .on_hover_text(format!("open a viewer on {flat}.{output}"))
                            .clicked()
                        {
                            commands.push(Command::OpenViewer {
                                output: format!("{flat}.{output}"),
                                data_type: data_type.name().to_string(),
                            });
                        }
                    }
                    for action in &part.actions {
                        if ui.small_button(action).clicked() {
                            commands.push(Command::TriggerAction {
                                component: flat.clone(),
                                action: action.clone(),
                            });
                        }
                    }
                });
            }
        });
}

/// What diagrams using this one as a subgraph see of the component: each input, output and property
/// ticked to expose it, with the name it has outside. Open when something of it is exposed.
fn exposed_ui(
    ui: &mut egui::Ui,
    session: &Session,
    component: &str,
    info: &ComponentInfo,
    commands: &mut Vec<Command>,
) {
    let exposes = session.document.diagram().exposes.as_ref();
    let items: Vec<(ExposedKind, &str)> = info
        .inputs
        .iter()
        .map(|i| (ExposedKind::Input, i.name.as_str()))
        .chain(
            info.outputs
                .iter()
                .map(|o| (ExposedKind::Output, o.name.as_str())),
        )
        .chain(
            info.properties
                .iter()
                .map(|p| (ExposedKind::Property, p.name.as_str())),
        )
        .collect();
    if items.is_empty() {
        return;
    }
    let any_exposed = items.iter().any(|(kind, name)| {
        exposes.is_some_and(|e| e.name_of(*kind, &PortRef::new(component, *name)).is_some())
    });
    ui.separator();
    egui::CollapsingHeader::new("Exposed as a subgraph")
        .id_salt(("exposed", component))
        .default_open(any_exposed)
        .show(ui, |ui| {
            ui.weak(
                "What a diagram using this one as a component sees of it. Inputs or properties given one \
                 name are set together.",
            );
            egui::Grid::new(("exposed grid", component))
                .num_columns(2)
                .show(ui, |ui| {
                    for (kind, name) in items {
                        exposed_row(
                            ui,
                            session,
                            exposes,
                            kind,
                            &PortRef::new(component, name),
                            commands,
                        );
                        ui.end_row();
                    }
                });
        });
}

/// The whole diagram as a subgraph: every exposed name with what it stands for inside, each removable.
fn exposes_overview_ui(ui: &mut egui::Ui, exposes: &Exposes, commands: &mut Vec<Command>) {
    ui.separator();
    ui.label(RichText::new("Exposed as a subgraph").strong());
    ui.weak("Select a component to expose more of it or rename what it exposes.");
    let outputs = exposes
        .outputs
        .iter()
        .map(|(name, port)| (ExposedKind::Output, name, port));
    let rows = each_target(ExposedKind::Input, &exposes.inputs)
        .chain(outputs)
        .chain(each_target(ExposedKind::Property, &exposes.properties));
    egui::Grid::new("exposes overview").num_columns(3).show(ui, |ui| {
        for (kind, name, port) in rows {
            ui.label(format!("{} {name}", kind.name()));
            ui.monospace(port.to_string());
            if ui
                .small_button("remove")
                .on_hover_text(format!("Stop exposing {port}"))
                .clicked()
            {
                commands.push(Command::SetExposed {
                    kind,
                    inner: port.clone(),
                    name: None,
                });
            }
            ui.end_row();
        }
    });
}

/// Each name with each inner port or property it stands for.
fn each_target(
    kind: ExposedKind,
    map: &std::collections::BTreeMap<String, Vec<PortRef>>,
) -> impl Iterator<Item = (ExposedKind, &String, &PortRef)> {
    map.iter()
        .flat_map(move |(name, ports)| ports.iter().map(move |port| (kind, name, port)))
}

/// One input, output or property: a tick to expose it and, exposed, its outer name, edited in place.
fn exposed_row(
    ui: &mut egui::Ui,
    session: &Session,
    exposes: Option<&Exposes>,
    kind: ExposedKind,
    inner: &PortRef,
    commands: &mut Vec<Command>,
) {
    let current = exposes.and_then(|e| e.name_of(kind, inner));
    let mut ticked = current.is_some();
    let tick = ui
        .checkbox(&mut ticked, format!("{} {}", kind.name(), inner.port))
        .on_hover_text(format!(
            "Expose this {} to the diagrams that use this one as a subgraph",
            kind.name()
        ));
    if tick.changed() {
        let name = ticked.then(|| exposes.map_or_else(|| inner.port.clone(), |e| e.free_name(inner)));
        commands.push(Command::SetExposed {
            kind,
            inner: inner.clone(),
            name,
        });
    }
    ui.vertical(|ui| {
        if let Some(current) = current {
            let edit_id = egui::Id::unique(("exposed name", kind.name(), inner));
            let mut text = ui
                .data(|d| d.get_temp::<String>(edit_id))
                .unwrap_or_else(|| current.to_owned());
            let response = ui
                .add(egui::TextEdit::singleline(&mut text).desired_width(120.0))
                .labelled_by(tick.id)
                .on_hover_text(
                    "Its name outside; one name given to several inputs or properties sets them together",
                );
            if response.changed() {
                ui.data_mut(|d| d.insert_temp(edit_id, text.clone()));
            }
            if response.lost_focus() {
                ui.data_mut(|d| d.remove_temp::<String>(edit_id));
                if text.trim() != current && !ui.input(|i| i.key_pressed(egui::Key::Escape)) {
                    commands.push(Command::SetExposed {
                        kind,
                        inner: inner.clone(),
                        name: Some(text.trim().to_owned()),
                    });
                }
            }
        }
        let field = crate::session::exposed_field(kind, &inner.port);
        if let Some(note) = session.field_note(&inner.component, &field) {
            ui.colored_label(crate::log_panel::WARN_COLOR, note);
        }
    });
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

#[cfg(test)]
mod tests {
    use crate::viewers::flatten_fields;

    #[test]
    fn a_status_is_shown_one_value_a_line_with_nested_names_joined() {
        let status = serde_json::json!({
            "decoded": 300,
            "python": {"pid": 42, "reload_error": null, "file": "a.py"},
        });
        let mut lines = Vec::new();
        flatten_fields("", &status, &mut lines);
        let lines: Vec<(&str, &str)> = lines.iter().map(|(n, v)| (n.as_str(), v.as_str())).collect();
        assert_eq!(
            lines,
            [
                ("decoded", "300"),
                ("python.file", "a.py"),
                ("python.pid", "42"),
                ("python.reload_error", "none"),
            ]
        );
    }
}

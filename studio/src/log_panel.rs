//! The bottom panel: the log, filtered by level and component, or the monitoring panel.

use egui::Color32;
use kairos_protocol::LogLevel;

use crate::log::{Log, LogFilter, LogLine, Tone};
use crate::monitor::Monitor;

/// The colour of warnings.
pub const WARN_COLOR: Color32 = Color32::from_rgb(240, 170, 60);

/// Which view the bottom panel shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BottomTab {
    /// The log.
    #[default]
    Log,
    /// The monitoring panel.
    Monitor,
    /// What console components print.
    Console,
}

/// The bottom panel's state between frames.
#[derive(Debug, Clone, Default)]
pub struct BottomPanel {
    /// The view shown.
    pub tab: BottomTab,
    /// The log's filter.
    pub filter: LogFilter,
}

/// The levels offered by the filter.
const LEVELS: [LogLevel; 4] = [LogLevel::Debug, LogLevel::Info, LogLevel::Warn, LogLevel::Error];

/// A line's colour: success green, errors red, warnings orange, the studio's other lines and the runtime's
/// grey.
fn color(line: &LogLine) -> Color32 {
    match (line.tone, line.level) {
        (Tone::Success, _) => Color32::LIGHT_GREEN,
        (Tone::Plain, LogLevel::Error) => Color32::LIGHT_RED,
        (Tone::Plain, LogLevel::Warn) => WARN_COLOR,
        (Tone::Plain, LogLevel::Trace | LogLevel::Debug | LogLevel::Info) => Color32::GRAY,
    }
}

/// The tabs, the log's filters, and the log or the monitoring panel.
pub fn bottom_panel_ui(
    ui: &mut egui::Ui,
    panel: &mut BottomPanel,
    log: &Log,
    monitor: &mut Monitor,
    console: &mut crate::console::Console,
) {
    ui.horizontal(|ui| {
        ui.selectable_value(&mut panel.tab, BottomTab::Log, "Log");
        ui.selectable_value(&mut panel.tab, BottomTab::Monitor, "Monitor");
        ui.selectable_value(&mut panel.tab, BottomTab::Console, "Console output");
        if panel.tab == BottomTab::Log {
            ui.separator();
            log_filter_ui(ui, &mut panel.filter, log);
        }
    });
    match panel.tab {
        BottomTab::Log => log_ui(ui, log, &panel.filter),
        BottomTab::Monitor => monitor.panel(ui),
        BottomTab::Console => console.ui(ui),
    }
}

/// The least level and the component shown.
fn log_filter_ui(ui: &mut egui::Ui, filter: &mut LogFilter, log: &Log) {
    let _ = egui::ComboBox::from_id_salt("log level")
        .selected_text(format!("{:?} and above", filter.least))
        .show_ui(ui, |ui| {
            for level in LEVELS {
                ui.selectable_value(&mut filter.least, level, format!("{level:?} and above"));
            }
        })
        .response
        .accessible_name("log level");
    let _ = egui::ComboBox::from_id_salt("log component")
        .selected_text(filter.component.as_deref().unwrap_or("all components"))
        .show_ui(ui, |ui| {
            ui.selectable_value(&mut filter.component, None, "all components");
            for component in log.components() {
                let label = component.clone();
                ui.selectable_value(&mut filter.component, Some(component), label);
            }
        })
        .response
        .accessible_name("log component");
}

/// The lines `filter` shows, following the newest until the user scrolls up (and again once scrolled back
/// to the bottom); long lines scroll sideways. Only the rows in view are laid out.
pub fn log_ui(ui: &mut egui::Ui, log: &Log, filter: &LogFilter) {
    let lines: Vec<&LogLine> = log.visible(filter).collect();
    let row_height = ui.text_style_height(&egui::TextStyle::Body);
    egui::ScrollArea::both()
        .auto_shrink([false, false])
        .stick_to_bottom(true)
        .show_rows(ui, row_height, lines.len(), |ui, rows| {
            for line in &lines[rows] {
                let text = if line.repeats > 1 {
                    format!("(×{}) {}", line.repeats, line.text)
                } else {
                    line.text.clone()
                };
                ui.add(egui::Label::new(egui::RichText::new(text).color(color(line))).extend());
            }
        });
}

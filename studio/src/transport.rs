//! Recording and replay controls: a strip under the canvas with one row per recorder (start, stop, split,
//! the file and its size) and one per player (play, pause, step, rewind, speed, loop, and a timeline to seek
//! by dragging, with the recording's time and its tracks). It reads what those components publish about
//! themselves in the telemetry (`status`) and drives them with protocol requests.

use std::collections::BTreeMap;

use egui::{Color32, Pos2, Rect, RichText, Sense, Stroke, Vec2};
use kairos_diagram::Value;
use kairos_protocol::RequestBody;

use crate::commands::Command;
use crate::monitor::Monitor;

/// Speeds offered for a replay.
const SPEEDS: [f64; 8] = [0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 10.0, 100.0];
/// The most track lanes drawn under a timeline.
const LANES: usize = 8;

/// The strip's state between frames: where each player's timeline is being dragged to.
#[derive(Debug, Default)]
pub struct Transport {
    scrubbing: BTreeMap<String, f64>,
}

fn number(status: &serde_json::Value, key: &str) -> f64 {
    status.get(key).and_then(serde_json::Value::as_f64).unwrap_or(0.0)
}

fn flag(status: &serde_json::Value, key: &str) -> bool {
    status
        .get(key)
        .and_then(serde_json::Value::as_bool)
        .unwrap_or(false)
}

/// Whether any deployed component has controls here.
pub fn has_controls(monitor: &Monitor) -> bool {
    monitor.components.values().any(|c| {
        c.latest
            .status
            .as_ref()
            .and_then(|s| s.get("kind"))
            .and_then(serde_json::Value::as_str)
            .is_some_and(|kind| kind == "player" || kind == "recorder")
    })
}

impl Transport {
    /// Shows a row per recorder and player; returns the requests the user made, and a replay asked for.
    pub fn show(&mut self, ui: &mut egui::Ui, monitor: &Monitor) -> (Vec<RequestBody>, Option<Command>) {
        let mut replay = None;
        let mut requests = Vec::new();
        for component in monitor.components.values() {
            let Some(status) = &component.latest.status else {
                continue;
            };
            let id = component.latest.id.clone();
            match status.get("kind").and_then(serde_json::Value::as_str) {
                Some("recorder") => recorder_row(ui, &id, status, &mut requests, &mut replay),
                Some("player") => self.player_row(ui, &id, status, &mut requests),
                _ => {}
            }
        }
        (requests, replay)
    }

    fn player_row(
        &mut self,
        ui: &mut egui::Ui,
        id: &str,
        status: &serde_json::Value,
        requests: &mut Vec<RequestBody>,
    ) {
        self.player_controls(ui, id, status, requests);
        self.timeline(ui, id, status, requests);
        ui.add_space(4.0);
    }

    /// Play or pause, step, rewind, speed, loop, and the time.
    fn player_controls(
        &self,
        ui: &mut egui::Ui,
        id: &str,
        status: &serde_json::Value,
        requests: &mut Vec<RequestBody>,
    ) {
        let component = id.to_owned();
        let duration = number(status, "duration_s").max(f64::EPSILON);
        let position = number(status, "position_s");
        let playing = flag(status, "playing");
        let ended = flag(status, "ended");
        ui.horizontal(|ui| {
            ui.strong(id).on_hover_text("a recording player");
            if ended {
                ui.weak(
                    "ended: Run replays it again; in its properties, 'at end: hold' keeps it at its end to seek \
                     back, 'loop' replays it without end",
                );
                return;
            }
            if playing {
                if ui.button("Pause").clicked() {
                    requests.push(RequestBody::PlayerPause {
                        component: component.clone(),
                    });
                }
            } else if ui.button("Play").clicked() {
                requests.push(RequestBody::PlayerPlay {
                    component: component.clone(),
                });
            }
            if ui
                .add_enabled(!playing, egui::Button::new("Step"))
                .on_hover_text("emit the next sample (while paused)")
                .clicked()
            {
                requests.push(RequestBody::PlayerStep {
                    component: component.clone(),
                });
            }
            if ui.button("Rewind").clicked() {
                requests.push(RequestBody::TriggerAction {
                    component: component.clone(),
                    action: "rewind".to_owned(),
                });
            }
            let has_markers = status
                .get("markers")
                .and_then(serde_json::Value::as_array)
                .is_some_and(|m| !m.is_empty());
            for (label, action, hint) in [
                (
                    "Previous mark",
                    "previous_marker",
                    "jump back to the marker before",
                ),
                ("Next mark", "next_marker", "jump to the next marker"),
            ] {
                if ui
                    .add_enabled(has_markers, egui::Button::new(label))
                    .on_hover_text(hint)
                    .clicked()
                {
                    requests.push(RequestBody::TriggerAction {
                        component: component.clone(),
                        action: action.to_owned(),
                    });
                }
            }
            let speed = number(status, "speed");
            egui::ComboBox::new(("speed", id), "speed")
                .width(70.0)
                .selected_text(format!("{speed}×"))
                .show_ui(ui, |ui| {
                    for choice in SPEEDS {
                        if ui
                            .selectable_label((choice - speed).abs() < 1e-9, format!("{choice}×"))
                            .clicked()
                        {
                            requests.push(RequestBody::PlayerSpeed {
                                component: component.clone(),
                                factor: choice,
                            });
                        }
                    }
                });
            let mut looping = flag(status, "loop");
            if ui.checkbox(&mut looping, "loop").changed() {
                requests.push(RequestBody::SetProperty {
                    component: component.clone(),
                    property: "loop".to_owned(),
                    value: Value::Bool(looping),
                });
            }
            let shown = self.scrubbing.get(id).copied().unwrap_or(position);
            ui.monospace(format!("{} / {}", clock(shown), clock(duration)));
        });
    }

    /// The whole recording as a bar (the replayed range shaded, the position marked, a lane per track);
    /// dragging or clicking seeks.
    fn timeline(
        &mut self,
        ui: &mut egui::Ui,
        id: &str,
        status: &serde_json::Value,
        requests: &mut Vec<RequestBody>,
    ) {
        let component = id.to_owned();
        let duration = number(status, "duration_s").max(f64::EPSILON);
        let position = number(status, "position_s");
        // The timeline: the whole recording, the replayed range, the position; drag or click to seek.
        let tracks = status
            .get("tracks")
            .and_then(serde_json::Value::as_array)
            .map_or(&[][..], Vec::as_slice);
        let files = status
            .get("files")
            .and_then(serde_json::Value::as_array)
            .map_or(&[][..], Vec::as_slice);
        let lanes = tracks.len().min(LANES);
        let height = 18.0 + 12.0 * lanes as f32;
        let width = ui.available_width().max(100.0);
        let (rect, response) = ui.allocate_exact_size(Vec2::new(width, height), Sense::click_and_drag());
        let label = format!("timeline of {id}");
        response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, &label));
        let names_width = 130.0_f32.min(rect.width() * 0.3);
        let bar = Rect::from_min_max(
            Pos2::new(rect.left() + names_width, rect.top()),
            Pos2::new(rect.right() - 6.0, rect.top() + 14.0),
        );
        let x_of = |seconds: f64| bar.left() + bar.width() * (seconds / duration).clamp(0.0, 1.0) as f32;
        let painter = ui.painter_at(rect);
        let visuals = ui.visuals();
        painter.rect_filled(bar, 3.0, visuals.extreme_bg_color);
        if let Some([start, end]) = status
            .get("range_s")
            .and_then(serde_json::Value::as_array)
            .and_then(|r| Some([r.first()?.as_f64()?, r.get(1)?.as_f64()?]))
        {
            let range = Rect::from_min_max(
                Pos2::new(x_of(start), bar.top()),
                Pos2::new(x_of(end), bar.bottom()),
            );
            painter.rect_filled(range, 3.0, visuals.selection.bg_fill.gamma_multiply(0.5));
        }
        painter.text(
            Pos2::new(rect.left(), bar.center().y),
            egui::Align2::LEFT_CENTER,
            "time",
            egui::FontId::proportional(11.0),
            visuals.weak_text_color(),
        );
        for (lane, track) in tracks.iter().take(LANES).enumerate() {
            let y = bar.bottom() + 4.0 + 12.0 * lane as f32;
            let name = track
                .get("output")
                .and_then(serde_json::Value::as_str)
                .unwrap_or("?");
            let messages = track
                .get("messages")
                .and_then(serde_json::Value::as_u64)
                .unwrap_or(0);
            let file = track.get("file").and_then(serde_json::Value::as_u64).unwrap_or(0);
            let span = files
                .get(usize::try_from(file).unwrap_or(0))
                .map_or((0.0, duration), |f| (number(f, "start_s"), number(f, "end_s")));
            painter.text(
                Pos2::new(rect.left(), y + 4.0),
                egui::Align2::LEFT_CENTER,
                format!("{name} ({messages})"),
                egui::FontId::proportional(10.0),
                visuals.text_color(),
            );
            let lane_rect = Rect::from_min_max(Pos2::new(x_of(span.0), y), Pos2::new(x_of(span.1), y + 8.0));
            painter.rect_filled(
                lane_rect,
                2.0,
                crate::canvas::type_color(name).gamma_multiply(0.6),
            );
        }
        if tracks.len() > LANES {
            response
                .clone()
                .on_hover_text(format!("{} more tracks not drawn", tracks.len() - LANES));
        }
        draw_markers(&painter, &response, status, (bar, rect), x_of);
        let shown = self.scrubbing.get(id).copied().unwrap_or(position);
        let x = x_of(shown);
        painter.line_segment(
            [Pos2::new(x, bar.top() - 1.0), Pos2::new(x, rect.bottom())],
            Stroke::new(2.0, Color32::from_rgb(240, 200, 80)),
        );
        let to_seconds = |p: Pos2| f64::from(((p.x - bar.left()) / bar.width()).clamp(0.0, 1.0)) * duration;
        if (response.dragged() || response.is_pointer_button_down_on())
            && let Some(pointer) = response.interact_pointer_pos()
        {
            self.scrubbing.insert(id.to_owned(), to_seconds(pointer));
        }
        // A click whose press and release came in one frame never scrubbed: it seeks where it landed.
        let clicked_at = response
            .clicked()
            .then(|| response.interact_pointer_pos().map(to_seconds))
            .flatten();
        if (response.drag_stopped() || response.clicked())
            && let Some(target) = self.scrubbing.remove(id).or(clicked_at)
        {
            requests.push(RequestBody::PlayerSeek {
                component,
                seconds: target,
            });
        }
    }
}

fn recorder_row(
    ui: &mut egui::Ui,
    id: &str,
    status: &serde_json::Value,
    requests: &mut Vec<RequestBody>,
    replay: &mut Option<Command>,
) {
    let component = id.to_owned();
    let recording = flag(status, "recording");
    let pre_trigger = status.get("mode").and_then(serde_json::Value::as_str) == Some("pre_trigger");
    let writing = recording && (!pre_trigger || flag(status, "in_event"));
    ui.horizontal(|ui| {
        ui.strong(id).on_hover_text("a recorder");
        if recording && !writing {
            ui.label(
                RichText::new("ARMED")
                    .color(Color32::from_rgb(230, 160, 60))
                    .strong(),
            )
            .on_hover_text("keeping the last seconds in memory, waiting for a trigger");
        } else if recording {
            ui.label(
                RichText::new("REC")
                    .color(Color32::from_rgb(230, 60, 60))
                    .strong(),
            );
        } else {
            ui.weak("not recording");
        }
        if ui.add_enabled(!recording, egui::Button::new("Start")).clicked() {
            requests.push(RequestBody::RecordStart {
                component: component.clone(),
            });
        }
        if ui.add_enabled(recording, egui::Button::new("Stop")).clicked() {
            requests.push(RequestBody::RecordStop {
                component: component.clone(),
            });
        }
        if ui
            .add_enabled(writing && !pre_trigger, egui::Button::new("Split"))
            .on_hover_text("close this file and go on in a new one")
            .clicked()
        {
            requests.push(RequestBody::RecordSplit {
                component: component.clone(),
            });
        }
        if ui
            .add_enabled(writing, egui::Button::new("Mark"))
            .on_hover_text("write a marker into the recording now (its text is the recorder's marker_text)")
            .clicked()
        {
            requests.push(RequestBody::TriggerAction {
                component,
                action: "mark".to_owned(),
            });
        }
        let markers = number(status, "markers");
        if markers > 0.0 {
            ui.weak(format!("{markers} markers"));
        }
        if pre_trigger {
            pre_trigger_controls(ui, id, status, requests);
        }
        if let Some(path) = status.get("path").and_then(serde_json::Value::as_str) {
            // The size on disk, as a file manager shows it; the samples' own size before compression on hover.
            ui.monospace(format!("{path}  {:.1} MB", number(status, "disk_bytes") / 1e6))
                .on_hover_text(format!(
                    "{:.1} MB of samples before compression",
                    number(status, "bytes") / 1e6
                ));
        }
        match status.get("files_closed").and_then(serde_json::Value::as_u64) {
            None | Some(0) => {}
            Some(1) => {
                ui.weak("1 file closed");
            }
            Some(closed) => {
                ui.weak(format!("{closed} files closed"));
            }
        }
        if let Some(file) = status.get("last_file").and_then(serde_json::Value::as_str)
            && ui
                .button("Replay")
                .on_hover_text(format!(
                    "replay {file} in a new diagram: a player on it, with the viewers of what it recorded"
                ))
                .clicked()
        {
            *replay = Some(Command::Replay {
                recorder: id.to_owned(),
                file: file.to_owned(),
            });
        }
    });
}

/// A tick per marker across the timeline, and the text of the one under the pointer.
fn draw_markers(
    painter: &egui::Painter,
    response: &egui::Response,
    status: &serde_json::Value,
    (bar, rect): (Rect, Rect),
    x_of: impl Fn(f64) -> f32,
) {
    // Markers: a tick each across the whole timeline, their texts on hover.
    let markers: Vec<(f64, &str)> = status
        .get("markers")
        .and_then(serde_json::Value::as_array)
        .map_or(&[][..], Vec::as_slice)
        .iter()
        .map(|m| {
            (
                number(m, "t_s"),
                m.get("text").and_then(serde_json::Value::as_str).unwrap_or(""),
            )
        })
        .collect();
    for (at, _) in &markers {
        let x = x_of(*at);
        painter.line_segment(
            [Pos2::new(x, bar.top()), Pos2::new(x, rect.bottom())],
            Stroke::new(1.5, MARKER_COLOR),
        );
    }
    if let Some(pointer) = response.hover_pos()
        && let Some((at, text)) = markers
            .iter()
            .filter(|(at, _)| (x_of(*at) - pointer.x).abs() <= 4.0)
            .min_by(|a, b| {
                (x_of(a.0) - pointer.x)
                    .abs()
                    .total_cmp(&(x_of(b.0) - pointer.x).abs())
            })
    {
        response
            .clone()
            .on_hover_text(format!("marker at {}: {text}", clock(*at)));
    }
}

/// A pre-trigger recorder's trigger button, what its memory holds, its events and its last error.
fn pre_trigger_controls(
    ui: &mut egui::Ui,
    id: &str,
    status: &serde_json::Value,
    requests: &mut Vec<RequestBody>,
) {
    if ui
        .button("Trigger")
        .on_hover_text("write the seconds kept in memory and the seconds that follow")
        .clicked()
    {
        requests.push(RequestBody::TriggerAction {
            component: id.to_owned(),
            action: "trigger".to_owned(),
        });
    }
    let state = if flag(status, "in_event") {
        "writing an event"
    } else {
        "waiting for a trigger"
    };
    ui.weak(format!(
        "{state} · {:.1} s in memory ({:.1} MB) · {} events",
        number(status, "ring_s"),
        number(status, "ring_bytes") / 1e6,
        number(status, "events")
    ));
    if let Some(error) = status.get("last_error").and_then(serde_json::Value::as_str) {
        ui.colored_label(Color32::from_rgb(230, 90, 90), error);
    }
}

/// The colour of markers on the timeline.
const MARKER_COLOR: Color32 = Color32::from_rgb(230, 90, 230);

/// Seconds as `m:ss.s`.
fn clock(seconds: f64) -> String {
    let seconds = seconds.max(0.0);
    let minutes = (seconds / 60.0).floor();
    format!("{minutes:.0}:{:04.1}", seconds - minutes * 60.0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn clock_reads_minutes_and_seconds() {
        assert_eq!(super::clock(75.25), "1:15.2");
        assert_eq!(super::clock(3.0), "0:03.0");
    }
}

//! The Console tab: what the diagram's console sinks (`core.console`) print, inside the studio, as
//! Node-RED's debug sidebar shows it; the runtime's terminal is often not where the user is. Bounded: the
//! oldest lines go first.

use std::collections::VecDeque;

use egui::RichText;

/// The most lines kept.
pub const CONSOLE_LINES: usize = 2000;

/// One printed line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConsoleLine {
    /// When the runtime printed it (ns since the UNIX epoch).
    pub at_ns: i64,
    /// The console component that printed it.
    pub component: String,
    /// The line.
    pub text: String,
}

/// The lines printed lately, oldest first.
#[derive(Debug, Default)]
pub struct Console {
    lines: VecDeque<ConsoleLine>,
    /// Lines dropped to stay within [`CONSOLE_LINES`].
    pub dropped: u64,
}

impl Console {
    /// Adds a line, dropping the oldest beyond the bound.
    pub fn push(&mut self, line: ConsoleLine) {
        if self.lines.len() == CONSOLE_LINES {
            self.lines.pop_front();
            self.dropped += 1;
        }
        self.lines.push_back(line);
    }

    /// The lines kept, oldest first.
    pub fn lines(&self) -> impl Iterator<Item = &ConsoleLine> {
        self.lines.iter()
    }

    /// Forgets every line.
    pub fn clear(&mut self) {
        self.lines.clear();
        self.dropped = 0;
    }

    /// The tab: a Clear button, then the lines, following the newest until scrolled up.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            if ui.button("Clear").clicked() {
                self.clear();
            }
            if self.dropped > 0 {
                ui.weak(format!("{} older lines dropped", self.dropped));
            }
        });
        if self.lines.is_empty() {
            ui.weak(
                "What console components (Console in the palette) print shows here while the diagram runs.",
            );
            return;
        }
        let row_height = ui.text_style_height(&egui::TextStyle::Monospace) + ui.spacing().item_spacing.y;
        egui::ScrollArea::both()
            .auto_shrink([false, false])
            .stick_to_bottom(true)
            .show_rows(ui, row_height, self.lines.len(), |ui, rows| {
                for line in self.lines.range(rows) {
                    line_ui(ui, line);
                }
            });
    }
}

/// One line: when, which component, what it printed.
fn line_ui(ui: &mut egui::Ui, line: &ConsoleLine) {
    ui.horizontal(|ui| {
        ui.label(RichText::new(time_of_day(line.at_ns)).monospace().weak())
            .on_hover_text("When the runtime printed it (UTC, as the runtime's own log)");
        ui.label(RichText::new(&line.component).monospace().strong());
        ui.add(egui::Label::new(RichText::new(printed_text(line)).monospace()).extend());
    });
}

/// What the line says beyond its component: a console prints its id first unless given a prefix, and the
/// component has a column of its own.
pub fn printed_text(line: &ConsoleLine) -> &str {
    line.text
        .strip_prefix(line.component.as_str())
        .and_then(|rest| rest.strip_prefix(": "))
        .unwrap_or(&line.text)
}

/// A time in ns since the UNIX epoch as the UTC time of day, to the millisecond (`14:03:07.250`).
pub fn time_of_day(at_ns: i64) -> String {
    let ms_of_day = at_ns.div_euclid(1_000_000).rem_euclid(86_400_000);
    let (hours, rest) = (ms_of_day / 3_600_000, ms_of_day % 3_600_000);
    let (minutes, rest) = (rest / 60_000, rest % 60_000);
    let (seconds, ms) = (rest / 1000, rest % 1000);
    format!("{hours:02}:{minutes:02}:{seconds:02}.{ms:03}")
}

#[cfg(test)]
mod tests {
    use super::{CONSOLE_LINES, Console, ConsoleLine};

    fn line(component: &str, text: &str) -> ConsoleLine {
        ConsoleLine {
            at_ns: 1_795_557_290_476_402_148,
            component: component.to_owned(),
            text: text.to_owned(),
        }
    }

    #[test]
    fn lines_show_their_time_and_lose_the_repeated_component() {
        assert_eq!(super::time_of_day(1_795_557_290_476_402_148), "21:54:50.476");
        assert_eq!(super::time_of_day(-1), "23:59:59.999");
        assert_eq!(
            super::printed_text(&line("console1", "console1: t=1 0.5")),
            "t=1 0.5"
        );
        assert_eq!(
            super::printed_text(&line("console1", "speed: t=1 0.5")),
            "speed: t=1 0.5"
        );
    }

    #[test]
    fn only_the_last_lines_are_kept() {
        let mut console = Console::default();
        for n in 0..CONSOLE_LINES + 5 {
            console.push(line("console1", &n.to_string()));
        }
        assert_eq!(console.lines().count(), CONSOLE_LINES);
        assert_eq!(console.lines().next().map(|l| l.text.as_str()), Some("5"));
        assert_eq!(console.dropped, 5);
        console.clear();
        assert_eq!(console.lines().count(), 0);
    }
}

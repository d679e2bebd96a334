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
        let row_height = ui.text_style_height(&egui::TextStyle::Monospace);
        egui::ScrollArea::both()
            .auto_shrink([false, false])
            .stick_to_bottom(true)
            .show_rows(ui, row_height, self.lines.len(), |ui, rows| {
                for line in self.lines.range(rows) {
                    ui.add(egui::Label::new(RichText::new(&line.text).monospace()).extend());
                }
            });
    }
}

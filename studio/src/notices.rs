//! Notices over the canvas: one per problem (a link losing samples, a component that failed), updated in
//! place with how often it happened, dismissable, kept inside the canvas so they never cover the palette,
//! its search or the inspector.

use std::time::{Duration, Instant};

use egui::{Color32, RichText};

/// How long a notice about a passing problem (losses) stays after it last happened.
const SHOWN_AFTER_LAST: Duration = Duration::from_secs(8);
/// At most this many problems are remembered; the oldest go first.
const KEPT: usize = 32;

/// What a notice is about: the same problem again updates its notice instead of adding one.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum Problem {
    /// A link (`a.out -> b.in`) lost samples: its reader is slower than its writer.
    Losses(String),
    /// A component failed.
    Failed(String),
    /// A host of a spread diagram (its name) stopped answering.
    HostLost(String),
    /// A connection between two hosts (`a.out -> b.in`) lost its far end.
    LinkCut(String),
    /// A connection between two hosts matches but delivers nothing.
    LinkSilent(String),
    /// A host's clock has had no reference for well over its usual wait (its name).
    ClockSilent(String),
    /// A host's clock left lock (its name).
    ClockUnlocked(String),
}

/// One problem's notice.
#[derive(Debug, Clone)]
pub struct Notice {
    /// What it is about.
    pub problem: Problem,
    /// What it says (the latest occurrence's words).
    pub text: String,
    /// How many: samples lost so far, or times the component failed.
    pub count: u64,
    /// When it last happened.
    pub last: Instant,
    /// Closed by the user: hidden until the next deployment, though still counted.
    pub dismissed: bool,
}

impl Notice {
    /// Whether it is shown now: not dismissed, and a failure, or losses seen lately.
    fn shown(&self, now: Instant) -> bool {
        !self.dismissed
            && match self.problem {
                Problem::Losses(_) => now.duration_since(self.last) < SHOWN_AFTER_LAST,
                _ => true,
            }
    }

    /// The line shown: the text and its count.
    pub fn line(&self) -> String {
        match self.problem {
            Problem::Losses(_) => format!("{} ({} lost so far)", self.text, self.count),
            _ if self.count > 1 => format!("{} ({} times)", self.text, self.count),
            _ => self.text.clone(),
        }
    }
}

/// Every problem's notice, oldest first.
#[derive(Debug, Default)]
pub struct Notices {
    list: Vec<Notice>,
}

impl Notices {
    /// The problem happened (again): its notice says `text` and `count` from now on. Returns whether it
    /// is new.
    pub fn raise(&mut self, problem: Problem, text: String, count: u64) -> bool {
        let now = Instant::now();
        if let Some(notice) = self.list.iter_mut().find(|n| n.problem == problem) {
            notice.text = text;
            notice.count = count;
            notice.last = now;
            return false;
        }
        if self.list.len() == KEPT {
            self.list.remove(0);
        }
        self.list.push(Notice {
            problem,
            text,
            count,
            last: now,
            dismissed: false,
        });
        true
    }

    /// The problem is over (a failed component runs again): its notice goes; whether there was one.
    pub fn resolve(&mut self, problem: &Problem) -> bool {
        let before = self.list.len();
        self.list.retain(|n| &n.problem != problem);
        self.list.len() != before
    }

    /// Forgets every notice (a new deployment).
    pub fn clear(&mut self) {
        self.list.clear();
    }

    /// Hides a problem's notice until the next deployment.
    pub fn dismiss(&mut self, problem: &Problem) {
        if let Some(notice) = self.list.iter_mut().find(|n| &n.problem == problem) {
            notice.dismissed = true;
        }
    }

    /// The notices shown now, oldest first.
    pub fn shown(&self) -> impl Iterator<Item = &Notice> {
        let now = Instant::now();
        self.list.iter().filter(move |n| n.shown(now))
    }

    /// Whether any notice is shown now.
    pub fn any_shown(&self) -> bool {
        self.shown().next().is_some()
    }

    /// Draws the notices shown, one line each with a button that dismisses it, in `ui`: a strip over the
    /// canvas, so that no notice covers a node.
    pub fn show(&mut self, ui: &mut egui::Ui) {
        let now = Instant::now();
        let shown: Vec<Notice> = self.list.iter().filter(|n| n.shown(now)).cloned().collect();
        if shown.is_empty() {
            return;
        }
        let mut dismissed = Vec::new();
        for notice in &shown {
            ui.horizontal_top(|ui| {
                if ui
                    .small_button("x")
                    .on_hover_text("Dismiss: hidden until the next run (the Log keeps it)")
                    .clicked()
                {
                    dismissed.push(notice.problem.clone());
                }
                ui.add(
                    egui::Label::new(RichText::new(notice.line()).color(Color32::from_rgb(240, 140, 60)))
                        .wrap(),
                );
            });
        }
        for problem in &dismissed {
            self.dismiss(problem);
        }
        let ctx = ui.ctx().clone();
        // Wake when the first passing notice is due to go, not before: at rest nothing is drawn.
        let next_expiry = shown
            .iter()
            .filter(|n| matches!(n.problem, Problem::Losses(_)))
            .map(|n| (n.last + SHOWN_AFTER_LAST).saturating_duration_since(now))
            .min();
        if let Some(after) = next_expiry {
            ctx.request_repaint_after(after + Duration::from_millis(20));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Notices, Problem};

    #[test]
    fn the_same_problem_updates_its_notice_in_place() {
        let mut notices = Notices::default();
        let link = Problem::Losses("a.out -> b.in".to_owned());
        assert!(notices.raise(link.clone(), "a.out -> b.in loses samples".to_owned(), 3));
        assert!(!notices.raise(link.clone(), "a.out -> b.in loses samples".to_owned(), 40));
        assert!(notices.raise(Problem::Failed("c".to_owned()), "c failed: boom".to_owned(), 1));
        let lines: Vec<String> = notices.shown().map(super::Notice::line).collect();
        assert_eq!(
            lines,
            ["a.out -> b.in loses samples (40 lost so far)", "c failed: boom"]
        );
        notices.dismiss(&link);
        assert_eq!(notices.shown().count(), 1);
        // Still counted while dismissed, and not shown again until the next deployment.
        assert!(!notices.raise(link, "again".to_owned(), 50));
        assert_eq!(notices.shown().count(), 1);
        notices.clear();
        assert_eq!(notices.shown().count(), 0);
    }
}

//! The log the studio shows: the runtime's records and the studio's own lines, the latest
//! [`LOG_LINES`], and the filter the log panel applies (a least level, one component). A line that says
//! again what a recent one said, but for its numbers (an overflow warned every second), replaces it with
//! a count, as the notices over the canvas do.

use std::collections::VecDeque;

use kairos_protocol::{LogLevel, LogRecord};

/// How many lines the log keeps; older ones go.
pub const LOG_LINES: usize = 2000;

/// How far back a repeat is looked for: the lines a problem's repeats are interleaved with.
const REPEAT_WINDOW: usize = 20;

/// Whether a line reports a success (drawn green) or is plain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tone {
    /// Coloured by its level.
    Plain,
    /// Something the user asked for succeeded (connected, deployed, loaded).
    Success,
}

/// Where a line came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// The studio itself.
    Studio,
    /// The runtime's log.
    Runtime,
}

/// One line of the log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogLine {
    /// Its level.
    pub level: LogLevel,
    /// Its tone.
    pub tone: Tone,
    /// Where it came from.
    pub source: Source,
    /// The component it concerns, for runtime records that name one.
    pub component: Option<String>,
    /// The text shown: the latest of its repeats.
    pub text: String,
    /// How many times it was said (1: once).
    pub repeats: u32,
    /// The text without its numbers, made once: what a repeat says again.
    words: String,
}

impl LogLine {
    fn new(level: LogLevel, tone: Tone, source: Source, component: Option<String>, text: String) -> Self {
        let words = text
            .chars()
            .filter(|c| !c.is_ascii_digit() && *c != '.')
            .collect();
        LogLine {
            level,
            tone,
            source,
            component,
            text,
            repeats: 1,
            words,
        }
    }

    /// Whether `self` says again what `other` said: the same level, source, component and words, but
    /// for the numbers.
    fn repeats_line(&self, other: &LogLine) -> bool {
        self.level == other.level
            && self.source == other.source
            && self.component == other.component
            && self.words == other.words
    }
}

/// What the log panel shows: lines of at least `least`, of one component or all.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogFilter {
    /// The least level shown.
    pub least: LogLevel,
    /// The one component shown; all when `None`.
    pub component: Option<String>,
}

impl Default for LogFilter {
    fn default() -> Self {
        LogFilter {
            least: LogLevel::Info,
            component: None,
        }
    }
}

impl LogFilter {
    /// Whether `line` passes.
    pub fn shows(&self, line: &LogLine) -> bool {
        line.level >= self.least
            && self
                .component
                .as_ref()
                .is_none_or(|c| line.component.as_ref() == Some(c))
    }
}

/// The log's lines, the oldest first.
#[derive(Debug, Clone, Default)]
pub struct Log {
    lines: VecDeque<LogLine>,
}

impl Log {
    /// Adds a line, forgetting the oldest beyond [`LOG_LINES`]. A repeat of one of the last few lines
    /// takes that line's place at the end, counted.
    pub fn push(&mut self, mut line: LogLine) {
        let recent = self.lines.len().saturating_sub(REPEAT_WINDOW);
        if let Some(at) = (recent..self.lines.len())
            .rev()
            .find(|&at| self.lines.get(at).is_some_and(|old| line.repeats_line(old)))
            && let Some(old) = self.lines.remove(at)
        {
            line.repeats = old.repeats.saturating_add(line.repeats);
        }
        self.lines.push_back(line);
        while self.lines.len() > LOG_LINES {
            self.lines.pop_front();
        }
    }

    /// A line of the studio's own.
    pub fn studio(&mut self, level: LogLevel, tone: Tone, text: impl Into<String>) {
        self.push(LogLine::new(level, tone, Source::Studio, None, text.into()));
    }

    /// A record of the runtime's log, prefixed with the component it concerns.
    pub fn record(&mut self, record: LogRecord) {
        let who = record
            .component
            .as_ref()
            .map_or_else(String::new, |c| format!("{c}: "));
        let text = format!("{who}{}", record.message);
        self.push(LogLine::new(
            record.level,
            Tone::Plain,
            Source::Runtime,
            record.component,
            text,
        ));
    }

    /// Every line, the oldest first.
    pub fn lines(&self) -> impl Iterator<Item = &LogLine> {
        self.lines.iter()
    }

    /// The lines `filter` shows, the oldest first.
    pub fn visible<'a>(&'a self, filter: &'a LogFilter) -> impl Iterator<Item = &'a LogLine> {
        self.lines.iter().filter(|l| filter.shows(l))
    }

    /// The components named in the log, sorted, each once (the panel's choices).
    pub fn components(&self) -> Vec<String> {
        let mut components: Vec<String> = self.lines.iter().filter_map(|l| l.component.clone()).collect();
        components.sort();
        components.dedup();
        components
    }
}

#[cfg(test)]
mod tests {
    use kairos_protocol::{LogLevel, LogRecord};

    use super::{LOG_LINES, Log, LogFilter, Tone};

    fn record(level: LogLevel, component: Option<&str>, message: &str) -> LogRecord {
        LogRecord {
            at_ns: 0,
            level,
            component: component.map(str::to_owned),
            message: message.to_owned(),
        }
    }

    fn texts<'a>(log: &'a Log, filter: &'a LogFilter) -> Vec<&'a str> {
        log.visible(filter).map(|l| l.text.as_str()).collect()
    }

    #[test]
    fn the_filter_keeps_lines_of_its_level_and_above_and_of_its_component() {
        let mut log = Log::default();
        log.record(record(LogLevel::Debug, Some("camera"), "exposure 4 ms"));
        log.record(record(LogLevel::Info, Some("camera"), "started"));
        log.record(record(LogLevel::Warn, Some("gnss"), "no fix"));
        log.studio(LogLevel::Error, Tone::Plain, "no runtime connected");
        log.record(record(LogLevel::Error, Some("camera"), "device lost"));

        let mut filter = LogFilter::default();
        assert_eq!(
            texts(&log, &filter),
            [
                "camera: started",
                "gnss: no fix",
                "no runtime connected",
                "camera: device lost"
            ]
        );
        filter.least = LogLevel::Warn;
        assert_eq!(
            texts(&log, &filter),
            ["gnss: no fix", "no runtime connected", "camera: device lost"]
        );
        filter.component = Some("camera".to_owned());
        assert_eq!(texts(&log, &filter), ["camera: device lost"]);
        filter.least = LogLevel::Trace;
        assert_eq!(
            texts(&log, &filter),
            ["camera: exposure 4 ms", "camera: started", "camera: device lost"]
        );
        assert_eq!(log.components(), ["camera", "gnss"]);
    }

    #[test]
    fn a_problem_said_again_is_one_line_with_a_count_at_the_end() {
        let mut log = Log::default();
        let filter = LogFilter::default();
        log.record(record(
            LogLevel::Warn,
            Some("a"),
            "a.out -> b.in overflowed: 12 samples lost",
        ));
        log.record(record(LogLevel::Info, Some("c"), "started"));
        log.record(record(
            LogLevel::Warn,
            Some("a"),
            "a.out -> b.in overflowed: 30 samples lost",
        ));
        log.record(record(
            LogLevel::Warn,
            Some("a"),
            "a.out -> b.in overflowed: 7 samples lost",
        ));
        // Other words, another component or another level: a line of its own.
        log.record(record(
            LogLevel::Warn,
            Some("b"),
            "a.out -> b.in overflowed: 7 samples lost",
        ));
        log.record(record(
            LogLevel::Error,
            Some("a"),
            "a.out -> b.in overflowed: 7 samples lost",
        ));
        let lines: Vec<(&str, u32)> = log
            .visible(&filter)
            .map(|l| (l.text.as_str(), l.repeats))
            .collect();
        assert_eq!(
            lines,
            [
                ("c: started", 1),
                ("a: a.out -> b.in overflowed: 7 samples lost", 3),
                ("b: a.out -> b.in overflowed: 7 samples lost", 1),
                ("a: a.out -> b.in overflowed: 7 samples lost", 1),
            ]
        );
    }

    #[test]
    fn the_log_keeps_its_latest_lines() {
        // Lines in words (digits would make them repeats of each other): n in base 26, as letters.
        let words = |mut n: usize| {
            let mut text = String::new();
            loop {
                text.push(char::from(b'a' + (n % 26) as u8));
                n /= 26;
                if n == 0 {
                    return text;
                }
            }
        };
        let mut log = Log::default();
        for n in 0..LOG_LINES + 5 {
            log.studio(LogLevel::Info, Tone::Plain, words(n));
        }
        assert_eq!(log.lines().count(), LOG_LINES);
        assert_eq!(log.lines().next().map(|l| l.text.clone()), Some(words(5)));
    }
}

//! Located diagnostics: what is wrong, where, and what would fix it.
//!
//! Both the reader (syntax and structure) and the validator (meaning, against a component library)
//! report through [`Diagnostic`], so a tool shows every problem the same way.

use std::fmt;

use serde::{Deserialize, Serialize};

/// How bad a problem is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Severity {
    /// The diagram cannot be run as it is.
    Error,
    /// The diagram can run, but something is probably not what the author meant.
    Warning,
}

impl Severity {
    /// The word printed before a message (`error`, `warning`).
    pub fn name(self) -> &'static str {
        match self {
            Severity::Error => "error",
            Severity::Warning => "warning",
        }
    }
}

impl fmt::Display for Severity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What kind of problem a diagnostic reports, so tools can react without parsing messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum DiagnosticCode {
    /// The text is not valid RON (of the subset diagrams use).
    Syntax,
    /// Values are nested deeper than the reader allows.
    TooDeep,
    /// A required field is absent.
    MissingField,
    /// A field the format does not know.
    UnknownField,
    /// A value of the wrong type for its place (a list where a string belongs, ...).
    WrongType,
    /// A field or map key given twice.
    DuplicateKey,
    /// The file's format version is not the one this crate reads.
    UnsupportedFormat,
    /// A component id with characters other than letters, digits, `_` and `-`, or empty.
    InvalidId,
    /// Two components share an id.
    DuplicateId,
    /// A component type the library does not have.
    UnknownComponentType,
    /// A property the component type does not have.
    UnknownProperty,
    /// A property value of the wrong kind, out of range, or not one of the choices.
    InvalidPropertyValue,
    /// Output settings for an output the component type does not have.
    UnknownOutput,
    /// A buffer size, subsampling or priority outside its range.
    InvalidSetting,
    /// A connection names a component id the diagram does not have.
    UnknownComponent,
    /// A connection names a port the component does not have.
    UnknownPort,
    /// Two connections feed the same input.
    InputFedTwice,
    /// A connection whose output type the input's filter refuses.
    TypeMismatch,
    /// A pack listed twice in the diagram's requirements.
    DuplicatePack,
    /// A pack version requirement that is not valid semver.
    InvalidVersionRequirement,
    /// A required pack the library does not have.
    MissingPack,
    /// A required pack whose version in the library does not satisfy the requirement.
    PackVersionMismatch,
    /// A component whose pack is not listed among the diagram's requirements.
    UnlistedPack,
    /// Reactive components connected in a cycle, which would deadlock.
    ReactiveCycle,
    /// A component whose ports depend on its properties could not describe itself (a player whose
    /// recording cannot be read).
    CannotDescribe,
    /// A clock source that is not a component of the diagram, or not one that can give the time.
    InvalidClockSource,
    /// A component placed on a host the `hosts` section does not name.
    UnknownHost,
    /// A host whose endpoint is not a `ws://` or `wss://` address with a port.
    InvalidEndpoint,
    /// An execution group that cannot run as asked: members on two machines, two members that wait, a
    /// group no component uses.
    InvalidGroup,
    /// Components of one execution group that feed each other in a loop.
    GroupCycle,
    /// A subgraph that cannot be used: its file cannot be read or has errors, it includes itself, an
    /// instance names a port or property it does not expose, or it exposes one twice or one it lacks.
    InvalidSubgraph,
}

/// Where a problem is in the source text.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Location {
    /// The line, counted from 1.
    pub line: usize,
    /// The column in characters (not bytes), counted from 1.
    pub column: usize,
    /// The byte offset of the span's start in the source.
    pub offset: usize,
    /// The span's length in bytes.
    pub len: usize,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.column)
    }
}

/// A secondary remark attached to a diagnostic, such as where the first of two duplicates is.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Note {
    /// What the note says.
    pub message: String,
    /// Where it points, when known.
    pub location: Option<Location>,
}

/// One problem found in a diagram.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Diagnostic {
    /// Whether the diagram is unusable or merely suspicious.
    pub severity: Severity,
    /// What kind of problem it is.
    pub code: DiagnosticCode,
    /// One sentence saying what is wrong.
    pub message: String,
    /// The offending token, when the diagram came from text.
    pub location: Option<Location>,
    /// What would probably fix it (`did you mean 'frequency'?`).
    pub suggestion: Option<String>,
    /// Related places, such as the other half of a duplicate.
    pub notes: Vec<Note>,
}

/// What a [`DiagnosticCode::MissingPack`] says after the pack's name.
const NOT_IN_LIBRARY: &str = "' is not in the component library";

impl Diagnostic {
    /// That the diagram needs pack `name`, which the component library lacks.
    pub fn missing_pack(name: &str) -> Self {
        Diagnostic::error(
            DiagnosticCode::MissingPack,
            format!("pack '{name}{NOT_IN_LIBRARY}"),
        )
    }

    /// The pack a [`Diagnostic::missing_pack`] is about, for whoever knows more of it (it was refused).
    pub fn missing_pack_name(&self) -> Option<&str> {
        matches!(self.code, DiagnosticCode::MissingPack)
            .then(|| self.message.strip_prefix("pack '")?.strip_suffix(NOT_IN_LIBRARY))
            .flatten()
    }

    /// An error with no location yet.
    pub fn error(code: DiagnosticCode, message: impl Into<String>) -> Self {
        Diagnostic {
            severity: Severity::Error,
            code,
            message: message.into(),
            location: None,
            suggestion: None,
            notes: Vec::new(),
        }
    }

    /// A warning with no location yet.
    pub fn warning(code: DiagnosticCode, message: impl Into<String>) -> Self {
        Diagnostic {
            severity: Severity::Warning,
            ..Diagnostic::error(code, message)
        }
    }

    /// The same diagnostic, located (or not, when `location` is `None`).
    #[must_use]
    pub fn at(mut self, location: Option<Location>) -> Self {
        self.location = location;
        self
    }

    /// The same diagnostic with a suggestion (ignored when `None`).
    #[must_use]
    pub fn with_suggestion(mut self, suggestion: Option<String>) -> Self {
        if suggestion.is_some() {
            self.suggestion = suggestion;
        }
        self
    }

    /// The same diagnostic with one more note.
    #[must_use]
    pub fn with_note(mut self, message: impl Into<String>, location: Option<Location>) -> Self {
        self.notes.push(Note {
            message: message.into(),
            location,
        });
        self
    }

    /// Whether this is an error rather than a warning.
    pub fn is_error(&self) -> bool {
        self.severity == Severity::Error
    }

    /// Rustc-like text: the message, the file position, the source line with the span underlined, the
    /// suggestion as `help:`, then each note the same way.
    ///
    /// `source` must be the text the locations were taken from; a location that does not fit it is
    /// shown without its source line rather than failing.
    pub fn render(&self, file_name: &str, source: &str) -> String {
        Rendered {
            diagnostic: self,
            file_name,
            source,
        }
        .to_string()
    }
}

/// Renders every diagnostic one after the other, as a compiler would print them.
pub fn render_all(diagnostics: &[Diagnostic], file_name: &str, source: &str) -> String {
    let rendered: Vec<String> = diagnostics.iter().map(|d| d.render(file_name, source)).collect();
    rendered.join("\n")
}

/// A diagnostic with the text it points into, displayed the way rustc shows errors.
struct Rendered<'a> {
    diagnostic: &'a Diagnostic,
    file_name: &'a str,
    source: &'a str,
}

impl fmt::Display for Rendered<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let diagnostic = self.diagnostic;
        writeln!(f, "{}: {}", diagnostic.severity, diagnostic.message)?;
        // One gutter width for the whole diagnostic, so the bars line up across notes.
        let gutter = diagnostic
            .notes
            .iter()
            .filter_map(|n| n.location)
            .chain(diagnostic.location)
            .map(|l| l.line.to_string().len())
            .max()
            .unwrap_or(1);
        if let Some(location) = diagnostic.location {
            self.snippet(f, location, gutter)?;
        }
        if let Some(suggestion) = &diagnostic.suggestion {
            writeln!(f, "{:gutter$} = help: {suggestion}", "")?;
        }
        for note in &diagnostic.notes {
            writeln!(f, "note: {}", note.message)?;
            if let Some(location) = note.location {
                self.snippet(f, location, gutter)?;
            }
        }
        Ok(())
    }
}

impl Rendered<'_> {
    /// ` --> file:line:col`, then the source line with a caret underline when the location fits.
    fn snippet(&self, f: &mut fmt::Formatter<'_>, location: Location, gutter: usize) -> fmt::Result {
        writeln!(f, "{:gutter$}--> {}:{location}", "", self.file_name)?;
        let source = self.source;
        let Some(before) = source.get(..location.offset) else {
            return Ok(());
        };
        let line_start = before.rfind('\n').map_or(0, |i| i + 1);
        let Some(line_and_rest) = source.get(line_start..) else {
            return Ok(());
        };
        let line_text = line_and_rest
            .split('\n')
            .next()
            .unwrap_or("")
            .trim_end_matches('\r');
        let prefix = before.get(line_start..).unwrap_or("");
        // Keep tabs as tabs so the caret lines up however wide the terminal draws them.
        let indent: String = prefix
            .chars()
            .map(|c| if c == '\t' { '\t' } else { ' ' })
            .collect();
        let line_end = line_start + line_text.len();
        let span_end = location
            .offset
            .saturating_add(location.len)
            .clamp(location.offset, line_end.max(location.offset));
        let underlined = source
            .get(location.offset..span_end)
            .map_or(0, |s| s.chars().count())
            .max(1);
        writeln!(f, "{:gutter$} |", "")?;
        writeln!(f, "{:>gutter$} | {line_text}", location.line)?;
        writeln!(f, "{:gutter$} | {indent}{}", "", "^".repeat(underlined))
    }
}

impl fmt::Display for Diagnostic {
    /// `line:column: error: message; suggestion`, on one line.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(location) = self.location {
            write!(f, "{location}: ")?;
        }
        write!(f, "{}: {}", self.severity, self.message)?;
        if let Some(suggestion) = &self.suggestion {
            write!(f, "; {suggestion}")?;
        }
        Ok(())
    }
}

/// Turns byte offsets into line and column numbers.
#[derive(Debug)]
pub(crate) struct LineIndex<'s> {
    source: &'s str,
    line_starts: Vec<usize>,
}

impl<'s> LineIndex<'s> {
    pub(crate) fn new(source: &'s str) -> Self {
        let line_starts = std::iter::once(0)
            .chain(source.match_indices('\n').map(|(i, _)| i + 1))
            .collect();
        LineIndex { source, line_starts }
    }

    /// The location of the bytes `start..end`.
    pub(crate) fn location(&self, start: usize, end: usize) -> Location {
        let line_index = self
            .line_starts
            .partition_point(|&s| s <= start)
            .saturating_sub(1);
        let line_start = self.line_starts.get(line_index).copied().unwrap_or(0);
        let column = self
            .source
            .get(line_start..start)
            .map_or(0, |p| p.chars().count())
            + 1;
        Location {
            line: line_index + 1,
            column,
            offset: start,
            len: end.saturating_sub(start),
        }
    }
}

/// The candidate closest to `target`, when one is close enough to be a plausible typo.
pub fn closest<'c>(target: &str, candidates: impl IntoIterator<Item = &'c str>) -> Option<&'c str> {
    let target_len = target.chars().count();
    candidates
        .into_iter()
        .filter(|c| *c != target)
        .map(|c| {
            // Case mistakes count as one edit at most: `Fifo` for `FIFO` is a typo, not a new name.
            let distance = if c.eq_ignore_ascii_case(target) {
                1
            } else {
                strsim::damerau_levenshtein(target, c)
            };
            (distance, c)
        })
        .filter(|(distance, c)| *distance <= (target_len.max(c.chars().count()) / 3).max(1))
        .min_by_key(|(distance, _)| *distance)
        .map(|(_, c)| c)
}

/// `did you mean 'x'?` when a candidate is close to `target`.
pub fn did_you_mean<'c>(target: &str, candidates: impl IntoIterator<Item = &'c str>) -> Option<String> {
    closest(target, candidates).map(|c| format!("did you mean '{c}'?"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_index_counts_characters_not_bytes() {
        let source = "ab\né\"x\"\n";
        let index = LineIndex::new(source);
        let location = index.location(5, 8);
        assert_eq!((location.line, location.column, location.len), (2, 2, 3));
        assert_eq!(index.location(0, 0).to_string(), "1:1");
        assert_eq!(index.location(source.len(), source.len()).to_string(), "3:1");
    }

    #[test]
    fn closest_finds_typos_and_ignores_strangers() {
        let names = ["frequency", "waveform", "amplitude"];
        assert_eq!(closest("frequncy", names), Some("frequency"));
        assert_eq!(closest("wavefrom", names), Some("waveform"));
        assert_eq!(closest("colour", names), None);
        assert_eq!(closest("frequency", names), None);
    }

    #[test]
    fn render_underlines_the_span_and_prints_help() {
        let source = "Diagram(\n    \"frequncy\": 2.0,\n)\n";
        let diagnostic = Diagnostic::error(DiagnosticCode::UnknownProperty, "unknown property 'frequncy'")
            .at(Some(LineIndex::new(source).location(13, 23)))
            .with_suggestion(Some("did you mean 'frequency'?".to_owned()));
        assert_eq!(
            diagnostic.render("d.ron", source),
            "error: unknown property 'frequncy'\n \
             --> d.ron:2:5\n  \
             |\n\
             2 |     \"frequncy\": 2.0,\n  \
             |     ^^^^^^^^^^\n  \
             = help: did you mean 'frequency'?\n"
        );
        assert_eq!(
            diagnostic.to_string(),
            "2:5: error: unknown property 'frequncy'; did you mean 'frequency'?"
        );
    }

    #[test]
    fn render_survives_locations_that_do_not_fit_the_source() {
        let diagnostic = Diagnostic::error(DiagnosticCode::Syntax, "odd").at(Some(Location {
            line: 9,
            column: 9,
            offset: 1000,
            len: 5,
        }));
        assert_eq!(diagnostic.render("x", "é"), "error: odd\n --> x:9:9\n");
        let inside_char = Diagnostic::error(DiagnosticCode::Syntax, "odd").at(Some(Location {
            line: 1,
            column: 1,
            offset: 1,
            len: 5,
        }));
        assert_eq!(inside_char.render("x", "é"), "error: odd\n --> x:1:1\n");
    }
}

//! A small reader for the RON subset diagrams use, keeping the byte span of every value.
//!
//! Off-the-shelf RON deserialisers forget where values came from, and located diagnostics need exactly
//! that. The reader never panics: it moves through the text with checked accessors only, always by whole
//! characters, and caps nesting at [`MAX_DEPTH`] so that hostile input cannot exhaust the stack.

use std::fmt;

use crate::diagnostic::DiagnosticCode;

/// How deeply values may nest in a diagram file; diagrams need five levels, so this is generous.
pub const MAX_DEPTH: usize = 64;

/// Byte offsets `start..end` in the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Span {
    pub(crate) start: usize,
    pub(crate) end: usize,
}

impl Span {
    fn new(start: usize, end: usize) -> Self {
        Span { start, end }
    }
}

/// A named field of a struct: `name: value`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Field {
    pub(crate) name: String,
    pub(crate) name_span: Span,
    pub(crate) value: Node,
}

/// One `key: value` entry of a map.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Entry {
    pub(crate) key: Node,
    pub(crate) value: Node,
}

/// What a value is.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum NodeKind {
    /// `Name(field: value, ...)` or `(field: value, ...)`; also `()`.
    Struct {
        name: Option<String>,
        fields: Vec<Field>,
    },
    /// `Name(value, ...)` or `(value, ...)`, such as `Some(3)`.
    Tuple { name: Option<String>, items: Vec<Node> },
    /// `{ key: value, ... }`.
    Map(Vec<Entry>),
    /// `[value, ...]`.
    List(Vec<Node>),
    /// A string literal, escapes resolved.
    Text(String),
    /// An integer literal; wide enough for every `u64` and `i64`.
    Integer(i128),
    /// A float literal's text, parsed where it is used so that `f32` fields round-trip exactly.
    Float(String),
    /// `true` or `false`.
    Bool(bool),
    /// A bare identifier such as `Fifo` or `None`.
    Ident(String),
}

/// A value with where it came from.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Node {
    pub(crate) kind: NodeKind,
    /// The whole value.
    pub(crate) span: Span,
    /// What to point at for the value as a whole: a struct's name or opening parenthesis, a list's
    /// opening bracket, or the whole of a scalar.
    pub(crate) head: Span,
}

impl Node {
    /// How the value reads in a message: `a string`, `a list`, `Pack(...)`.
    pub(crate) fn describe(&self) -> String {
        match &self.kind {
            NodeKind::Struct { name: Some(name), .. } | NodeKind::Tuple { name: Some(name), .. } => {
                format!("{name}(...)")
            }
            NodeKind::Struct { name: None, .. } => "a struct".to_owned(),
            NodeKind::Tuple { name: None, .. } => "a tuple".to_owned(),
            NodeKind::Map(_) => "a map".to_owned(),
            NodeKind::List(_) => "a list".to_owned(),
            NodeKind::Text(_) => "a string".to_owned(),
            NodeKind::Integer(_) => "an integer".to_owned(),
            NodeKind::Float(_) => "a number".to_owned(),
            NodeKind::Bool(_) => "a boolean".to_owned(),
            NodeKind::Ident(name) => format!("'{name}'"),
        }
    }
}

/// Why the text is not valid RON.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct SyntaxError {
    pub(crate) code: DiagnosticCode,
    pub(crate) message: String,
    pub(crate) span: Span,
}

impl fmt::Display for SyntaxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} at byte {}", self.message, self.span.start)
    }
}

/// Reads one value filling the whole of `source` (comments and white space around it allowed).
pub(crate) fn parse_document(source: &str) -> Result<Node, SyntaxError> {
    let mut parser = Parser { source, pos: 0 };
    let node = parser.value(0)?;
    parser.skip_trivia()?;
    if parser.pos < source.len() {
        return Err(parser.error_here("expected the end of the file after the diagram"));
    }
    Ok(node)
}

type Parsed<T> = Result<T, SyntaxError>;

/// A cursor over the source; `pos` always sits on a character boundary.
struct Parser<'s> {
    source: &'s str,
    pos: usize,
}

fn is_ident_start(c: char) -> bool {
    c.is_ascii_alphabetic() || c == '_'
}

fn is_ident_continue(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

fn syntax_error(span: Span, message: impl Into<String>) -> SyntaxError {
    SyntaxError {
        code: DiagnosticCode::Syntax,
        message: message.into(),
        span,
    }
}

/// How a character reads in a message.
fn describe_char(c: Option<char>) -> String {
    match c {
        None => "end of file".to_owned(),
        Some(c) if c.is_control() || c.is_whitespace() => format!("{c:?}"),
        Some(c) => format!("'{c}'"),
    }
}

impl Parser<'_> {
    fn rest(&self) -> &str {
        self.source.get(self.pos..).unwrap_or("")
    }

    fn peek(&self) -> Option<char> {
        self.rest().chars().next()
    }

    fn peek_second(&self) -> Option<char> {
        self.rest().chars().nth(1)
    }

    fn bump(&mut self) -> Option<char> {
        let c = self.peek()?;
        self.pos += c.len_utf8();
        Some(c)
    }

    fn eat(&mut self, expected: char) -> bool {
        if self.peek() == Some(expected) {
            self.pos += expected.len_utf8();
            true
        } else {
            false
        }
    }

    /// An error pointing at the character under the cursor (or the end of the file), naming it.
    fn error_here(&self, expected: &str) -> SyntaxError {
        let found = self.peek();
        let len = found.map_or(0, char::len_utf8);
        syntax_error(
            Span::new(self.pos, self.pos + len),
            format!("{expected}, found {}", describe_char(found)),
        )
    }

    /// Skips white space, `//` line comments and (nested) `/* */` block comments.
    fn skip_trivia(&mut self) -> Parsed<()> {
        loop {
            match (self.peek(), self.peek_second()) {
                (Some(c), _) if c.is_whitespace() => {
                    self.bump();
                }
                // A byte-order mark, which some editors write at the start of a UTF-8 file.
                (Some('\u{feff}'), _) if self.pos == 0 => {
                    self.bump();
                }
                (Some('/'), Some('/')) => {
                    while let Some(c) = self.bump() {
                        if c == '\n' {
                            break;
                        }
                    }
                }
                (Some('/'), Some('*')) => self.skip_block_comment()?,
                _ => return Ok(()),
            }
        }
    }

    fn skip_block_comment(&mut self) -> Parsed<()> {
        let start = self.pos;
        self.pos += 2;
        let mut open = 1_usize;
        while open > 0 {
            match (self.bump(), self.peek()) {
                (None, _) => {
                    return Err(syntax_error(
                        Span::new(start, start + 2),
                        "unterminated block comment",
                    ));
                }
                (Some('/'), Some('*')) => {
                    self.bump();
                    open += 1;
                }
                (Some('*'), Some('/')) => {
                    self.bump();
                    open -= 1;
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn value(&mut self, depth: usize) -> Parsed<Node> {
        self.skip_trivia()?;
        let start = self.pos;
        if depth > MAX_DEPTH {
            let mut error = self.error_here("");
            error.code = DiagnosticCode::TooDeep;
            error.message = format!("values are nested more than {MAX_DEPTH} levels deep");
            return Err(error);
        }
        match self.peek() {
            Some('"') => self.string(),
            Some('[') => self.list(depth),
            Some('{') => self.map(depth),
            Some('(') => {
                self.bump();
                self.parenthesised(None, Span::new(start, self.pos), depth)
            }
            Some(c) if c == '-' || c.is_ascii_digit() => self.number(),
            Some(c) if is_ident_start(c) => self.identifier_or_named(depth),
            _ => Err(self.error_here("expected a value")),
        }
    }

    fn identifier(&mut self) -> (String, Span) {
        let start = self.pos;
        while self.peek().is_some_and(is_ident_continue) {
            self.bump();
        }
        let text = self.source.get(start..self.pos).unwrap_or("").to_owned();
        (text, Span::new(start, self.pos))
    }

    /// A bare identifier (`true`, `Fifo`, `inf`) or a named struct or tuple (`Pack(...)`, `Some(1)`).
    fn identifier_or_named(&mut self, depth: usize) -> Parsed<Node> {
        let (name, span) = self.identifier();
        let after_name = self.pos;
        self.skip_trivia()?;
        if self.eat('(') {
            return self.parenthesised(Some(name), span, depth);
        }
        self.pos = after_name;
        let kind = match name.as_str() {
            "true" => NodeKind::Bool(true),
            "false" => NodeKind::Bool(false),
            "inf" | "NaN" => NodeKind::Float(name),
            _ => NodeKind::Ident(name),
        };
        Ok(Node {
            kind,
            span,
            head: span,
        })
    }

    /// After `(`: named fields, positional items, or nothing.
    fn parenthesised(&mut self, name: Option<String>, head: Span, depth: usize) -> Parsed<Node> {
        let start = head.start;
        self.skip_trivia()?;
        if self.starts_named_field()? {
            let fields = self.named_fields(head, depth)?;
            let kind = NodeKind::Struct { name, fields };
            return Ok(Node {
                kind,
                span: Span::new(start, self.pos),
                head,
            });
        }
        let mut items = Vec::new();
        loop {
            self.skip_trivia()?;
            if self.eat(')') {
                break;
            }
            items.push(self.value(depth + 1)?);
            self.separator(')', head)?;
        }
        // `()` is the empty struct: every field of every struct in a diagram is optional or reported
        // missing by name, which reads better than "expected a struct, found a tuple".
        let kind = if items.is_empty() {
            NodeKind::Struct {
                name,
                fields: Vec::new(),
            }
        } else {
            NodeKind::Tuple { name, items }
        };
        Ok(Node {
            kind,
            span: Span::new(start, self.pos),
            head,
        })
    }

    /// Whether the cursor sits on `identifier :`, without moving it.
    fn starts_named_field(&mut self) -> Parsed<bool> {
        if !self.peek().is_some_and(is_ident_start) {
            return Ok(false);
        }
        let saved = self.pos;
        self.identifier();
        self.skip_trivia()?;
        let named = self.peek() == Some(':');
        self.pos = saved;
        Ok(named)
    }

    fn named_fields(&mut self, head: Span, depth: usize) -> Parsed<Vec<Field>> {
        let mut fields = Vec::new();
        loop {
            self.skip_trivia()?;
            if self.eat(')') {
                return Ok(fields);
            }
            if !self.peek().is_some_and(is_ident_start) {
                return Err(self.unclosed_or(head, '(', "expected a field name or ')'"));
            }
            let (name, name_span) = self.identifier();
            self.skip_trivia()?;
            if !self.eat(':') {
                return Err(self.error_here(&format!("expected ':' after field name '{name}'")));
            }
            let value = self.value(depth + 1)?;
            fields.push(Field {
                name,
                name_span,
                value,
            });
            self.separator(')', head)?;
        }
    }

    /// After an element: a `,`, or the closing delimiter, which is left for the caller's loop to eat.
    fn separator(&mut self, close: char, open: Span) -> Parsed<()> {
        self.skip_trivia()?;
        if self.eat(',') || self.peek() == Some(close) {
            return Ok(());
        }
        let opener = match close {
            ')' => '(',
            ']' => '[',
            _ => '{',
        };
        Err(self.unclosed_or(open, opener, &format!("expected ',' or '{close}'")))
    }

    /// At the end of the file, points at the delimiter that was never closed; otherwise reports what
    /// was expected here.
    fn unclosed_or(&self, open: Span, opener: char, expected: &str) -> SyntaxError {
        if self.peek().is_none() {
            syntax_error(open, format!("this '{opener}' is never closed"))
        } else {
            self.error_here(expected)
        }
    }

    fn list(&mut self, depth: usize) -> Parsed<Node> {
        let start = self.pos;
        self.bump();
        let head = Span::new(start, self.pos);
        let mut items = Vec::new();
        loop {
            self.skip_trivia()?;
            if self.eat(']') {
                break;
            }
            if self.peek().is_none() {
                return Err(self.unclosed_or(head, '[', ""));
            }
            items.push(self.value(depth + 1)?);
            self.separator(']', head)?;
        }
        Ok(Node {
            kind: NodeKind::List(items),
            span: Span::new(start, self.pos),
            head,
        })
    }

    fn map(&mut self, depth: usize) -> Parsed<Node> {
        let start = self.pos;
        self.bump();
        let head = Span::new(start, self.pos);
        let mut entries = Vec::new();
        loop {
            self.skip_trivia()?;
            if self.eat('}') {
                break;
            }
            if self.peek().is_none() {
                return Err(self.unclosed_or(head, '{', ""));
            }
            let key = self.value(depth + 1)?;
            self.skip_trivia()?;
            if !self.eat(':') {
                return Err(self.error_here("expected ':' after a map key"));
            }
            let value = self.value(depth + 1)?;
            entries.push(Entry { key, value });
            self.separator('}', head)?;
        }
        Ok(Node {
            kind: NodeKind::Map(entries),
            span: Span::new(start, self.pos),
            head,
        })
    }

    fn string(&mut self) -> Parsed<Node> {
        let start = self.pos;
        self.bump();
        let mut text = String::new();
        loop {
            match self.bump() {
                None => return Err(syntax_error(Span::new(start, start + 1), "unterminated string")),
                Some('"') => break,
                Some('\\') => text.push(self.escape()?),
                Some(c) => text.push(c),
            }
        }
        let span = Span::new(start, self.pos);
        Ok(Node {
            kind: NodeKind::Text(text),
            span,
            head: span,
        })
    }

    /// After a backslash in a string.
    fn escape(&mut self) -> Parsed<char> {
        let start = self.pos - 1;
        let escaped = match self.bump() {
            Some('n') => '\n',
            Some('t') => '\t',
            Some('r') => '\r',
            Some('0') => '\0',
            Some('\\') => '\\',
            Some('"') => '"',
            Some('\'') => '\'',
            Some('u') => return self.unicode_escape(start),
            other => {
                let end = self.pos;
                return Err(syntax_error(
                    Span::new(start, end),
                    format!(
                        "unknown escape '\\{}' in a string",
                        other.map(String::from).unwrap_or_default()
                    ),
                ));
            }
        };
        Ok(escaped)
    }

    /// `\u{1F600}` (Rust style) or `\u00e9` (four hex digits), after the `u`.
    fn unicode_escape(&mut self, start: usize) -> Parsed<char> {
        let braced = self.eat('{');
        let digits_start = self.pos;
        let max_digits = if braced { 6 } else { 4 };
        while self.pos - digits_start < max_digits && self.peek().is_some_and(|c| c.is_ascii_hexdigit()) {
            self.bump();
        }
        let digits = self.source.get(digits_start..self.pos).unwrap_or("");
        let closed = !braced || self.eat('}');
        let complete = if braced {
            !digits.is_empty()
        } else {
            digits.len() == 4
        };
        let decoded = u32::from_str_radix(digits, 16).ok().and_then(char::from_u32);
        match decoded {
            Some(c) if closed && complete => Ok(c),
            _ => Err(syntax_error(
                Span::new(start, self.pos),
                "invalid unicode escape: write \\u{...} with 1 to 6 hex digits of a valid character",
            )),
        }
    }

    /// An integer or a float, possibly negative; `-inf` too.
    fn number(&mut self) -> Parsed<Node> {
        let start = self.pos;
        let negative = self.eat('-');
        if negative && self.peek().is_some_and(is_ident_start) {
            let (name, _) = self.identifier();
            let span = Span::new(start, self.pos);
            if name == "inf" {
                let kind = NodeKind::Float("-inf".to_owned());
                return Ok(Node {
                    kind,
                    span,
                    head: span,
                });
            }
            return Err(syntax_error(
                span,
                format!("expected a number after '-', found '{name}'"),
            ));
        }
        if !self.skip_digits() {
            return Err(self.error_here("expected a digit after '-'"));
        }
        let mut is_float = false;
        if self.peek() == Some('.') && self.peek_second().is_some_and(|c| c.is_ascii_digit()) {
            is_float = true;
            self.bump();
            self.skip_digits();
        }
        if matches!(self.peek(), Some('e' | 'E')) {
            is_float = true;
            self.bump();
            if matches!(self.peek(), Some('+' | '-')) {
                self.bump();
            }
            if !self.skip_digits() {
                return Err(self.error_here("expected the exponent's digits"));
            }
        }
        // `12abc` or `1.2.3` is one bad token, not a number followed by something else.
        while self.peek().is_some_and(|c| is_ident_continue(c) || c == '.') {
            self.bump();
        }
        let span = Span::new(start, self.pos);
        let text = self.source.get(start..self.pos).unwrap_or("");
        let kind = if is_float {
            text.parse::<f64>()
                .map(|_| NodeKind::Float(text.to_owned()))
                .map_err(|_| syntax_error(span, format!("invalid number '{text}'")))?
        } else {
            match text.parse::<i128>() {
                Ok(value) => NodeKind::Integer(value),
                Err(_) if text.bytes().all(|b| b == b'-' || b.is_ascii_digit()) => {
                    return Err(syntax_error(span, format!("integer '{text}' is too large")));
                }
                Err(_) => return Err(syntax_error(span, format!("invalid number '{text}'"))),
            }
        };
        Ok(Node {
            kind,
            span,
            head: span,
        })
    }

    /// Skips ASCII digits; whether there was at least one.
    fn skip_digits(&mut self) -> bool {
        let start = self.pos;
        while self.peek().is_some_and(|c| c.is_ascii_digit()) {
            self.bump();
        }
        self.pos > start
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kind(source: &str) -> NodeKind {
        parse_document(source).map(|n| n.kind).unwrap()
    }

    fn error(source: &str) -> String {
        parse_document(source).unwrap_err().message
    }

    #[test]
    fn scalars() {
        assert_eq!(kind("true"), NodeKind::Bool(true));
        assert_eq!(kind(" -42 "), NodeKind::Integer(-42));
        assert_eq!(kind("2.5e-3"), NodeKind::Float("2.5e-3".to_owned()));
        assert_eq!(kind("1e20"), NodeKind::Float("1e20".to_owned()));
        assert_eq!(kind("-inf"), NodeKind::Float("-inf".to_owned()));
        assert_eq!(kind("Fifo"), NodeKind::Ident("Fifo".to_owned()));
        assert_eq!(
            kind(r#""a\"b\\c\n\u{e9}\u00e9""#),
            NodeKind::Text("a\"b\\c\né\u{e9}".to_owned())
        );
    }

    #[test]
    fn containers_comments_and_trailing_commas() {
        let source = "/* a /* nested */ comment */ Pack( // line\n name: \"core\", list: [1, 2,], map: {\"k\": Some(1),}, )";
        let node = parse_document(source).unwrap();
        let NodeKind::Struct { name, fields } = node.kind else {
            panic!("not a struct")
        };
        assert_eq!(name.as_deref(), Some("Pack"));
        let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["name", "list", "map"]);
        assert_eq!(node.head, Span::new(29, 33));
        assert_eq!(
            kind("()"),
            NodeKind::Struct {
                name: None,
                fields: vec![]
            }
        );
    }

    #[test]
    fn errors_say_what_was_found() {
        assert_eq!(error(""), "expected a value, found end of file");
        assert_eq!(error("[1 2]"), "expected ',' or ']', found '2'");
        assert_eq!(error("[1, 2"), "this '[' is never closed");
        assert_eq!(error("(a: 1"), "this '(' is never closed");
        assert_eq!(error("\"abc"), "unterminated string");
        assert_eq!(error("/* x"), "unterminated block comment");
        assert_eq!(error("12abc"), "invalid number '12abc'");
        assert_eq!(
            error("99999999999999999999999999999999999999999"),
            "integer '99999999999999999999999999999999999999999' is too large"
        );
        assert_eq!(
            error("1 2"),
            "expected the end of the file after the diagram, found '2'"
        );
        assert_eq!(error("\"\\q\""), "unknown escape '\\q' in a string");
        assert_eq!(error("é"), "expected a value, found 'é'");
        assert_eq!(error("-"), "expected a digit after '-', found end of file");
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_crash() {
        let deep = "[".repeat(100_000);
        let error = parse_document(&deep).unwrap_err();
        assert_eq!(error.code, DiagnosticCode::TooDeep);
        let fine = format!("{}{}", "[".repeat(MAX_DEPTH), "]".repeat(MAX_DEPTH));
        assert!(parse_document(&fine).is_ok());
    }
}

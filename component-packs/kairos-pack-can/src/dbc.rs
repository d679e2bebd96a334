//! DBC databases: frames to named, scaled signals and back. The `can-dbc` crate parses the file; the bit
//! layout is done here, as the DBC format defines it:
//!
//! - little-endian (Intel, `@1`) signals start at their least significant bit, numbered byte by byte
//!   from bit 0 of byte 0 upwards;
//! - big-endian (Motorola, `@0`) signals start at their most significant bit and run towards bit 0 of
//!   their byte, then on from bit 7 of the next byte;
//! - a signed (`-`) raw value is two's complement in its size; the physical value is
//!   `raw × factor + offset`.
//!
//! A multiplexed signal is decoded only when its multiplexor holds its value.

use std::collections::BTreeMap;
use std::path::Path;

use can_dbc::{ByteOrder, Dbc, MessageId, MultiplexIndicator, ValueType};
use kairos_sdk::CanFrame;

/// One signal of a message, as decoding needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalSpec {
    /// The signal's name.
    pub name: String,
    /// Its unit (may be empty).
    pub unit: String,
    start_bit: u32,
    size: u32,
    big_endian: bool,
    signed: bool,
    factor: f64,
    offset: f64,
    /// `Some(value)`: decoded only when the message's multiplexor holds it.
    multiplexed_on: Option<u64>,
    is_multiplexor: bool,
    /// Its value descriptions (`VAL_`): a raw value's meaning, in words.
    pub choices: BTreeMap<i64, String>,
}

/// One message of the database.
#[derive(Debug, Clone, PartialEq)]
pub struct MessageSpec {
    /// The message's name.
    pub name: String,
    /// Its signals, in the file's order.
    pub signals: Vec<SignalSpec>,
}

/// A decoded signal.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded<'a> {
    /// The signal's position among its message's signals.
    pub index: usize,
    /// The message's name.
    pub message: &'a str,
    /// The signal's name.
    pub signal: &'a str,
    /// The physical value.
    pub value: f64,
    /// Its unit.
    pub unit: &'a str,
    /// What its raw value means, where the database describes it (`VAL_`).
    pub choice: Option<&'a str>,
}

/// A database, by frame identifier.
#[derive(Debug, Clone, Default)]
pub struct Database {
    /// (identifier, extended) → message.
    pub messages: BTreeMap<(u32, bool), MessageSpec>,
}

/// Why a database cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct DbcFileError(pub String);

impl Database {
    /// Reads a DBC file.
    ///
    /// # Errors
    ///
    /// The file cannot be read or does not parse: the message names the file and, for a parse error,
    /// the line and column of the fault (`broken.dbc:18:18: ...`).
    pub fn open(path: &Path) -> Result<Self, DbcFileError> {
        let shown = path.display();
        let bytes = std::fs::read(path).map_err(|e| DbcFileError(format!("cannot read {shown}: {e}")))?;
        let text = String::from_utf8_lossy(&bytes);
        Self::parse(&text).map_err(|e| DbcFileError(format!("{shown}:{}", e.0)))
    }

    /// Reads a DBC file's text.
    ///
    /// # Errors
    ///
    /// It does not parse: the message starts `LINE:COLUMN:` at the fault (for a signal line, the first
    /// field that is wrong).
    pub fn parse(text: &str) -> Result<Self, DbcFileError> {
        let dbc = Dbc::try_from(text).map_err(|e| DbcFileError(located(&e, text)))?;
        let mut messages = BTreeMap::new();
        for message in &dbc.messages {
            let key = match message.id {
                MessageId::Standard(id) => (u32::from(id), false),
                MessageId::Extended(id) => (id, true),
            };
            let signals = message
                .signals
                .iter()
                .map(|signal| SignalSpec {
                    name: signal.name.clone(),
                    unit: signal.unit.clone(),
                    start_bit: u32::try_from(signal.start_bit).unwrap_or(u32::MAX),
                    size: u32::try_from(signal.size).unwrap_or(0).min(64),
                    big_endian: matches!(signal.byte_order, ByteOrder::BigEndian),
                    signed: matches!(signal.value_type, ValueType::Signed),
                    factor: signal.factor,
                    offset: signal.offset,
                    multiplexed_on: match signal.multiplexer_indicator {
                        MultiplexIndicator::MultiplexedSignal(value)
                        | MultiplexIndicator::MultiplexorAndMultiplexedSignal(value) => Some(value),
                        _ => None,
                    },
                    is_multiplexor: matches!(
                        signal.multiplexer_indicator,
                        MultiplexIndicator::Multiplexor
                            | MultiplexIndicator::MultiplexorAndMultiplexedSignal(_)
                    ),
                    choices: dbc
                        .value_descriptions_for_signal(message.id, &signal.name)
                        .unwrap_or_default()
                        .iter()
                        .map(|choice| (choice.id, choice.description.clone()))
                        .collect(),
                })
                .collect();
            messages.insert(
                key,
                MessageSpec {
                    name: message.name.clone(),
                    signals,
                },
            );
        }
        Ok(Database { messages })
    }

    /// The signals of `frame`, if its message is in the database; a signal whose bits lie beyond the
    /// frame's data is left out.
    pub fn decode(&self, frame: &CanFrame) -> Option<Vec<Decoded<'_>>> {
        let message = self.messages.get(&(frame.id, frame.extended))?;
        let data = frame.data();
        let switch = message
            .signals
            .iter()
            .find(|s| s.is_multiplexor)
            .and_then(|s| raw_of(s, data));
        let decoded = message
            .signals
            .iter()
            .enumerate()
            .filter(|(_, s)| s.multiplexed_on.is_none() || s.multiplexed_on == switch)
            .filter_map(|(index, signal)| {
                let raw = raw_of(signal, data)?;
                Some(Decoded {
                    index,
                    message: &message.name,
                    signal: &signal.name,
                    value: physical(signal, raw),
                    unit: &signal.unit,
                    choice: signal.choices.get(&integer(signal, raw)).map(String::as_str),
                })
            })
            .collect();
        Some(decoded)
    }

    /// A frame of message `message` carrying `values` (by signal name; missing ones are 0), or `None`
    /// when the message is unknown.
    pub fn encode(&self, message: &str, values: &BTreeMap<String, f64>) -> Option<CanFrame> {
        let ((id, extended), spec) = self.messages.iter().find(|(_, m)| m.name == message)?;
        let length = spec
            .signals
            .iter()
            .filter_map(|s| bits_of(s).max())
            .max()
            .map_or(0, |bit| bit as usize / 8 + 1)
            .min(64);
        let mut data = vec![0_u8; if length > 8 { 64 } else { 8 }];
        for signal in &spec.signals {
            let physical = values.get(&signal.name).copied().unwrap_or(0.0);
            let raw = ((physical - signal.offset) / signal.factor).round();
            #[allow(
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                reason = "masked to its size"
            )]
            let raw = if raw < 0.0 {
                (raw as i64) as u64
            } else {
                raw as u64
            };
            for (index, bit) in bits_of(signal).enumerate() {
                let from = if signal.big_endian {
                    signal.size as usize - 1 - index
                } else {
                    index
                };
                if let Some(byte) = data.get_mut(bit as usize / 8) {
                    if (raw >> from) & 1 == 1 {
                        *byte |= 1 << (bit % 8);
                    } else {
                        *byte &= !(1 << (bit % 8));
                    }
                }
            }
        }
        CanFrame::new(*id, *extended, &data)
    }
}

/// The data bit positions of `signal`, from its first (LSB for little-endian, MSB for big-endian).
fn bits_of(signal: &SignalSpec) -> impl Iterator<Item = u32> + '_ {
    let mut position = signal.start_bit;
    (0..signal.size).map(move |_| {
        let bit = position;
        position = if signal.big_endian {
            if bit.is_multiple_of(8) { bit + 15 } else { bit - 1 }
        } else {
            bit + 1
        };
        bit
    })
}

/// The raw value of `signal` in `data`, or `None` when its bits lie beyond the data.
fn raw_of(signal: &SignalSpec, data: &[u8]) -> Option<u64> {
    let mut raw = 0_u64;
    for (index, bit) in bits_of(signal).enumerate() {
        let value = u64::from((data.get(bit as usize / 8)? >> (bit % 8)) & 1);
        if signal.big_endian {
            raw = (raw << 1) | value;
        } else {
            raw |= value << index;
        }
    }
    Some(raw)
}

/// The raw value as the integer it stands for: two's complement in its size when signed.
#[allow(clippy::cast_possible_wrap, reason = "a signal of at most 64 bits")]
fn integer(signal: &SignalSpec, raw: u64) -> i64 {
    if signal.signed && signal.size > 0 && signal.size < 64 && raw >> (signal.size - 1) & 1 == 1 {
        (raw | (u64::MAX << signal.size)) as i64
    } else {
        raw as i64
    }
}

fn physical(signal: &SignalSpec, raw: u64) -> f64 {
    #[allow(
        clippy::cast_precision_loss,
        reason = "a signal of at most 64 bits, as exact as a double holds it"
    )]
    let number = if signal.signed {
        integer(signal, raw) as f64
    } else {
        raw as f64
    };
    number * signal.factor + signal.offset
}

/// A parse error as `LINE:COLUMN: what was expected`, with the line. The parser places a fault in a
/// signal line where the optional multiplexer indicator could have been (before its `:`), so a signal
/// line is read here field by field to find the first one that is wrong.
fn located(error: &can_dbc::DbcError, text: &str) -> String {
    let can_dbc::DbcError::Pest(error) = error else {
        return format!(" {error}");
    };
    let (line, column) = match error.line_col {
        pest::error::LineColLocation::Pos(at) | pest::error::LineColLocation::Span(at, _) => at,
    };
    let source = text.lines().nth(line.saturating_sub(1)).unwrap_or_default();
    let (column, what) = signal_fault(source).unwrap_or_else(|| (column, expected(&error.variant)));
    format!("{line}:{column}: {what}\n  {line} | {source}")
}

/// What the parser expected, in words.
fn expected<R: std::fmt::Debug>(variant: &pest::error::ErrorVariant<R>) -> String {
    match variant {
        pest::error::ErrorVariant::ParsingError { positives, .. } if !positives.is_empty() => {
            let names: Vec<String> = positives
                .iter()
                .map(|rule| format!("{rule:?}").replace('_', " "))
                .collect();
            format!("expected {}", names.join(" or "))
        }
        pest::error::ErrorVariant::ParsingError { .. } => "unexpected text".to_owned(),
        pest::error::ErrorVariant::CustomError { message } => message.clone(),
    }
}

/// In a signal line (` SG_ NAME [MUX] : START|SIZE@ORDER SIGN (FACTOR,OFFSET) [MIN|MAX] "UNIT" NODES`),
/// the 1-based column of the first field that is wrong and what it should be; `None` for another line,
/// or one whose fields are all right.
fn signal_fault(line: &str) -> Option<(usize, String)> {
    let mut scan = Scan { line, at: 0 };
    scan.spaces();
    if !scan.word("SG_") {
        return None;
    }
    let fields: [(&str, Field); 16] = [
        ("the signal's name", |s| s.spaces_then(Scan::identifier)),
        ("a multiplexer indicator (M, mN or mNM) or ':'", |s| {
            s.spaces();
            let mark = s.at;
            if s.identifier() && !s.line[mark..s.at].starts_with(['M', 'm']) {
                s.at = mark;
                return false;
            }
            true
        }),
        ("':'", |s| s.spaces_then(|s| s.word(":"))),
        ("the start bit, a whole number", |s| s.spaces_then(Scan::digits)),
        ("'|'", |s| s.word("|")),
        ("the size in bits, a whole number", |s| s.digits()),
        ("'@'", |s| s.word("@")),
        ("the byte order: 1 (Intel) or 0 (Motorola)", |s| {
            s.word("1") || s.word("0")
        }),
        ("the sign: + (unsigned) or - (signed)", |s| {
            s.word("+") || s.word("-")
        }),
        ("'(' and the factor, a number", |s| {
            s.spaces_then(|s| s.word("(") && s.number())
        }),
        ("',' and the offset, a number, then ')'", |s| {
            s.word(",") && s.number() && s.word(")")
        }),
        ("'[' and the minimum, a number", |s| {
            s.spaces_then(|s| s.word("[") && s.number())
        }),
        ("'|' and the maximum, a number, then ']'", |s| {
            s.word("|") && s.number() && s.word("]")
        }),
        ("the unit in double quotes", |s| s.spaces_then(Scan::quoted)),
        ("the receiving nodes", |s| s.spaces_then(Scan::identifier)),
        ("more receiving nodes after ','", |s| {
            while s.spaces_then(|s| s.word(",")) {
                if !s.spaces_then(Scan::identifier) {
                    return false;
                }
            }
            s.spaces();
            s.at == s.line.len()
        }),
    ];
    for (what, field) in fields {
        if !field(&mut scan) {
            // The column of the part of the field that is wrong (a part that fails reads nothing), past
            // the spaces before it: the ')' missing after an offset, not the ',' before it.
            scan.spaces();
            let start = scan.at;
            let found: String = line[start..]
                .chars()
                .take_while(|c| !c.is_whitespace())
                .take(16)
                .collect();
            let found = if found.is_empty() {
                "the end of the line".to_owned()
            } else {
                format!("{found:?}")
            };
            return Some((start + 1, format!("expected {what}, found {found}")));
        }
    }
    None
}

/// Reads one field of a line, past it; whether it is right.
type Field = fn(&mut Scan<'_>) -> bool;

/// A cursor over one line.
struct Scan<'a> {
    line: &'a str,
    at: usize,
}

impl Scan<'_> {
    fn rest(&self) -> &str {
        &self.line[self.at..]
    }

    fn spaces(&mut self) {
        self.at = self.line.len() - self.rest().trim_start().len();
    }

    fn spaces_then(&mut self, then: impl FnOnce(&mut Self) -> bool) -> bool {
        self.spaces();
        then(self)
    }

    fn word(&mut self, word: &str) -> bool {
        let found = self.rest().starts_with(word);
        if found {
            self.at += word.len();
        }
        found
    }

    /// Characters while `keep`; whether there was one.
    fn take(&mut self, keep: impl Fn(char) -> bool) -> bool {
        let length: usize = self
            .rest()
            .chars()
            .take_while(|c| keep(*c))
            .map(char::len_utf8)
            .sum();
        self.at += length;
        length > 0
    }

    fn identifier(&mut self) -> bool {
        self.rest()
            .starts_with(|c: char| c.is_ascii_alphabetic() || c == '_')
            && self.take(|c| c.is_ascii_alphanumeric() || c == '_')
    }

    /// Digits, then nothing that would make the field something else.
    fn digits(&mut self) -> bool {
        let start = self.at;
        let read = self.take(|c| c.is_ascii_digit())
            && !self.rest().starts_with(|c: char| c.is_ascii_alphanumeric());
        self.back_unless(read, start)
    }

    fn number(&mut self) -> bool {
        let start = self.at;
        self.take(|c| c.is_ascii_digit() || matches!(c, '+' | '-' | '.' | 'e' | 'E'));
        let read = self.line[start..self.at].parse::<f64>().is_ok();
        self.back_unless(read, start)
    }

    fn quoted(&mut self) -> bool {
        let start = self.at;
        if !self.word("\"") {
            return false;
        }
        let read = self.rest().find('"').map(|end| self.at += end + 1).is_some();
        self.back_unless(read, start)
    }

    /// Back to `start` unless the part was `read`: a wrong part is shown from its first character.
    fn back_unless(&mut self, read: bool, start: usize) -> bool {
        if !read {
            self.at = start;
        }
        read
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A database written from the DBC format: an engine message (Intel signals, one signed) and a
    /// Motorola one, and a multiplexed message.
    pub(crate) const DBC: &str = r#"VERSION ""

NS_ :

BS_:

BU_: ECU DASH

BO_ 256 Engine: 8 ECU
 SG_ Speed : 0|16@1+ (0.25,0) [0|16383.75] "rpm" DASH
 SG_ Temperature : 16|8@1- (1,-40) [-168|87] "degC" DASH
 SG_ Running : 24|1@1+ (1,0) [0|1] "" DASH

BO_ 512 Brake: 8 ECU
 SG_ Pressure : 7|12@0+ (0.1,0) [0|409.5] "bar" DASH

BO_ 2147484160 Diag: 8 ECU
 SG_ Page M : 0|8@1+ (1,0) [0|255] "" DASH
 SG_ Voltage m1 : 8|16@1+ (0.001,0) [0|65.535] "V" DASH
 SG_ Current m2 : 8|16@1- (0.01,0) [-327.68|327.67] "A" DASH
"#;

    fn values(decoded: &[Decoded<'_>]) -> Vec<(String, f64, String)> {
        decoded
            .iter()
            .map(|d| {
                (
                    d.signal.to_owned(),
                    (d.value * 1000.0).round() / 1000.0,
                    d.unit.to_owned(),
                )
            })
            .collect()
    }

    #[test]
    fn intel_motorola_signed_and_multiplexed_signals_decode_as_the_format_says() {
        let database = Database::parse(DBC).unwrap();
        // Speed 0x1F40 × 0.25 = 2000 rpm; temperature byte 0xEC = −20, − 40 = −60 °C; running.
        let engine = CanFrame::new(256, false, &[0x40, 0x1F, 0xEC, 0x01, 0, 0, 0, 0]).unwrap();
        assert_eq!(
            values(&database.decode(&engine).unwrap()),
            [
                ("Speed".to_owned(), 2000.0, "rpm".to_owned()),
                ("Temperature".to_owned(), -60.0, "degC".to_owned()),
                ("Running".to_owned(), 1.0, String::new()),
            ]
        );
        // Motorola, 12 bits from bit 7 of byte 0: 0xAB then the high nibble 0xC of byte 1 = 0xABC.
        let brake = CanFrame::new(512, false, &[0xAB, 0xC0, 0, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(
            values(&database.decode(&brake).unwrap()),
            [("Pressure".to_owned(), 274.8, "bar".to_owned())]
        );
        // Page 2 carries the current: −150 × 0.01 A.
        let raw = (-150_i16).to_le_bytes();
        let diag = CanFrame::new(0x200, true, &[2, raw[0], raw[1], 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(
            values(&database.decode(&diag).unwrap()),
            [
                ("Page".to_owned(), 2.0, String::new()),
                ("Current".to_owned(), -1.5, "A".to_owned())
            ]
        );
        assert!(
            database
                .decode(&CanFrame::new(0x7FF, false, &[0]).unwrap())
                .is_none()
        );
    }

    #[test]
    fn encoding_gives_back_what_decoding_reads() {
        let database = Database::parse(DBC).unwrap();
        for (message, signals) in [
            (
                "Engine",
                vec![("Speed", 1234.5), ("Temperature", -12.0), ("Running", 1.0)],
            ),
            ("Brake", vec![("Pressure", 101.7)]),
        ] {
            let wanted: BTreeMap<String, f64> = signals.iter().map(|(n, v)| ((*n).to_owned(), *v)).collect();
            let frame = database.encode(message, &wanted).unwrap();
            let decoded = database.decode(&frame).unwrap();
            for (name, value) in &wanted {
                let got = decoded.iter().find(|d| d.signal == name).unwrap().value;
                assert!((got - value).abs() < 1e-9, "{message}.{name}: {got} for {value}");
            }
        }
    }

    #[test]
    fn a_dbc_error_is_placed_at_the_field_that_is_wrong() {
        let error = |from: &str, to: &str| {
            let broken = DBC.replace(from, to);
            let message = Database::parse(&broken).unwrap_err().to_string();
            message.lines().next().unwrap_or_default().to_owned()
        };
        assert_eq!(
            error("SG_ Speed : 0|16@1+", "SG_ Speed : 0|16@3+"),
            "10:19: expected the byte order: 1 (Intel) or 0 (Motorola), found \"3+\""
        );
        assert_eq!(
            error("SG_ Speed : 0|16@1+", "SG_ Speed : 0|1x@1+"),
            "10:16: expected the size in bits, a whole number, found \"1x@1+\""
        );
        assert_eq!(
            error("\"rpm\" DASH", "rpm DASH"),
            "10:44: expected the unit in double quotes, found \"rpm\""
        );
        assert_eq!(
            error("(0.25,0) [0|16383.75]", "(0.25;0) [0|16383.75]"),
            "10:27: expected ',' and the offset, a number, then ')', found \";0)\""
        );
        // A part missing inside a field: placed where it should be.
        assert_eq!(
            error("(0.25,0) [0|16383.75]", "(0.25,0 [0|16383.75]"),
            "10:30: expected ',' and the offset, a number, then ')', found \"[0|16383.75]\""
        );
        assert_eq!(
            error("(0.25,0) [0|16383.75]", "(0.25,0x) [0|16383.75]"),
            "10:29: expected ',' and the offset, a number, then ')', found \"x)\""
        );
        // Elsewhere, where the parser says.
        assert_eq!(
            error("BO_ 512 Brake: 8 ECU", "BO_ x512 Brake: 8 ECU"),
            "14:5: expected message id"
        );
    }
}

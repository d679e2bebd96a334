//! The candump log format (can-utils' `candump -l`, `canplayer`): one frame per line,
//! `(seconds.micros) interface ID#DATA`. A classic frame's data is up to 8 hex bytes; `ID##F` starts a
//! CAN FD frame with the flags nibble F; `ID#R` is a remote request, `ID#R5` one asking for 5 bytes. An identifier of 3 hex digits is
//! standard, of 8 extended; one with bit 29 set (`CAN_ERR_FLAG`) is an error frame.

use std::fmt::Write as _;

use kairos_sdk::CanFrame;

/// Bit 29 of an identifier marks an error frame.
const ERROR_FLAG: u32 = 0x2000_0000;
/// The identifier bits of an extended frame.
const EXTENDED_MASK: u32 = 0x1FFF_FFFF;

/// One line of a log.
#[derive(Debug, Clone, PartialEq)]
pub enum Logged {
    /// A data frame (or a remote request, with no data).
    Frame {
        /// Seconds since the UNIX epoch, as logged.
        time_s: f64,
        /// The interface it was logged on.
        interface: String,
        /// The frame.
        frame: CanFrame,
    },
    /// An error frame: counted, not passed on.
    Error {
        /// Seconds since the UNIX epoch.
        time_s: f64,
    },
}

/// Why a line is not a logged frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct LineError(pub String);

fn bad(what: impl Into<String>) -> LineError {
    LineError(what.into())
}

/// Parses one line.
///
/// # Errors
///
/// The line does not have the candump log's shape; the message says what is wrong.
pub fn parse(line: &str) -> Result<Logged, LineError> {
    let line = line.trim();
    let (time, rest) = line
        .strip_prefix('(')
        .and_then(|l| l.split_once(')'))
        .ok_or_else(|| bad("expected `(seconds.micros) interface ID#DATA`"))?;
    let time_s: f64 = time
        .parse()
        .map_err(|_| bad(format!("the time {time:?} is not a number")))?;
    let mut fields = rest.split_whitespace();
    let interface = fields
        .next()
        .ok_or_else(|| bad("no interface after the time"))?
        .to_owned();
    let body = fields.next().ok_or_else(|| bad("no frame after the interface"))?;
    let (id_text, data_text) = body
        .split_once('#')
        .ok_or_else(|| bad(format!("{body:?} has no '#'")))?;
    if id_text.is_empty() || id_text.len() > 8 || !id_text.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(bad(format!(
            "the identifier {id_text:?} is not 3 or 8 hex digits"
        )));
    }
    let raw_id = u32::from_str_radix(id_text, 16).map_err(|_| bad("identifier"))?;
    if raw_id & ERROR_FLAG != 0 {
        return Ok(Logged::Error { time_s });
    }
    let extended = id_text.len() > 3;
    let id = if extended { raw_id & EXTENDED_MASK } else { raw_id };
    if !extended && id > 0x7FF {
        return Err(bad(format!("standard identifier {id_text} is over 7FF")));
    }
    let (fd, hex) = match data_text.strip_prefix('#') {
        Some(fd) => {
            let mut chars = fd.chars();
            chars
                .next()
                .filter(char::is_ascii_hexdigit)
                .ok_or_else(|| bad("a CAN FD frame needs its flags digit after '##'"))?;
            (true, chars.as_str())
        }
        None => match data_text.strip_prefix('R') {
            Some(length) => {
                let length = match length {
                    "" => 0,
                    digit => digit
                        .parse::<u8>()
                        .ok()
                        .filter(|length| *length <= 8)
                        .ok_or_else(|| {
                            bad(format!("a remote request asks for 0 to 8 bytes, not {digit:?}"))
                        })?,
                };
                let frame =
                    CanFrame::remote_request(id, extended, length).ok_or_else(|| bad("remote request"))?;
                return Ok(Logged::Frame {
                    time_s,
                    interface,
                    frame,
                });
            }
            None => (false, data_text),
        },
    };
    if hex.len() % 2 != 0 || !hex.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(bad(format!("the data {hex:?} is not whole hex bytes")));
    }
    let data: Vec<u8> = (0..hex.len())
        .step_by(2)
        .filter_map(|at| u8::from_str_radix(hex.get(at..at + 2)?, 16).ok())
        .collect();
    if (!fd && data.len() > 8) || data.len() > 64 {
        return Err(bad(format!(
            "{} data bytes, more than a {} frame holds",
            data.len(),
            if fd { "CAN FD" } else { "classic" }
        )));
    }
    let mut frame = CanFrame::new(id, extended, &data).ok_or_else(|| bad("too many data bytes"))?;
    frame.fd = fd;
    Ok(Logged::Frame {
        time_s,
        interface,
        frame,
    })
}

/// `frame` as a log line at `time_ns` on `interface`.
pub fn format(frame: &CanFrame, time_ns: i64, interface: &str) -> String {
    let seconds = time_ns.div_euclid(1_000_000_000);
    let micros = time_ns.rem_euclid(1_000_000_000) / 1000;
    let id = if frame.extended {
        format!("{:08X}", frame.id)
    } else {
        format!("{:03X}", frame.id)
    };
    if frame.remote {
        let length = if frame.length() == 0 {
            String::new()
        } else {
            frame.length().to_string()
        };
        return format!("({seconds}.{micros:06}) {interface} {id}#R{length}");
    }
    let mut data = String::with_capacity(frame.data().len() * 2);
    for byte in frame.data() {
        let _ = write!(data, "{byte:02X}");
    }
    let separator = if frame.fd { "##0" } else { "#" };
    format!("({seconds}.{micros:06}) {interface} {id}{separator}{data}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classic_extended_fd_remote_and_error_frames_parse_and_format_back() {
        let Logged::Frame {
            time_s,
            interface,
            frame,
        } = parse("(1436509052.249713) vcan0 044#2A366C2BBA").unwrap()
        else {
            panic!()
        };
        assert!((time_s - 1_436_509_052.249_713).abs() < 1e-6);
        assert_eq!(interface, "vcan0");
        assert_eq!((frame.id, frame.extended, frame.fd), (0x44, false, false));
        assert_eq!(frame.data(), [0x2A, 0x36, 0x6C, 0x2B, 0xBA]);
        assert_eq!(
            format(&frame, 1_436_509_052_249_713_000, "vcan0"),
            "(1436509052.249713) vcan0 044#2A366C2BBA"
        );

        let Logged::Frame { frame, .. } = parse("(1.000000) can1 1ABCDEF0#11").unwrap() else {
            panic!()
        };
        assert_eq!((frame.id, frame.extended), (0x1ABC_DEF0, true));
        let Logged::Frame { frame, .. } = parse("(1.0) can0 123##1001122334455667788").unwrap() else {
            panic!()
        };
        assert!(frame.fd);
        assert_eq!(frame.data().len(), 9);
        // Remote requests, with and without the length they ask for, written back as they were.
        for line in ["(1.000000) can0 123#R", "(1.000000) can0 1ABCDEF0#R8"] {
            let Logged::Frame { frame, .. } = parse(line).unwrap() else {
                panic!()
            };
            assert!(frame.remote && frame.data().is_empty(), "{line}");
            assert_eq!(format(&frame, 1_000_000_000, "can0"), line);
        }
        assert!(matches!(
            parse("(2.5) can0 20000080#0000000000000000").unwrap(),
            Logged::Error { .. }
        ));
    }

    #[test]
    fn malformed_lines_say_what_is_wrong() {
        for (line, says) in [
            ("1436509052.249713 vcan0 044#2A", "expected"),
            ("(soon) vcan0 044#2A", "not a number"),
            ("(1.0) vcan0", "no frame"),
            ("(1.0) vcan0 044-2A", "no '#'"),
            ("(1.0) vcan0 0G4#2A", "hex digits"),
            ("(1.0) vcan0 044#2A3", "whole hex bytes"),
            ("(1.0) vcan0 044#000000000000000000", "more than a classic"),
            ("(1.0) vcan0 844#00", "over 7FF"),
            ("(1.0) vcan0 123#R9", "0 to 8 bytes"),
        ] {
            let error = parse(line).unwrap_err().to_string();
            assert!(error.contains(says), "{line}: {error}");
        }
    }
}

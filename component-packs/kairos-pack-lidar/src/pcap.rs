//! UDP datagrams from a pcap capture (the classic format `tcpdump -w` writes): Ethernet (with or without
//! a VLAN tag), IPv4, UDP. Records of any other kind are passed over; a record that claims more bytes than
//! the file holds ends the capture, reported.

use std::fs::File;
use std::io::{BufReader, Read as _};
use std::path::Path;

/// Why a capture cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PcapError {
    /// Not a pcap file.
    #[error("{0} is not a pcap capture (its first bytes are not a pcap magic number)")]
    NotPcap(String),
    /// Not Ethernet.
    #[error("{path} captures link type {link}, not Ethernet (1)")]
    NotEthernet {
        /// The file.
        path: String,
        /// Its link type.
        link: u32,
    },
    /// It cannot be read.
    #[error("cannot read {0}")]
    Io(String),
}

/// One UDP datagram of a capture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Datagram {
    /// When it was captured, ns since the UNIX epoch.
    pub time_ns: i64,
    /// Its destination port.
    pub port: u16,
    /// Its payload.
    pub payload: Vec<u8>,
}

/// The longest record accepted: a jumbo frame with margin.
const LONGEST_RECORD: usize = 1 << 18;

/// Reads a capture's UDP datagrams in order.
#[derive(Debug)]
pub struct Capture {
    reader: BufReader<File>,
    big_endian: bool,
    nanoseconds: bool,
    /// Why reading stopped before the end, if it did.
    pub cut_short: Option<String>,
}

impl Capture {
    /// Opens `path` and reads its header.
    ///
    /// # Errors
    ///
    /// The file cannot be read, is not a pcap capture, or does not capture Ethernet.
    pub fn open(path: &Path) -> Result<Self, PcapError> {
        let shown = path.display().to_string();
        let file = File::open(path).map_err(|e| PcapError::Io(format!("{shown}: {e}")))?;
        let mut reader = BufReader::new(file);
        let mut header = [0_u8; 24];
        reader
            .read_exact(&mut header)
            .map_err(|_| PcapError::NotPcap(shown.clone()))?;
        let magic = [header[0], header[1], header[2], header[3]];
        let (big_endian, nanoseconds) = match magic {
            [0xd4, 0xc3, 0xb2, 0xa1] => (false, false),
            [0xa1, 0xb2, 0xc3, 0xd4] => (true, false),
            [0x4d, 0x3c, 0xb2, 0xa1] => (false, true),
            [0xa1, 0xb2, 0x3c, 0x4d] => (true, true),
            _ => return Err(PcapError::NotPcap(shown)),
        };
        let capture = Capture {
            reader,
            big_endian,
            nanoseconds,
            cut_short: None,
        };
        let link = capture.u32_of([header[20], header[21], header[22], header[23]]);
        if link != 1 {
            return Err(PcapError::NotEthernet { path: shown, link });
        }
        Ok(capture)
    }

    fn u32_of(&self, bytes: [u8; 4]) -> u32 {
        if self.big_endian {
            u32::from_be_bytes(bytes)
        } else {
            u32::from_le_bytes(bytes)
        }
    }

    /// The next UDP datagram, or `None` at the end (see [`Capture::cut_short`]).
    pub fn next_datagram(&mut self) -> Option<Datagram> {
        loop {
            let mut header = [0_u8; 16];
            if self.reader.read_exact(&mut header).is_err() {
                return None;
            }
            let word = |at: usize| self.u32_of([header[at], header[at + 1], header[at + 2], header[at + 3]]);
            let (seconds, fraction, length) = (word(0), word(4), word(8) as usize);
            if length > LONGEST_RECORD {
                self.cut_short = Some(format!("a record claims {length} bytes: the capture is damaged"));
                return None;
            }
            let mut frame = vec![0_u8; length];
            if self.reader.read_exact(&mut frame).is_err() {
                self.cut_short = Some("the capture ends in the middle of a record (truncated)".to_owned());
                return None;
            }
            let fraction_ns = if self.nanoseconds {
                i64::from(fraction)
            } else {
                i64::from(fraction) * 1000
            };
            if let Some((port, payload)) = udp_of(&frame) {
                return Some(Datagram {
                    time_ns: i64::from(seconds) * 1_000_000_000 + fraction_ns,
                    port,
                    payload: payload.to_vec(),
                });
            }
        }
    }
}

/// The destination port and payload of an Ethernet frame carrying IPv4 UDP.
fn udp_of(frame: &[u8]) -> Option<(u16, &[u8])> {
    let mut at = 12;
    let mut ether_type = u16::from_be_bytes([*frame.get(at)?, *frame.get(at + 1)?]);
    if ether_type == 0x8100 {
        at += 4;
        ether_type = u16::from_be_bytes([*frame.get(at)?, *frame.get(at + 1)?]);
    }
    if ether_type != 0x0800 {
        return None;
    }
    let ip = frame.get(at + 2..)?;
    let header_length = usize::from(ip.first()? & 0x0f) * 4;
    if ip.first()? >> 4 != 4 || header_length < 20 || *ip.get(9)? != 17 {
        return None;
    }
    let total = usize::from(u16::from_be_bytes([*ip.get(2)?, *ip.get(3)?]));
    let udp = ip.get(header_length..total.min(ip.len()))?;
    let port = u16::from_be_bytes([*udp.get(2)?, *udp.get(3)?]);
    let udp_length = usize::from(u16::from_be_bytes([*udp.get(4)?, *udp.get(5)?]));
    let payload = udp.get(8..udp_length.max(8).min(udp.len()))?;
    Some((port, payload))
}

/// `payload` as one Ethernet/IPv4/UDP frame to `port`, for tests and tools that write captures.
pub fn frame_of(port: u16, payload: &[u8]) -> Vec<u8> {
    let mut frame = vec![0_u8; 12];
    frame.extend_from_slice(&0x0800_u16.to_be_bytes());
    let total = u16::try_from(20 + 8 + payload.len()).unwrap_or(u16::MAX);
    frame.extend_from_slice(&[0x45, 0]);
    frame.extend_from_slice(&total.to_be_bytes());
    frame.extend_from_slice(&[0, 0, 0x40, 0, 64, 17, 0, 0, 192, 168, 1, 201, 255, 255, 255, 255]);
    frame.extend_from_slice(&2368_u16.to_be_bytes());
    frame.extend_from_slice(&port.to_be_bytes());
    frame.extend_from_slice(&u16::try_from(8 + payload.len()).unwrap_or(u16::MAX).to_be_bytes());
    frame.extend_from_slice(&[0, 0]);
    frame.extend_from_slice(payload);
    frame
}

/// A whole capture (microsecond timestamps, little-endian) of `frames` at their times in ns.
pub fn capture_of(frames: &[(i64, Vec<u8>)]) -> Vec<u8> {
    let mut bytes = vec![
        0xd4, 0xc3, 0xb2, 0xa1, 2, 0, 4, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 0, 0, 1, 0, 0, 0,
    ];
    for (time_ns, frame) in frames {
        let seconds = u32::try_from(time_ns / 1_000_000_000).unwrap_or(0);
        let micros = u32::try_from((time_ns % 1_000_000_000) / 1000).unwrap_or(0);
        let length = u32::try_from(frame.len()).unwrap_or(0);
        for word in [seconds, micros, length, length] {
            bytes.extend_from_slice(&word.to_le_bytes());
        }
        bytes.extend_from_slice(frame);
    }
    bytes
}

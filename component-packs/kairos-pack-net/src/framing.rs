//! How messages are cut from a byte stream and put into one: raw (what each read gives), lines (up to
//! `\n`, a `\r` before it dropped) or length-prefixed (a 4-byte big-endian length, then that many bytes).

use kairos_sdk::descriptor::Property;

/// The longest message accepted in lines or length-prefixed framing: longer ones are refused (the
/// connection is closed, since what follows cannot be trusted to start a message).
pub const LONGEST_MESSAGE: usize = 64 << 20;

/// A framing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Framing {
    /// Each read as it comes.
    Raw,
    /// Text lines.
    Lines,
    /// A u32 big-endian length, then the message.
    LengthPrefixed,
}

impl Framing {
    /// The framing of a property value.
    pub fn of(name: &str) -> Self {
        match name {
            "lines" => Framing::Lines,
            "length_prefixed" => Framing::LengthPrefixed,
            _ => Framing::Raw,
        }
    }

    /// The property that chooses it.
    pub fn property() -> Property {
        Property::choice("framing", &["raw", "lines", "length_prefixed"], "raw").doc(
            "raw: each read as it comes; lines: up to each line ending; length_prefixed: a 4-byte \
             big-endian length, then the message",
        )
    }

    /// `message` framed for sending (a line gets `\n` unless it has one).
    pub fn frame(self, message: &[u8]) -> Vec<u8> {
        match self {
            Framing::Raw => message.to_vec(),
            Framing::Lines => {
                let mut framed = message.to_vec();
                if framed.last() != Some(&b'\n') {
                    framed.push(b'\n');
                }
                framed
            }
            Framing::LengthPrefixed => {
                let mut framed = length_prefix(message.len()).to_vec();
                framed.extend_from_slice(message);
                framed
            }
        }
    }
}

/// The 4-byte big-endian length that goes before a message of `length` bytes in length-prefixed framing.
pub fn length_prefix(length: usize) -> [u8; 4] {
    u32::try_from(length).unwrap_or(u32::MAX).to_be_bytes()
}

/// Why a stream cannot be read on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TooLong(pub usize);

/// Cuts messages from the bytes of one connection.
#[derive(Debug)]
pub struct Deframer {
    framing: Framing,
    pending: Vec<u8>,
}

impl Deframer {
    /// A deframer for `framing`.
    pub fn new(framing: Framing) -> Self {
        Deframer {
            framing,
            pending: Vec::new(),
        }
    }

    /// Bytes held for a message not complete yet (cut off if the connection ends now).
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Feeds `bytes`, calling `on_message` with each complete message.
    ///
    /// # Errors
    ///
    /// A message longer than [`LONGEST_MESSAGE`]: the stream cannot be followed further.
    pub fn feed(&mut self, bytes: &[u8], mut on_message: impl FnMut(&[u8])) -> Result<(), TooLong> {
        match self.framing {
            Framing::Raw => {
                if !bytes.is_empty() {
                    on_message(bytes);
                }
                Ok(())
            }
            Framing::Lines => {
                for &byte in bytes {
                    if byte == b'\n' {
                        let line = self.pending.strip_suffix(b"\r").unwrap_or(&self.pending);
                        on_message(line);
                        self.pending.clear();
                    } else if self.pending.len() >= LONGEST_MESSAGE {
                        return Err(TooLong(self.pending.len()));
                    } else {
                        self.pending.push(byte);
                    }
                }
                Ok(())
            }
            Framing::LengthPrefixed => {
                self.pending.extend_from_slice(bytes);
                loop {
                    let Some(head) = self.pending.first_chunk::<4>() else {
                        return Ok(());
                    };
                    let length = u32::from_be_bytes(*head) as usize;
                    if length > LONGEST_MESSAGE {
                        return Err(TooLong(length));
                    }
                    let Some(message) = self.pending.get(4..4 + length) else {
                        return Ok(());
                    };
                    on_message(message);
                    self.pending.drain(..4 + length);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_framing_gives_back_what_was_framed_whatever_the_reads() {
        for framing in [Framing::Lines, Framing::LengthPrefixed] {
            let messages: [&[u8]; 3] = [b"one", b"", b"three and more"];
            let stream: Vec<u8> = messages.iter().flat_map(|m| framing.frame(m)).collect();
            for cut in [1, 2, 3, 5, 7, stream.len()] {
                let mut deframer = Deframer::new(framing);
                let mut got = Vec::new();
                for piece in stream.chunks(cut) {
                    deframer.feed(piece, |m| got.push(m.to_vec())).unwrap();
                }
                assert_eq!(
                    got,
                    messages.map(<[u8]>::to_vec),
                    "{framing:?} in pieces of {cut}"
                );
                assert_eq!(deframer.pending(), 0);
            }
        }
    }

    #[test]
    fn an_absurd_length_is_refused_and_a_cut_message_stays_pending() {
        let mut deframer = Deframer::new(Framing::LengthPrefixed);
        assert_eq!(
            deframer.feed(&[0xff, 0xff, 0xff, 0xff], |_| {}),
            Err(TooLong(0xffff_ffff))
        );
        let mut deframer = Deframer::new(Framing::LengthPrefixed);
        deframer
            .feed(&[0, 0, 0, 9, b'a', b'b'], |_| panic!("not complete"))
            .unwrap();
        assert_eq!(deframer.pending(), 6);
    }
}

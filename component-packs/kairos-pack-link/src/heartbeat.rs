//! A reliable sender's heartbeat: while Zenoh says the receiver matches, the sender asks it every
//! [`PERIOD`] what it received. Zenoh's matching alone is not enough: after a reconnection that flaps
//! once more, a link was seen to stay matched while nothing reached the far end, for minutes, and
//! nobody was told. Only the far end can say what arrived.
//!
//! Two faults are told apart:
//! - **unanswered**: [`UNANSWERED_CUT`] questions in a row get no answer. The path is dead whatever
//!   Zenoh says; the sender treats the link as cut (its ride-out asks again and sends again what the
//!   receiver missed once it answers).
//! - **silent**: the receiver answers, but has received nothing new over a whole period while samples
//!   were on their way. Its consumer may be stalled (a link that never skips then holds its producer, as
//!   it should) or the data path is broken; either way the user is told, and nothing is sent again (what
//!   is queued would arrive twice).

use std::time::{Duration, Instant};

/// How often a matched receiver is asked what it received.
pub const PERIOD: Duration = Duration::from_secs(1);

/// Questions unanswered in a row after which a matched link counts as cut.
pub const UNANSWERED_CUT: u32 = 2;

/// How long a receiver may receive nothing while samples are on their way before the user is told.
pub const SILENT_SAID: Duration = Duration::from_secs(2);

/// What the heartbeat has learnt of the far end.
#[derive(Debug, Default)]
pub struct Heartbeat {
    /// When the last question went.
    asked: Option<Instant>,
    /// The last answer: how many samples the receiver had received by then (its newest + 1), and how
    /// many had been sent when that question went.
    last: Option<(u64, u64)>,
    /// Questions unanswered in a row, and how many samples had been sent when the first of them went.
    unanswered: u32,
    unanswered_from: u64,
    /// Since when the receiver has received nothing while samples were on their way.
    silent_since: Option<Instant>,
    /// Whether that silence has been said.
    silence_said: bool,
}

/// News of the receiver's silence, to be said.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Silence {
    /// It has received nothing this long, past [`SILENT_SAID`].
    Began(Duration),
    /// It receives again.
    Ended,
}

impl Heartbeat {
    /// Whether a question is due at `now`.
    pub fn due(&self, now: Instant) -> bool {
        self.asked.is_none_or(|at| now.duration_since(at) >= PERIOD)
    }

    /// A question went at `now`.
    pub fn asked(&mut self, now: Instant) {
        self.asked = Some(now);
    }

    /// The receiver said it had received `received` samples (its newest + 1) in answer to a question
    /// that went when `sent_then` had been sent.
    pub fn answered(&mut self, received: u64, sent_then: u64, now: Instant) {
        self.unanswered = 0;
        let caught_up = received >= sent_then;
        // Any change is news: fewer than before is a receiver that started afresh.
        let progressed = self.last.is_none_or(|(before, _)| received != before);
        // Silent only when something was already on its way at the previous question: what was put
        // since may simply not have arrived yet.
        let was_waiting = self
            .last
            .is_some_and(|(before, sent_before)| before < sent_before);
        if caught_up || progressed || !was_waiting {
            self.silent_since = None;
        } else {
            self.silent_since.get_or_insert(now);
        }
        self.last = Some((received, sent_then));
    }

    /// A question that went when `sent_then` had been sent got no answer.
    pub fn unanswered(&mut self, sent_then: u64) {
        if self.unanswered == 0 {
            self.unanswered_from = sent_then;
        }
        self.unanswered += 1;
    }

    /// The receiver answered after a cut (the ride-out's question): the heartbeat starts afresh.
    pub fn heard(&mut self) {
        *self = Heartbeat {
            asked: self.asked,
            silence_said: self.silence_said,
            ..Heartbeat::default()
        };
    }

    /// Whether the receiver answers (fewer than [`UNANSWERED_CUT`] questions in a row went unanswered).
    pub fn answering(&self) -> bool {
        self.unanswered < UNANSWERED_CUT
    }

    /// How many samples had been sent when the receiver stopped answering.
    pub fn unanswered_from(&self) -> u64 {
        self.unanswered_from
    }

    /// News of the receiver's silence since it was last asked for, if any.
    pub fn silence_news(&mut self, now: Instant) -> Option<Silence> {
        match self.silent_for(now) {
            Some(silent) if silent >= SILENT_SAID && !self.silence_said => {
                self.silence_said = true;
                Some(Silence::Began(silent))
            }
            None if self.silence_said => {
                self.silence_said = false;
                Some(Silence::Ended)
            }
            _ => None,
        }
    }

    /// How long the receiver has received nothing while samples were on their way (counted from the
    /// question before the one that found it, a period earlier), if it has.
    pub fn silent_for(&self, now: Instant) -> Option<Duration> {
        self.silent_since.map(|since| now.duration_since(since) + PERIOD)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(start: Instant, seconds: u64) -> Instant {
        start + Duration::from_secs(seconds)
    }

    #[test]
    fn a_receiver_that_keeps_up_or_progresses_is_never_silent() {
        let start = Instant::now();
        let mut beat = Heartbeat::default();
        beat.answered(10, 12, at(start, 1));
        beat.answered(20, 25, at(start, 2));
        beat.answered(25, 25, at(start, 3));
        // Nothing new, but nothing was on its way either.
        beat.answered(25, 25, at(start, 4));
        beat.answered(25, 30, at(start, 5));
        assert_eq!(beat.silent_for(at(start, 5)), None);
        assert!(beat.answering());
    }

    #[test]
    fn a_receiver_that_receives_nothing_while_samples_are_on_their_way_is_silent_until_it_does() {
        let start = Instant::now();
        let mut beat = Heartbeat::default();
        beat.answered(10, 12, at(start, 1));
        beat.answered(10, 40, at(start, 2));
        assert_eq!(beat.silent_for(at(start, 2)), Some(PERIOD));
        beat.answered(10, 70, at(start, 3));
        assert_eq!(beat.silent_for(at(start, 3)), Some(PERIOD * 2));
        assert_eq!(beat.silence_news(at(start, 3)), Some(Silence::Began(PERIOD * 2)));
        assert_eq!(beat.silence_news(at(start, 3)), None, "said once");
        beat.answered(11, 100, at(start, 4));
        assert_eq!(beat.silent_for(at(start, 4)), None);
        assert_eq!(beat.silence_news(at(start, 4)), Some(Silence::Ended));
    }

    #[test]
    fn a_receiver_that_stops_answering_counts_as_cut_from_the_second_question_and_answers_again() {
        let start = Instant::now();
        let mut beat = Heartbeat::default();
        assert!(beat.due(start));
        beat.asked(start);
        assert!(!beat.due(start + PERIOD / 2));
        assert!(beat.due(start + PERIOD));
        beat.answered(5, 5, at(start, 1));
        beat.unanswered(30);
        assert!(beat.answering(), "one unanswered question may be a flap");
        beat.unanswered(60);
        assert!(!beat.answering());
        assert_eq!(beat.unanswered_from(), 30);
        beat.heard();
        assert!(beat.answering());
        assert_eq!(beat.silent_for(at(start, 5)), None);
    }
}

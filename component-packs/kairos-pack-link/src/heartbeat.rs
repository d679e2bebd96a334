//! A reliable sender's heartbeat: while Zenoh says the receiver matches, the sender asks it every
//! [`PERIOD`] what it received. Zenoh's matching alone is not enough: after a reconnection that flaps
//! once more, a link was seen to stay matched while nothing reached the far end, for minutes, and
//! nobody was told. Only the far end can say what arrived.
//!
//! Two findings are told apart, and said; neither changes what the link sends:
//! - **unanswered**: [`UNANSWERED_SAID`] questions in a row get no answer. Either the path is dead
//!   whatever Zenoh says, or the receiver's host is held up delivering what came before the question (a
//!   consumer that never skips, slower than its producer: the question waits behind the samples). From
//!   here the two look the same, so the link is not treated as cut: holding samples back would take the
//!   back-pressure off a slow consumer's producer and lose what it must not skip.
//! - **silent**: the receiver answers, but has received nothing new over a whole period while samples
//!   were on their way.
//!
//! The coordinator, which sees both ends' statuses, says which (`kairos_coordinator::watch`).

use std::time::{Duration, Instant};

/// How often a matched receiver is asked what it received.
pub const PERIOD: Duration = Duration::from_secs(1);

/// Questions unanswered in a row after which the receiver counts as not answering.
pub const UNANSWERED_SAID: u32 = 2;

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
    /// Questions unanswered in a row.
    unanswered: u32,
    /// Since when the receiver has received nothing while samples were on their way.
    silent_since: Option<Instant>,
    /// Whether that silence, and the receiver's not answering, have been said.
    silence_said: bool,
    unanswered_said: bool,
}

/// News of the receiver, to be said.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum News {
    /// It has received nothing this long, past [`SILENT_SAID`].
    Silent(Duration),
    /// It receives again.
    Receiving,
    /// It stopped answering.
    Unanswering,
    /// It answers again.
    Answering,
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

    /// A question got no answer.
    pub fn unanswered(&mut self) {
        self.unanswered += 1;
    }

    /// Whether the receiver answers (fewer than [`UNANSWERED_SAID`] questions in a row went unanswered).
    pub fn answering(&self) -> bool {
        self.unanswered < UNANSWERED_SAID
    }

    /// News of the receiver since it was last asked for, if any.
    pub fn news(&mut self, now: Instant) -> Option<News> {
        if self.answering() == self.unanswered_said {
            self.unanswered_said = !self.answering();
            return Some(if self.unanswered_said {
                News::Unanswering
            } else {
                News::Answering
            });
        }
        match self.silent_for(now) {
            Some(silent) if silent >= SILENT_SAID && !self.silence_said => {
                self.silence_said = true;
                Some(News::Silent(silent))
            }
            None if self.silence_said => {
                self.silence_said = false;
                Some(News::Receiving)
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
        assert_eq!(beat.news(at(start, 3)), Some(News::Silent(PERIOD * 2)));
        assert_eq!(beat.news(at(start, 3)), None, "said once");
        beat.answered(11, 100, at(start, 4));
        assert_eq!(beat.silent_for(at(start, 4)), None);
        assert_eq!(beat.news(at(start, 4)), Some(News::Receiving));
    }

    #[test]
    fn a_receiver_that_stops_answering_is_said_from_the_second_question_and_again_when_it_answers() {
        let start = Instant::now();
        let mut beat = Heartbeat::default();
        assert!(beat.due(start));
        beat.asked(start);
        assert!(!beat.due(start + PERIOD / 2));
        assert!(beat.due(start + PERIOD));
        beat.answered(5, 5, at(start, 1));
        beat.unanswered();
        assert!(beat.answering(), "one unanswered question may be a flap");
        assert_eq!(beat.news(at(start, 2)), None);
        beat.unanswered();
        assert!(!beat.answering());
        assert_eq!(beat.news(at(start, 3)), Some(News::Unanswering));
        assert_eq!(beat.news(at(start, 3)), None, "said once");
        beat.answered(9, 9, at(start, 4));
        assert_eq!(beat.news(at(start, 4)), Some(News::Answering));
        assert_eq!(beat.silent_for(at(start, 4)), None);
    }
}

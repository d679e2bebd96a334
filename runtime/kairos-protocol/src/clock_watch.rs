//! Watching a clock that follows a source from its telemetry: whether its references stopped coming,
//! long before it leaves lock. `kairos deploy` and the studio say the same from it.

use crate::ClockState;

/// Silence this many times a clock's usual longest wait between references, and at least
/// [`SILENT_AT_LEAST_S`], is said: a master answering every 250 ms is missed after 1 s, a GNSS receiver
/// giving a reference a second after 2 to 2.5 s, both before the clock's holdover (3 s).
const SILENT_FACTOR: f64 = 2.0;
const SILENT_AT_LEAST_S: f64 = 1.0;
/// Waits between references seen before a silence is judged.
const WAITS_TO_LEARN: u32 = 3;
/// How much of the longest wait seen is kept from one wait to the next: a reference lost once raises the
/// limit for some seconds, not for ever.
const KEPT_PER_WAIT: f64 = 0.95;

/// What a look at a host's clock found about its references.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum References {
    /// As usual.
    AsUsual,
    /// None for this long, well over the usual wait: its source stopped answering.
    Stopped {
        /// Seconds since the last reference.
        for_s: f64,
    },
    /// They come again, the clock having stayed locked meanwhile.
    Back,
}

/// How long a host's clock usually waits between references, learnt from its statuses (the count of
/// references rising, as seen from here), so that a source that stops answering is said long before the
/// clock leaves lock. Only waits that ended are learnt: a silence does not teach that silences are usual.
#[derive(Debug, Default, Clone)]
pub struct ReferenceWatch {
    /// The references counted at the last look, and when that count was first seen.
    counted: Option<(u64, std::time::Instant)>,
    longest_wait_s: f64,
    waits: u32,
    stopped: bool,
}

impl ReferenceWatch {
    /// A look at the clock at `now`: its state, references so far and the time since the last.
    pub fn look(
        &mut self,
        now: std::time::Instant,
        state: ClockState,
        references: u64,
        since_reference_s: Option<f64>,
    ) -> References {
        match self.counted {
            Some((counted, at)) if references > counted => {
                let waited = now.duration_since(at).as_secs_f64();
                self.longest_wait_s = (self.longest_wait_s * KEPT_PER_WAIT).max(waited);
                self.waits += 1;
                self.counted = Some((references, now));
            }
            Some((counted, _)) if references == counted => {}
            _ => self.counted = Some((references, now)),
        }
        let (Some(since), true) = (since_reference_s, state == ClockState::Locked) else {
            // Out of lock, the clock's own state says it; references coming back then say it locked.
            self.stopped = false;
            return References::AsUsual;
        };
        let limit = (self.longest_wait_s * SILENT_FACTOR).max(SILENT_AT_LEAST_S);
        if self.stopped {
            if since < limit {
                self.stopped = false;
                return References::Back;
            }
            return References::AsUsual;
        }
        if self.waits >= WAITS_TO_LEARN && since > limit {
            self.stopped = true;
            return References::Stopped { for_s: since };
        }
        References::AsUsual
    }
}

#[cfg(test)]
mod tests {
    use super::{ReferenceWatch, References};
    use crate::ClockState;

    #[test]
    fn a_source_that_stops_answering_is_said_after_its_usual_wait_and_its_return_too() {
        use ClockState::{Holdover, Locked};
        use std::time::{Duration, Instant};
        let start = Instant::now();
        let at = |s: f64| start + Duration::from_secs_f64(s);
        // A master answering every 250 ms, looked at every 250 ms (a reference between each two looks).
        let mut master = ReferenceWatch::default();
        for look in 0..20_u32 {
            let now = f64::from(look) * 0.25;
            assert_eq!(
                master.look(at(now), Locked, u64::from(look), Some(0.24)),
                References::AsUsual
            );
        }
        // It dies after its 20th answer: the silence grows, and is said once over 1 s.
        let said: Vec<References> = (1..=8)
            .map(|n| {
                master.look(
                    at(4.75 + f64::from(n) * 0.25),
                    Locked,
                    19,
                    Some(0.24 + f64::from(n) * 0.25),
                )
            })
            .collect();
        assert_eq!(
            said.iter().filter(|r| **r != References::AsUsual).count(),
            1,
            "{said:?}"
        );
        assert_eq!(said[3], References::Stopped { for_s: 1.24 }, "{said:?}");
        assert_eq!(master.look(at(7.0), Locked, 20, Some(0.05)), References::Back);

        // A GNSS receiver's reference a second: 1.2 s of silence is usual, 2.6 s is not.
        let mut gnss = ReferenceWatch::default();
        for look in 0..40_u32 {
            let now = f64::from(look) * 0.25;
            gnss.look(
                at(now),
                Locked,
                u64::from(look / 4),
                Some(f64::from(look % 4) * 0.25),
            );
        }
        assert_eq!(
            gnss.clone().look(at(10.2), Locked, 9, Some(1.2)),
            References::AsUsual
        );
        assert_eq!(
            gnss.look(at(11.6), Locked, 9, Some(2.6)),
            References::Stopped { for_s: 2.6 }
        );
        // Out of lock the clock's state speaks: no return is said then.
        assert_eq!(gnss.look(at(12.5), Holdover, 9, Some(3.5)), References::AsUsual);
        assert_eq!(gnss.look(at(12.75), Locked, 10, Some(0.1)), References::AsUsual);
        // Nothing is judged before the usual wait is known.
        let mut fresh = ReferenceWatch::default();
        assert_eq!(fresh.look(at(0.0), Locked, 1, Some(5.0)), References::AsUsual);
    }
}

/// A clock's error as people read it: signed milliseconds to the microsecond (`+0.012 ms`,
/// `-1.500 ms`), and `0.000 ms` within half a microsecond either way, never `-0.000 ms`.
pub fn error_ms(error_ns: i64) -> String {
    let ms = (error_ns as f64 * 1e-6 * 1e3).round() / 1e3;
    if ms == 0.0 {
        "0.000 ms".to_owned()
    } else {
        format!("{ms:+.3} ms")
    }
}

#[cfg(test)]
mod error_words {
    use super::error_ms;

    #[test]
    fn an_error_reads_in_signed_milliseconds_and_no_error_has_no_sign() {
        assert_eq!(error_ms(12_000), "+0.012 ms");
        assert_eq!(error_ms(-1_500_000), "-1.500 ms");
        assert_eq!(error_ms(-400), "0.000 ms");
        assert_eq!(error_ms(499), "0.000 ms");
        assert_eq!(error_ms(-600), "-0.001 ms");
    }
}

//! The pre-trigger ring: the last seconds of every recorded input, in memory, bounded in time and in
//! bytes, ready to be written when a trigger arrives.

use std::collections::{BTreeMap, VecDeque};

use kairos_sdk::{Sample, Timestamp};

/// Samples in arrival order, with what they hold.
#[derive(Debug, Default)]
pub struct Ring {
    samples: VecDeque<(usize, Sample, usize)>,
    bytes: usize,
    /// Samples pushed out (too old or over the byte bound) since the start.
    pub dropped: u64,
    /// The same, per input.
    pub dropped_by_input: BTreeMap<usize, u64>,
}

/// What a sample costs the ring: the bytes behind its payload and the sample itself.
fn cost(sample: &Sample) -> usize {
    sample.payload.heavy_size_bytes() + size_of::<Sample>()
}

impl Ring {
    /// Adds `sample` of `input`, then drops the oldest samples until the ring spans at most `keep_nanos`
    /// (by timestamps) and holds at most `max_bytes`.
    pub fn push(&mut self, input: usize, sample: Sample, keep_nanos: i64, max_bytes: usize) {
        let newest = sample.timestamp;
        let bytes = cost(&sample);
        self.bytes += bytes;
        self.samples.push_back((input, sample, bytes));
        while let Some((input, oldest, bytes)) = self.samples.front() {
            let too_old = newest.nanos_since(oldest.timestamp) > keep_nanos;
            if !too_old && self.bytes <= max_bytes {
                break;
            }
            self.bytes -= bytes;
            *self.dropped_by_input.entry(*input).or_default() += 1;
            self.samples.pop_front();
            self.dropped += 1;
        }
    }

    /// Takes out every sample stamped at or after `from`, in arrival order; earlier ones are dropped.
    pub fn take_from(&mut self, from: Timestamp) -> Vec<(usize, Sample)> {
        let taken = self
            .samples
            .drain(..)
            .filter(|(_, sample, _)| sample.timestamp >= from)
            .map(|(input, sample, _)| (input, sample))
            .collect();
        self.bytes = 0;
        taken
    }

    /// Puts samples back at the front (a write that failed part-way keeps what it did not write).
    pub fn restore(&mut self, samples: impl DoubleEndedIterator<Item = (usize, Sample)>) {
        for (input, sample) in samples.rev() {
            let bytes = cost(&sample);
            self.bytes += bytes;
            self.samples.push_front((input, sample, bytes));
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Samples held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Seconds between its oldest and newest samples.
    pub fn span_s(&self) -> f64 {
        match (self.samples.front(), self.samples.back()) {
            (Some((_, first, _)), Some((_, last, _))) => {
                last.timestamp.nanos_since(first.timestamp) as f64 * 1e-9
            }
            _ => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use kairos_sdk::{Payload, Sample, Timestamp};

    use super::Ring;

    fn sample(ms: i64, bytes: usize) -> Sample {
        Sample::new(
            Payload::Bytes(Arc::from(vec![0_u8; bytes])),
            Timestamp::from_millis(ms),
        )
    }

    #[test]
    fn the_ring_keeps_the_last_seconds_within_its_byte_bound() {
        let mut ring = Ring::default();
        for ms in (0..10_000).step_by(10) {
            ring.push(0, sample(ms, 100), 2_000_000_000, usize::MAX);
        }
        assert!((ring.span_s() - 2.0).abs() < 0.011, "{}", ring.span_s());
        assert_eq!(ring.dropped, 1000 - 201);
        assert_eq!(ring.dropped_by_input.get(&0), Some(&(1000 - 201)));
        let mut small = Ring::default();
        for ms in 0..100 {
            small.push(0, sample(ms, 10_000), i64::MAX, 50_000);
        }
        assert!(
            small.bytes() <= 50_000 && small.len() == 4,
            "{} bytes, {}",
            small.bytes(),
            small.len()
        );
        let taken = ring.take_from(Timestamp::from_millis(9_500));
        assert_eq!(taken.len(), 50);
        assert!(ring.is_empty() && ring.bytes() == 0);
        ring.restore(taken.into_iter());
        assert_eq!(ring.len(), 50);
    }
}

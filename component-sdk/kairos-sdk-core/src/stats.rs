//! Counters kept per link, and a small latency histogram.

use std::sync::atomic::Ordering::Relaxed;
use std::sync::atomic::{AtomicI64, AtomicU64};

use serde::{Deserialize, Serialize};

/// Latencies in a log-linear histogram: exact min, max and mean; p50 and p99 within one sub-bucket
/// (at most 1/8 of the value too high).
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    count: u64,
    sum_nanos: i128,
    min_nanos: i64,
    max_nanos: i64,
    buckets: Box<[u64; BUCKETS]>,
}

const SUB_BITS: u32 = 3;
const SUB: usize = 1 << SUB_BITS;
const BUCKETS: usize = 64 * SUB;

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram {
            count: 0,
            sum_nanos: 0,
            min_nanos: i64::MAX,
            max_nanos: i64::MIN,
            buckets: Box::new([0; BUCKETS]),
        }
    }
}

#[inline]
fn bucket_of(value: u64) -> usize {
    if value < SUB as u64 {
        return value as usize;
    }
    let magnitude = value.ilog2(); // >= SUB_BITS
    let shift = magnitude - SUB_BITS;
    let sub = ((value >> shift) as usize) & (SUB - 1);
    ((magnitude - SUB_BITS + 1) as usize) * SUB + sub
}

fn bucket_upper_bound(index: usize) -> u64 {
    let group = index / SUB;
    let sub = (index % SUB) as u64;
    if group == 0 {
        return sub;
    }
    let shift = (group - 1) as u32;
    (((SUB as u64) + sub + 1) << shift).saturating_sub(1)
}

impl LatencyHistogram {
    /// Adds one latency. Negative latencies (a timestamp in the future, e.g. from a remote clock) count
    /// as zero in the percentiles; the minimum and the mean keep their sign.
    pub fn record(&mut self, nanos: i64) {
        self.count += 1;
        self.sum_nanos += i128::from(nanos);
        self.min_nanos = self.min_nanos.min(nanos);
        self.max_nanos = self.max_nanos.max(nanos);
        let index = bucket_of(u64::try_from(nanos).unwrap_or(0));
        if let Some(slot) = self.buckets.get_mut(index) {
            *slot += 1;
        }
    }

    /// Min, mean, p50, p99 and max so far.
    pub fn summary(&self) -> LatencySummary {
        if self.count == 0 {
            return LatencySummary::default();
        }
        LatencySummary {
            count: self.count,
            min_nanos: self.min_nanos,
            mean_nanos: (self.sum_nanos / i128::from(self.count)) as i64,
            p50_nanos: self.quantile(0.50),
            p99_nanos: self.quantile(0.99),
            max_nanos: self.max_nanos,
        }
    }

    fn quantile(&self, q: f64) -> i64 {
        let rank = ((self.count as f64) * q).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (index, n) in self.buckets.iter().enumerate() {
            seen += n;
            if seen >= rank {
                let bound = i64::try_from(bucket_upper_bound(index)).unwrap_or(i64::MAX);
                return bound.min(self.max_nanos).max(self.min_nanos.max(0));
            }
        }
        self.max_nanos
    }
}

/// A [`LatencyHistogram`] one thread records into while others take snapshots: every field is an atomic
/// that only the recording thread writes, so recording is a few plain stores, with no lock and no
/// read-modify-write. A snapshot may miss the latency being recorded at that instant.
pub(crate) struct SharedLatency {
    sum_nanos: AtomicI64,
    min_nanos: AtomicI64,
    max_nanos: AtomicI64,
    buckets: Box<Buckets>,
}

/// The counts of a [`SharedLatency`], which its reader bumps for every sample: on cache lines of their
/// own, so that no neighbour in the heap that another thread reads or writes shares one.
#[repr(align(128))]
struct Buckets([AtomicU64; BUCKETS]);

impl Default for SharedLatency {
    fn default() -> Self {
        SharedLatency {
            sum_nanos: AtomicI64::new(0),
            min_nanos: AtomicI64::new(i64::MAX),
            max_nanos: AtomicI64::new(i64::MIN),
            buckets: Box::new(Buckets(std::array::from_fn(|_| AtomicU64::new(0)))),
        }
    }
}

impl SharedLatency {
    /// Adds one latency. Only one thread may record (the reader owning it).
    #[inline]
    pub(crate) fn record(&self, nanos: i64) {
        self.sum_nanos
            .store(self.sum_nanos.load(Relaxed).wrapping_add(nanos), Relaxed);
        if nanos < self.min_nanos.load(Relaxed) {
            self.min_nanos.store(nanos, Relaxed);
        }
        if nanos > self.max_nanos.load(Relaxed) {
            self.max_nanos.store(nanos, Relaxed);
        }
        // `bucket_of` is below BUCKETS already; the mask says so to the compiler (no bounds check on
        // every sample read).
        let bucket = &self.buckets.0[bucket_of(u64::try_from(nanos).unwrap_or(0)) % BUCKETS];
        bucket.store(bucket.load(Relaxed) + 1, Relaxed);
    }

    /// A copy to summarise.
    pub(crate) fn snapshot(&self) -> LatencyHistogram {
        let mut buckets = Box::new([0; BUCKETS]);
        for (copy, bucket) in buckets.iter_mut().zip(self.buckets.0.iter()) {
            *copy = bucket.load(Relaxed);
        }
        LatencyHistogram {
            // The buckets decide the percentiles, so the count is theirs.
            count: buckets.iter().sum(),
            sum_nanos: i128::from(self.sum_nanos.load(Relaxed)),
            min_nanos: self.min_nanos.load(Relaxed),
            max_nanos: self.max_nanos.load(Relaxed),
            buckets,
        }
    }
}

/// A summary of latencies (time of issue − timestamp), in nanoseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// How many samples were measured.
    pub count: u64,
    /// The smallest latency.
    pub min_nanos: i64,
    /// The mean latency.
    pub mean_nanos: i64,
    /// The median.
    pub p50_nanos: i64,
    /// The 99th percentile.
    pub p99_nanos: i64,
    /// The largest latency.
    pub max_nanos: i64,
}

/// Counters of one link (one reader of one output) since the reader attached.
///
/// `written == read + skipped + overwritten + queued` always holds exactly.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LinkCounters {
    /// Samples written to the output since this reader attached.
    pub written: u64,
    /// Samples returned to the reader (each once).
    pub read: u64,
    /// Samples the reader's policy or subsampling passed over.
    pub skipped: u64,
    /// Samples overwritten by the writer before a FIFO reader got to them.
    pub overwritten: u64,
    /// Samples written and not yet read, skipped or overwritten.
    pub queued: u64,
    /// Times a Sampling reader was given a sample it had already had.
    pub repeated: u64,
    /// Latency of the samples read.
    pub latency: LatencySummary,
}

impl LinkCounters {
    /// Whether the counting identity holds.
    pub fn balanced(&self) -> bool {
        self.written == self.read + self.skipped + self.overwritten + self.queued
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_are_monotonic_and_bounds_cover_values() {
        let mut last = 0;
        for value in [
            0_u64,
            1,
            7,
            8,
            9,
            15,
            16,
            17,
            100,
            1000,
            12_345,
            1 << 20,
            u64::MAX / 2,
        ] {
            let index = bucket_of(value);
            assert!(index >= last, "bucket of {value}");
            last = index;
            assert!(
                bucket_upper_bound(index) >= value,
                "upper bound of bucket for {value}"
            );
            assert!(
                bucket_upper_bound(index) <= value + value / 8 + 1,
                "bound tight for {value}"
            );
        }
    }

    #[test]
    fn percentiles_of_a_uniform_spread() {
        let mut histogram = LatencyHistogram::default();
        for v in 1..=1000 {
            histogram.record(v * 1000);
        }
        let summary = histogram.summary();
        assert_eq!(summary.count, 1000);
        assert_eq!(summary.min_nanos, 1000);
        assert_eq!(summary.max_nanos, 1_000_000);
        assert_eq!(summary.mean_nanos, 500_500);
        assert!((500_000..=570_000).contains(&summary.p50_nanos), "{summary:?}");
        assert!((990_000..=1_000_000).contains(&summary.p99_nanos), "{summary:?}");
    }
}

//! A `loom` model of the buffer: every interleaving of a writer and a blocking reader is explored.
//!
//! Run with `RUSTFLAGS="--cfg loom" cargo test -p kairos-sdk --test loom --release --target-dir target/loom`.
#![cfg(loom)]
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::Arc;

use kairos_sdk_core::host::{OutputBuffer, ReadError, Reader, ReaderConfig};
use kairos_sdk_core::{Payload, ReaderPolicy, RunSignal, Sample, Timestamp};

fn sample(sequence: u64) -> Sample {
    Sample {
        payload: Payload::I64(sequence as i64),
        timestamp: Timestamp(sequence as i64),
        time_of_issue: Timestamp(sequence as i64),
        sequence,
    }
}

/// Explores up to 100 000 branches per execution with at most 3 preemptions: the buffer's waits spin a
/// little before they sleep, which makes paths long, and bugs of this kind show within two preemptions.
/// `LOOM_MAX_BRANCHES` and `LOOM_MAX_PREEMPTIONS` override both, to investigate a failure.
fn builder() -> loom::model::Builder {
    let mut builder = loom::model::Builder::new();
    if std::env::var_os("LOOM_MAX_BRANCHES").is_none() {
        builder.max_branches = 100_000;
    }
    if std::env::var_os("LOOM_MAX_PREEMPTIONS").is_none() {
        builder.preemption_bound = Some(3);
    }
    builder
}

/// Reads with blocking reads until the end of the stream; the sequences read.
fn read_to_end(reader: &mut Reader) -> Vec<u64> {
    let mut got = Vec::new();
    loop {
        match reader.read(false) {
            Ok(sample) => got.push(sample.sequence),
            Err(ReadError::EndOfStream) => return got,
            Err(other) => panic!("unexpected {other:?}"),
        }
    }
}

/// A writer writes `count` samples then closes; the reader reads until the end of the stream.
fn model(policy: ReaderPolicy, capacity: usize, count: u64, check: fn(&[u64])) {
    subsampled_model(policy, capacity, 1, count, check);
}

/// As [`model`], the reader keeping one sample in `one_in`.
fn subsampled_model(policy: ReaderPolicy, capacity: usize, one_in: u32, count: u64, check: fn(&[u64])) {
    builder().check(move || {
        let buffer = OutputBuffer::new("w.out", capacity);
        let signal = Arc::new(RunSignal::new());
        let mut config = ReaderConfig::new(policy, "w.out -> r.in");
        config.subsampling = one_in;
        let mut reader = buffer.attach(config, Arc::clone(&signal));
        let writer = {
            let buffer = buffer.clone();
            loom::thread::spawn(move || {
                let signal = Arc::new(RunSignal::new());
                signal.bind_current_thread();
                for sequence in 0..count {
                    buffer.write(sample(sequence), &signal).unwrap();
                }
                buffer.close();
            })
        };
        signal.bind_current_thread();
        let got = read_to_end(&mut reader);
        writer.join().unwrap();
        let counters = reader.counters();
        assert!(counters.balanced(), "{counters:?}");
        assert!(counters.queued <= capacity as u64, "{counters:?}");
        assert_eq!(counters.written, count);
        assert!(
            got.iter().all(|s| s % u64::from(one_in) == 0),
            "not kept: {got:?}"
        );
        check(&got);
    });
}

#[test]
fn fifo_never_loses_a_wake_up_and_keeps_order() {
    model(ReaderPolicy::Fifo, 2, 3, |got| {
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
        assert_eq!(got.last(), Some(&2), "the newest always arrives: {got:?}");
    });
}

#[test]
fn never_skipping_delivers_everything_in_order() {
    model(ReaderPolicy::NeverSkipping, 1, 3, |got| {
        assert_eq!(got, [0, 1, 2]);
    });
}

#[test]
fn last_or_next_ends_on_the_newest() {
    model(ReaderPolicy::LastOrNext, 2, 3, |got| {
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
        assert_eq!(got.last(), Some(&2), "{got:?}");
    });
}

#[test]
fn a_subsampled_reader_of_the_newest_sees_kept_samples_only_and_ends_on_the_newest_kept() {
    subsampled_model(ReaderPolicy::LastOrNext, 2, 2, 4, |got| {
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
        assert_eq!(got.last(), Some(&2), "{got:?}");
    });
}

#[test]
fn a_subsampled_never_skipping_reader_gets_every_kept_sample() {
    subsampled_model(ReaderPolicy::NeverSkipping, 1, 2, 3, |got| {
        assert_eq!(got, [0, 2]);
    });
}

/// A reader attaching while the writer writes: every later write sees it, and it ends on the newest sample.
///
/// The writer runs on the model's main thread: loom wakes a thread blocked in `join` when someone unparks
/// it, which only the writer's last wake-up of the reader could do here.
#[test]
fn a_reader_attaching_mid_stream_sees_every_later_write() {
    builder().check(|| {
        // One slot: the second write replaces the sample the reader may be cloning.
        let buffer = OutputBuffer::new("w.out", 1);
        let reader = {
            let buffer = buffer.clone();
            loom::thread::spawn(move || {
                let signal = Arc::new(RunSignal::new());
                signal.bind_current_thread();
                let mut reader = buffer.attach(
                    ReaderConfig::new(ReaderPolicy::Fifo, "w.out -> late.in"),
                    Arc::clone(&signal),
                );
                let got = read_to_end(&mut reader);
                (got, reader.counters())
            })
        };
        let signal = Arc::new(RunSignal::new());
        signal.bind_current_thread();
        for sequence in 0..2 {
            buffer.write(sample(sequence), &signal).unwrap();
        }
        buffer.close();
        let (got, counters) = reader.join().unwrap();
        assert!(counters.balanced(), "{counters:?}");
        assert_eq!(got.last(), Some(&1), "the newest always arrives: {got:?}");
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{got:?}");
    });
}

/// A NeverSkipping reader that leaves while its writer waits for room releases the writer.
#[test]
fn a_reader_leaving_releases_a_waiting_writer() {
    builder().check(|| {
        let buffer = OutputBuffer::new("w.out", 1);
        let reader = buffer.attach(
            ReaderConfig::new(ReaderPolicy::NeverSkipping, "w.out -> slow.in"),
            Arc::new(RunSignal::new()),
        );
        let writer = {
            let buffer = buffer.clone();
            loom::thread::spawn(move || {
                let signal = Arc::new(RunSignal::new());
                signal.bind_current_thread();
                for sequence in 0..2 {
                    buffer.write(sample(sequence), &signal).unwrap();
                }
            })
        };
        drop(reader);
        writer.join().unwrap();
        assert_eq!(buffer.written(), 2);
    });
}

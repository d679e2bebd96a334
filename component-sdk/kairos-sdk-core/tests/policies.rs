//! Each reader policy against a fast producer (the reader falls behind) and a slow one (the reader waits),
//! asserting exactly which samples arrive and every counter.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::Arc;
use std::thread;
use std::time::Duration;

use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{LinkCounters, Payload, ReaderPolicy, RunSignal, Sample, Timestamp};

fn sample(sequence: u64) -> Sample {
    Sample {
        payload: Payload::I64(sequence as i64),
        timestamp: Timestamp::from_micros(sequence as i64),
        time_of_issue: Timestamp::from_micros(sequence as i64 + 5),
        sequence,
    }
}

fn write_range(buffer: &OutputBuffer, writer: &Arc<RunSignal>, range: std::ops::Range<u64>) {
    for sequence in range {
        buffer.write(sample(sequence), writer).unwrap();
    }
}

fn reader(buffer: &OutputBuffer, policy: ReaderPolicy) -> kairos_sdk_core::host::Reader {
    buffer.attach(ReaderConfig::new(policy, "test"), Arc::new(RunSignal::new()))
}

/// Waits until `buffer` has had `count` samples written (at once on a fast machine, at most 5 s), then
/// checks the writer stays there a while.
fn written_stays_at(buffer: &OutputBuffer, count: u64, why: &str) {
    let started = std::time::Instant::now();
    while buffer.written() < count {
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "{} of {count} written in 5 s",
            buffer.written()
        );
        thread::sleep(Duration::from_millis(1));
    }
    thread::sleep(Duration::from_millis(50));
    assert_eq!(buffer.written(), count, "{why}");
}

fn counts(c: LinkCounters) -> [u64; 5] {
    assert!(c.balanced(), "identity broken: {c:?}");
    [c.written, c.read, c.skipped, c.overwritten, c.queued]
}

fn sequences(reader: &mut kairos_sdk_core::host::Reader) -> Vec<u64> {
    std::iter::from_fn(|| reader.try_read())
        .map(|s| s.sequence)
        .collect()
}

// ----- fast producer: ten samples into a buffer of four before the reader looks -----

#[test]
fn fifo_behind_gets_the_oldest_still_held_and_counts_the_overwritten() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::Fifo);
    write_range(&buffer, &writer, 0..10);
    assert_eq!(counts(r.counters()), [10, 0, 0, 6, 4]);
    assert_eq!(sequences(&mut r), vec![6, 7, 8, 9]);
    assert_eq!(counts(r.counters()), [10, 4, 0, 6, 0]);
}

#[test]
fn last_or_next_behind_gets_the_newest_and_counts_the_rest_as_skipped() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::LastOrNext);
    write_range(&buffer, &writer, 0..10);
    assert_eq!(sequences(&mut r), vec![9]);
    assert_eq!(counts(r.counters()), [10, 1, 9, 0, 0]);
    write_range(&buffer, &writer, 10..12);
    assert_eq!(sequences(&mut r), vec![11]);
    assert_eq!(counts(r.counters()), [12, 2, 10, 0, 0]);
}

#[test]
fn wait_for_next_behind_ignores_everything_pending_and_waits() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let signal = Arc::new(RunSignal::new());
    let mut r = buffer.attach(
        ReaderConfig::new(ReaderPolicy::WaitForNext, "test"),
        Arc::clone(&signal),
    );
    write_range(&buffer, &writer, 0..10);
    let waiting = thread::Builder::new()
        .name("policies".to_owned())
        .spawn(move || {
            signal.bind_current_thread();
            let got = r.read(false).unwrap().sequence;
            (got, r.counters())
        })
        .expect("starting a thread");
    // Let the reader discard the pending ten and go to sleep.
    thread::sleep(Duration::from_millis(50));
    write_range(&buffer, &writer, 10..11);
    let (got, c) = waiting.join().unwrap();
    assert_eq!(got, 10);
    assert_eq!(counts(c), [11, 1, 10, 0, 0]);
}

#[test]
fn sampling_behind_gets_the_newest_at_once_and_again() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::Sampling);
    assert!(r.try_read().is_none(), "nothing written yet");
    write_range(&buffer, &writer, 0..10);
    assert_eq!(r.try_read().unwrap().sequence, 9);
    assert_eq!(r.try_read().unwrap().sequence, 9);
    assert_eq!(r.try_read().unwrap().sequence, 9);
    let c = r.counters();
    assert_eq!(counts(c), [10, 1, 9, 0, 0]);
    assert_eq!(c.repeated, 2);
}

#[test]
fn never_skipping_blocks_the_writer_until_the_reader_makes_room() {
    let buffer = OutputBuffer::new("p.out", 4);
    let mut r = reader(&buffer, ReaderPolicy::NeverSkipping);
    let producer = {
        let buffer = buffer.clone();
        thread::Builder::new()
            .name("policies".to_owned())
            .spawn(move || {
                let writer = Arc::new(RunSignal::new());
                writer.bind_current_thread();
                write_range(&buffer, &writer, 0..10);
            })
            .expect("starting a thread")
    };
    written_stays_at(&buffer, 4, "the writer must wait for room");
    let mut got = Vec::new();
    while got.len() < 10 {
        match r.try_read() {
            Some(s) => got.push(s.sequence),
            None => thread::sleep(Duration::from_millis(1)),
        }
    }
    producer.join().unwrap();
    assert_eq!(got, (0..10).collect::<Vec<_>>());
    assert_eq!(counts(r.counters()), [10, 10, 0, 0, 0]);
}

#[test]
fn a_stop_releases_a_writer_blocked_by_never_skipping() {
    let buffer = OutputBuffer::new("p.out", 2);
    let _r = reader(&buffer, ReaderPolicy::NeverSkipping);
    let writer = Arc::new(RunSignal::new());
    let producer = {
        let buffer = buffer.clone();
        let writer = Arc::clone(&writer);
        thread::Builder::new()
            .name("policies".to_owned())
            .spawn(move || {
                writer.bind_current_thread();
                (0..10)
                    .map(|s| buffer.write(sample(s), &writer))
                    .find(Result::is_err)
            })
            .expect("starting a thread")
    };
    written_stays_at(&buffer, 2, "the writer waits for room until the stop");
    writer.request_stop();
    let failure = producer.join().unwrap();
    assert_eq!(failure, Some(Err(kairos_sdk_core::host::WriteError::Stopped)));
    assert_eq!(buffer.written(), 2);
}

#[test]
fn only_never_skipping_slows_the_writer_other_readers_keep_its_pace() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut readers: Vec<_> = [
        ReaderPolicy::Fifo,
        ReaderPolicy::LastOrNext,
        ReaderPolicy::WaitForNext,
        ReaderPolicy::Sampling,
    ]
    .into_iter()
    .map(|p| reader(&buffer, p))
    .collect();
    // None of them reads: the writer must never block.
    write_range(&buffer, &writer, 0..1000);
    assert_eq!(buffer.written(), 1000);
    for r in &mut readers {
        assert!(r.counters().balanced());
    }
}

// ----- slow producer: the reader is always waiting when a sample arrives -----

/// A writer that writes `count` samples, each one 5 ms after the reader said it is about to read again, so
/// that the reader is waiting when it arrives. The reader reads until it has the last sample.
///
/// On a loaded machine the reader can still be descheduled for longer than that between saying so and
/// waiting; LastOrNext and WaitForNext then rightly skip a sample, so the reader stops at the last one
/// rather than after `count` reads (reading `count` times would then wait for ever). A watchdog stops the
/// reader after 10 s, so a lost wake-up fails the test instead of hanging it.
fn paced(policy: ReaderPolicy, count: u64) -> (Vec<u64>, LinkCounters) {
    let buffer = OutputBuffer::new("p.out", 4);
    let signal = Arc::new(RunSignal::new());
    let mut r = buffer.attach(ReaderConfig::new(policy, "test"), Arc::clone(&signal));
    let (ready, about_to_read) = std::sync::mpsc::channel::<()>();
    let watchdog = Arc::clone(&signal);
    let consumer = thread::Builder::new()
        .name("policies".to_owned())
        .spawn(move || {
            signal.bind_current_thread();
            let mut got = Vec::new();
            while got.last() != Some(&(count - 1)) {
                let _ = ready.send(());
                match r.read(false) {
                    Ok(sample) => got.push(sample.sequence),
                    Err(error) => panic!("{policy}: after {got:?}, {error:?}"),
                }
            }
            (got, r.counters())
        })
        .expect("starting a thread");
    let writer = Arc::new(RunSignal::new());
    for sequence in 0..count {
        // The reader may have skipped ahead already and be waiting for a later sample: don't wait for it.
        let _ = about_to_read.recv_timeout(Duration::from_millis(100));
        thread::sleep(Duration::from_millis(5));
        buffer.write(sample(sequence), &writer).unwrap();
    }
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while !consumer.is_finished() && std::time::Instant::now() < deadline {
        thread::sleep(Duration::from_millis(10));
    }
    watchdog.request_stop();
    consumer.join().unwrap()
}

#[test]
fn a_waiting_reader_gets_every_sample_under_each_queueing_policy() {
    for policy in [ReaderPolicy::Fifo, ReaderPolicy::NeverSkipping] {
        let (got, c) = paced(policy, 8);
        assert_eq!(got, (0..8).collect::<Vec<_>>(), "{policy}");
        assert_eq!(counts(c), [8, 8, 0, 0, 0], "{policy}");
    }
    for policy in [ReaderPolicy::LastOrNext, ReaderPolicy::WaitForNext] {
        let (got, c) = paced(policy, 8);
        // Each sample is read once, in order, and the newest at the end; a sample is skipped only when
        // the machine kept the reader from waiting in time, and then it is counted.
        assert!(got.windows(2).all(|w| w[0] < w[1]), "{policy}: {got:?}");
        assert_eq!(c.read, got.len() as u64, "{policy}");
        assert_eq!(c.written, 8, "{policy}");
        assert_eq!(c.read + c.skipped, 8, "{policy}: {got:?}");
        assert_eq!((c.overwritten, c.queued), (0, 0), "{policy}");
    }
}

#[test]
fn a_fast_sampling_reader_sees_repeats_between_writes() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::Sampling);
    let mut got = Vec::new();
    for sequence in 0..3 {
        buffer.write(sample(sequence), &writer).unwrap();
        got.push(r.try_read().unwrap().sequence);
        got.push(r.try_read().unwrap().sequence);
    }
    assert_eq!(got, vec![0, 0, 1, 1, 2, 2]);
    let c = r.counters();
    assert_eq!(counts(c), [3, 3, 0, 0, 0]);
    assert_eq!(c.repeated, 3);
}

// ----- subsampling, capacity per reader, late readers, payload sharing -----

#[test]
fn input_subsampling_keeps_one_in_n_and_counts_the_rest_as_skipped() {
    let buffer = OutputBuffer::new("p.out", 16);
    let writer = Arc::new(RunSignal::new());
    let mut config = ReaderConfig::new(ReaderPolicy::Fifo, "test");
    config.subsampling = 3;
    let mut r = buffer.attach(config, Arc::new(RunSignal::new()));
    write_range(&buffer, &writer, 0..10);
    assert_eq!(sequences(&mut r), vec![0, 3, 6, 9]);
    assert_eq!(counts(r.counters()), [10, 4, 6, 0, 0]);
}

fn subsampled(buffer: &OutputBuffer, policy: ReaderPolicy, one_in: u32) -> kairos_sdk_core::host::Reader {
    let mut config = ReaderConfig::new(policy, "test");
    config.subsampling = one_in;
    buffer.attach(config, Arc::new(RunSignal::new()))
}

#[test]
fn subsampling_keeps_the_same_samples_whatever_the_policy_and_however_often_the_reader_looks() {
    for policy in ReaderPolicy::ALL {
        let buffer = OutputBuffer::new("p.out", 64);
        let writer = Arc::new(RunSignal::new());
        let mut r = subsampled(&buffer, policy, 2);
        let mut got = Vec::new();
        // The reader looks after every write: it must see the even samples only, each once (Sampling
        // repeats the newest even one while the odd one follows it).
        for sequence in 0..10 {
            write_range(&buffer, &writer, sequence..sequence + 1);
            if policy == ReaderPolicy::WaitForNext {
                got.extend(sequences(&mut r));
            } else if let Some(sample) = r.try_read() {
                got.push(sample.sequence);
            }
        }
        let expected: Vec<u64> = if policy == ReaderPolicy::Sampling {
            vec![0, 0, 2, 2, 4, 4, 6, 6, 8, 8]
        } else {
            vec![0, 2, 4, 6, 8]
        };
        assert_eq!(got, expected, "{policy}");
        let c = r.counters();
        // Each look passes over the odd sample that came since.
        assert_eq!(counts(c), [10, 5, 5, 0, 0], "{policy}");
        assert_eq!(
            c.repeated,
            if policy == ReaderPolicy::Sampling { 5 } else { 0 },
            "{policy}"
        );
    }
}

#[test]
fn an_overloaded_subsampled_reader_of_the_newest_takes_the_newest_kept_sample_without_waiting() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut last = subsampled(&buffer, ReaderPolicy::LastOrNext, 2);
    let mut sampling = subsampled(&buffer, ReaderPolicy::Sampling, 2);
    // The reader falls behind: the newest sample is odd, the kept one before it is still unread.
    write_range(&buffer, &writer, 0..10);
    assert_eq!(last.try_read().map(|s| s.sequence), Some(8));
    assert_eq!(sampling.try_read().map(|s| s.sequence), Some(8));
    assert_eq!(counts(last.counters()), [10, 1, 9, 0, 0]);
    // Only an odd sample is new: nothing for LastOrNext, the same kept one again for Sampling.
    write_range(&buffer, &writer, 10..11);
    write_range(&buffer, &writer, 11..12);
    assert_eq!(last.try_read().map(|s| s.sequence), Some(10));
    write_range(&buffer, &writer, 12..13);
    write_range(&buffer, &writer, 13..14);
    assert_eq!(last.try_read().map(|s| s.sequence), Some(12));
    assert!(last.try_read().is_none());
    assert_eq!(counts(last.counters()), [14, 3, 11, 0, 0]);
}

#[test]
fn a_lapped_subsampled_fifo_reader_counts_kept_samples_as_overwritten_and_the_others_as_skipped() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = subsampled(&buffer, ReaderPolicy::Fifo, 2);
    write_range(&buffer, &writer, 0..10);
    // Lost to the writer: 0, 2, 4 (kept) and 1, 3, 5 (passed over anyway); 6 to 9 still held.
    assert_eq!(counts(r.counters()), [10, 0, 3, 3, 4]);
    assert_eq!(sequences(&mut r), vec![6, 8]);
    assert_eq!(counts(r.counters()), [10, 2, 5, 3, 0]);
}

#[test]
fn queued_never_exceeds_the_share_and_samples_lapped_before_a_reader_of_the_newest_looks_are_skipped() {
    for policy in [
        ReaderPolicy::LastOrNext,
        ReaderPolicy::WaitForNext,
        ReaderPolicy::Sampling,
    ] {
        let buffer = OutputBuffer::new("p.out", 4);
        let writer = Arc::new(RunSignal::new());
        let mut r = reader(&buffer, policy);
        write_range(&buffer, &writer, 0..34);
        assert_eq!(counts(r.counters()), [34, 0, 30, 0, 4], "{policy}");
        // When it looks, the counts go on from there: the lapped ones were skipped, never overwritten.
        if policy != ReaderPolicy::WaitForNext {
            assert_eq!(r.try_read().map(|s| s.sequence), Some(33), "{policy}");
            assert_eq!(counts(r.counters()), [34, 1, 33, 0, 0], "{policy}");
        }
    }
}

#[test]
fn a_connection_may_have_a_larger_share_than_the_output_default() {
    let buffer = OutputBuffer::with_slots("p.out", 2, 8);
    let writer = Arc::new(RunSignal::new());
    let mut small = reader(&buffer, ReaderPolicy::Fifo);
    let mut config = ReaderConfig::new(ReaderPolicy::Fifo, "big");
    config.capacity = Some(8);
    let mut big = buffer.attach(config, Arc::new(RunSignal::new()));
    write_range(&buffer, &writer, 0..8);
    assert_eq!(sequences(&mut small), vec![6, 7]);
    assert_eq!(sequences(&mut big), (0..8).collect::<Vec<_>>());
    assert_eq!(counts(small.counters()), [8, 2, 0, 6, 0]);
    assert_eq!(counts(big.counters()), [8, 8, 0, 0, 0]);
}

#[test]
fn a_reader_asking_for_more_than_the_ring_gets_the_ring() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut config = ReaderConfig::new(ReaderPolicy::Fifo, "greedy");
    config.capacity = Some(100);
    let mut greedy = buffer.attach(config, Arc::new(RunSignal::new()));
    write_range(&buffer, &writer, 0..10);
    assert_eq!(sequences(&mut greedy), vec![6, 7, 8, 9]);
    assert_eq!(counts(greedy.counters()), [10, 4, 0, 6, 0]);
}

#[test]
fn a_buffer_size_beyond_the_maximum_is_cut_to_it_instead_of_taking_the_process_down() {
    let buffer = OutputBuffer::with_slots("p.out", usize::MAX, usize::MAX);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::Fifo);
    write_range(&buffer, &writer, 0..3);
    assert_eq!(sequences(&mut r), vec![0, 1, 2]);
}

#[test]
fn a_late_reader_starts_from_the_newest_sample() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    write_range(&buffer, &writer, 0..5);
    let mut r = reader(&buffer, ReaderPolicy::Fifo);
    write_range(&buffer, &writer, 5..6);
    assert_eq!(sequences(&mut r), vec![4, 5]);
    assert_eq!(counts(r.counters()), [2, 2, 0, 0, 0]);
}

#[test]
fn readers_share_the_payload_instead_of_copying_it() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut a = reader(&buffer, ReaderPolicy::Fifo);
    let mut b = reader(&buffer, ReaderPolicy::Fifo);
    let pixels = kairos_sdk_core::Pixels::from(vec![7_u8; 1 << 20]);
    let image =
        kairos_sdk_core::Image::packed(1024, 1024, kairos_sdk_core::PixelFormat::Gray8, pixels.clone())
            .unwrap();
    buffer
        .write(Sample::new(Payload::Image(image), Timestamp::ZERO), &writer)
        .unwrap();
    for r in [&mut a, &mut b] {
        let Payload::Image(got) = r.try_read().unwrap().payload else {
            panic!("not an image")
        };
        assert!(got.pixels.ptr_eq(&pixels), "the pixel buffer was copied");
    }
}

#[test]
fn shared_payloads_are_released_when_replaced_and_when_the_buffer_goes() {
    // Plain and shared samples take turns over a ring of 2 slots, starting plain: the writer reads a
    // replaced sample only when it owns shared data, and readers look at payloads only once the stream
    // has carried one that does, so every reference taken must be counted and must come back.
    let bytes: Arc<[u8]> = Arc::from(vec![1_u8; 64]);
    let buffer = OutputBuffer::new("p.out", 2);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::NeverSkipping);
    let mut kept = Vec::new();
    for sequence in 0..8_u64 {
        let payload = if sequence % 3 == 1 {
            Payload::Bytes(Arc::clone(&bytes))
        } else {
            Payload::I64(sequence as i64)
        };
        buffer
            .write(Sample::new(payload, Timestamp::ZERO), &writer)
            .unwrap();
        let got = r.try_read().unwrap();
        assert_eq!(got.payload.owns_shared_data(), sequence % 3 == 1);
        kept.push(got);
    }
    // Shared: sequences 1, 4 and 7, all read; the ring still holds 6 (plain) and 7.
    assert_eq!(Arc::strong_count(&bytes), 1 + 3 + 1);
    drop(kept);
    assert_eq!(Arc::strong_count(&bytes), 2);
    drop(r);
    drop(buffer);
    assert_eq!(
        Arc::strong_count(&bytes),
        1,
        "a sample left in the ring was not dropped"
    );
}

#[test]
fn closing_ends_the_stream_after_what_is_left() {
    let buffer = OutputBuffer::new("p.out", 4);
    let writer = Arc::new(RunSignal::new());
    let mut r = reader(&buffer, ReaderPolicy::Fifo);
    write_range(&buffer, &writer, 0..2);
    buffer.close();
    assert_eq!(r.read(false).unwrap().sequence, 0);
    assert_eq!(r.read(false).unwrap().sequence, 1);
    assert_eq!(r.read(false), Err(kairos_sdk_core::host::ReadError::EndOfStream));
}

#[test]
fn a_stop_wakes_a_blocked_reader() {
    let buffer = OutputBuffer::new("p.out", 4);
    let signal = Arc::new(RunSignal::new());
    let mut r = buffer.attach(ReaderConfig::new(ReaderPolicy::Fifo, "test"), Arc::clone(&signal));
    let waiting = {
        let signal = Arc::clone(&signal);
        thread::Builder::new()
            .name("policies".to_owned())
            .spawn(move || {
                signal.bind_current_thread();
                r.read(true)
            })
            .expect("starting a thread")
    };
    thread::sleep(Duration::from_millis(30));
    signal.request_stop();
    assert_eq!(
        waiting.join().unwrap(),
        Err(kairos_sdk_core::host::ReadError::Stopped)
    );
}

#[test]
fn a_reader_whose_signal_was_never_bound_is_still_woken() {
    let buffer = OutputBuffer::new("p.out", 4);
    let mut r = buffer.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "unbound"),
        Arc::new(RunSignal::new()),
    );
    let (done, finished) = std::sync::mpsc::channel();
    thread::Builder::new()
        .name("policies".to_owned())
        .spawn(move || {
            let _ = done.send(r.read(false).map(|s| s.sequence));
        })
        .expect("starting a thread");
    // Long enough for the reader to go to sleep.
    thread::sleep(Duration::from_millis(50));
    buffer.write(sample(7), &Arc::new(RunSignal::new())).unwrap();
    assert_eq!(
        finished.recv_timeout(Duration::from_secs(10)),
        Ok(Ok(7)),
        "the reader slept on although a sample arrived"
    );
}

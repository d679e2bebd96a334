//! The counting identity `written = read + skipped + overwritten + queued` under random producer and
//! consumer speeds, for every policy, with real threads.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::Arc;
use std::thread;
use std::time::Duration;

use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{Payload, ReaderPolicy, RunSignal, Sample, Timestamp};
use proptest::prelude::*;

fn policy() -> impl Strategy<Value = ReaderPolicy> {
    prop::sample::select(ReaderPolicy::ALL.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, max_shrink_iters: 0, ..ProptestConfig::default() })]

    #[test]
    fn identity_holds_at_every_instant_and_at_the_end(
        policies in prop::collection::vec(policy(), 1..4),
        capacity in 1_usize..8,
        subsampling in 1_u32..4,
        writes in 1_u64..300,
        writer_pause_every in 1_u64..50,
        reader_pauses in prop::collection::vec(0_u64..3, 1..4),
    ) {
        // As the runtime sizes it: a reader of the newest with subsampling N needs N slots.
        let buffer = OutputBuffer::with_slots("p.out", capacity, capacity.max(subsampling as usize));
        let mut consumers = Vec::new();
        for (index, policy) in policies.iter().enumerate() {
            let signal = Arc::new(RunSignal::new());
            let mut config = ReaderConfig::new(*policy, format!("link{index}"));
            config.subsampling = subsampling;
            let mut reader = buffer.attach(config, Arc::clone(&signal));
            let pause_micros = reader_pauses.get(index % reader_pauses.len()).copied().unwrap_or(0) * 50;
            consumers.push(thread::Builder::new().name("identity".to_owned()).spawn(move || {
                signal.bind_current_thread();
                let mut last_sequence = None;
                let mut last_counters = reader.counters();
                loop {
                    match reader.read(true) {
                        Ok(sample) => {
                            let c = reader.counters();
                            assert!(c.balanced(), "{c:?}");
                            assert!(c.queued <= capacity as u64, "queued beyond the share: {c:?}");
                            assert_eq!(sample.sequence % u64::from(subsampling), 0, "not kept: {c:?}");
                            let before = last_counters;
                            assert!(
                                c.written >= before.written && c.read + c.repeated > before.read + before.repeated
                                    && c.skipped >= before.skipped && c.overwritten >= before.overwritten,
                                "counters went back: {before:?} then {c:?}"
                            );
                            last_counters = c;
                            // Queueing policies never go backwards; Sampling may repeat.
                            if let Some(last) = last_sequence {
                                assert!(sample.sequence >= last);
                            }
                            last_sequence = Some(sample.sequence);
                        }
                        Err(_) => return reader.counters(),
                    }
                    if pause_micros > 0 {
                        thread::sleep(Duration::from_micros(pause_micros));
                    }
                }
            }).expect("starting a thread"));
        }
        let writer = Arc::new(RunSignal::new());
        writer.bind_current_thread();
        for sequence in 0..writes {
            let sample = Sample { payload: Payload::I64(sequence as i64), timestamp: Timestamp(sequence as i64), time_of_issue: Timestamp(sequence as i64), sequence };
            buffer.write(sample, &writer).unwrap();
            if sequence % writer_pause_every == 0 {
                thread::sleep(Duration::from_micros(100));
            }
        }
        // Let NeverSkipping readers drain, then end the stream so every reader returns.
        buffer.close();
        for consumer in consumers {
            let c = consumer.join().unwrap();
            prop_assert!(c.balanced(), "{:?}", c);
            prop_assert_eq!(c.written, writes);
        }
    }
}

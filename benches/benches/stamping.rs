//! Benchmark 5 — the cost of stamping a sample.
//!
//! `Context::write` stamps a sample's timestamp and time of issue from one read of the runtime clock (an
//! `Arc<dyn Clock>`). Measured here: that stamping (one `dyn Clock::now()` into both fields of a `Sample`),
//! against a bare `RealTimeClock::now()`, the same through `Arc<dyn Clock>`, and a bare `Instant::now()`.
//! For context: stamping with two clock reads, and the whole `Context::write` into an output nobody reads
//! (stamp, type check, lock, ring slot). Per-call times come from batches of 1000 calls; the percentiles
//! are over batches.

use std::collections::BTreeMap;
use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, nanos, print_latency, size};
use kairos_sdk_core::host::{ContextParts, OutputBuffer};
use kairos_sdk_core::{Clock, Context, DataType, Payload, RealTimeClock, RunSignal, Sample};

const BATCH: u32 = 1_000;

/// Per-call times of `op`, one figure per batch.
fn per_call(batches: usize, mut op: impl FnMut(u64)) -> Percentiles {
    let mut times = Vec::with_capacity(batches);
    let mut i = 0_u64;
    for _ in 0..batches {
        let start = Instant::now();
        for _ in 0..BATCH {
            op(i);
            i += 1;
        }
        times.push(nanos(start.elapsed()) / f64::from(BATCH));
    }
    Percentiles::of(&mut times)
}

fn context(clock: Arc<dyn Clock>) -> Context {
    let output =
        kairos_sdk_core::host::output_port("out", Some(DataType::F64), OutputBuffer::new("bench.out", 16), 1);
    kairos_sdk_core::host::context(ContextParts {
        id: "bench".to_owned(),
        inputs: Vec::new(),
        outputs: vec![output],
        properties: BTreeMap::new(),
        clock,
        signal: Arc::new(RunSignal::new()),
    })
}

fn main() {
    let batches = size(2_000, 20_000);
    header(
        "5. stamping cost",
        "single thread, no wake-up (cost of the clock reads on the write path)",
        &format!("{batches} batches of {BATCH} calls per run"),
    );
    let real = RealTimeClock::new();
    let shared: Arc<dyn Clock> = RealTimeClock::shared();
    let mut ctx = context(Arc::clone(&shared));
    let mut instant = LatencySeries::new("baseline: Instant::now()");
    let mut concrete = LatencySeries::new("baseline: RealTimeClock::now()");
    let mut dynamic = LatencySeries::new("baseline: Arc<dyn Clock>::now()");
    let mut stamp = LatencySeries::new("ours: stamp a Sample from one dyn clock read");
    let mut two_reads = LatencySeries::new("context: stamp with two clock reads");
    let mut write = LatencySeries::new("context: whole Context::write, no reader");
    // Warm-up.
    let _ = per_call(batches / 10, |_| {
        black_box(shared.now());
    });
    for _ in 0..kairos_benches::repetitions() {
        instant.reps.push(per_call(batches, |_| {
            black_box(Instant::now());
        }));
        concrete.reps.push(per_call(batches, |_| {
            black_box(black_box(&real).now());
        }));
        dynamic.reps.push(per_call(batches, |_| {
            black_box(black_box(&shared).now());
        }));
        stamp.reps.push(per_call(batches, |i| {
            let now = black_box(&shared).now();
            black_box(Sample {
                payload: Payload::F64(i as f64),
                timestamp: now,
                time_of_issue: now,
                sequence: i,
            });
        }));
        two_reads.reps.push(per_call(batches, |i| {
            let clock = black_box(&shared);
            black_box(Sample {
                payload: Payload::F64(i as f64),
                timestamp: clock.now(),
                time_of_issue: clock.now(),
                sequence: i,
            });
        }));
        write.reps.push(per_call(batches, |i| {
            let _ = black_box(ctx.write(0_usize, Payload::F64(i as f64)));
        }));
    }
    print_latency(&[&instant, &concrete, &dynamic, &stamp, &two_reads, &write]);
    let mut ratios = Ratios::new();
    let goal = Some(Goal::AtMost(1.1));
    ratios.add(
        "p50 stamp / dyn clock read",
        kairos_benches::ratio_spread(&stamp, &dynamic, |p| p.p50),
        goal,
    );
    ratios.add(
        "p50 stamp / RealTimeClock::now",
        kairos_benches::ratio_spread(&stamp, &concrete, |p| p.p50),
        goal,
    );
    ratios.add(
        "p50 stamp / Instant::now",
        kairos_benches::ratio_spread(&stamp, &instant, |p| p.p50),
        None,
    );
    ratios.add(
        "p50 two reads / dyn clock read",
        kairos_benches::ratio_spread(&two_reads, &dynamic, |p| p.p50),
        None,
    );
    ratios.add(
        "p50 Context::write / dyn clock read",
        kairos_benches::ratio_spread(&write, &dynamic, |p| p.p50),
        None,
    );
    ratios.print();
}

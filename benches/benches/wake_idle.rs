//! Benchmark 1 — one link, reader idle 1 ms between samples (the sensor case).
//!
//! A writer thread writes one sample every millisecond; a reader thread sleeps in a blocking read and
//! wakes when it arrives. Latency = the reader's clock read after the read returns − the writer's clock
//! read just before it writes. Baselines: the same hand-over through a raw `Mutex<Option<_>>` + `Condvar`,
//! and through an atomic slot + `thread::park`/`unpark` (one futex wake-up).

use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::{Arc, Barrier, Condvar, Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, print_latency, size, sleep_until};
use kairos_sdk::{
    Clock, OutputBuffer, Payload, ReaderConfig, ReaderPolicy, RealTimeClock, RunSignal, Sample, Timestamp,
};

const PERIOD: Duration = Duration::from_millis(1);

struct Plan {
    warmup: usize,
    samples: usize,
}

/// Runs the writer's 1 kHz schedule; `write` is given the clock reading just before it writes.
fn write_paced(plan: &Plan, clock: &RealTimeClock, mut write: impl FnMut(i64)) {
    let start = Instant::now() + PERIOD;
    for i in 0..plan.warmup + plan.samples {
        sleep_until(start + PERIOD * i as u32);
        write(clock.now().as_nanos());
    }
}

/// Keeps the measured part of a reader's latencies (the warm-up dropped).
fn measured(plan: &Plan, latencies: &[i64]) -> Percentiles {
    let mut values: Vec<f64> = latencies.iter().skip(plan.warmup).map(|&l| l as f64).collect();
    Percentiles::of(&mut values)
}

fn run_ours(plan: &Plan, clock: &Arc<RealTimeClock>) -> Percentiles {
    let buffer = OutputBuffer::new("sensor.out", 16);
    let reader_signal = Arc::new(RunSignal::new());
    let writer_signal = Arc::new(RunSignal::new());
    writer_signal.bind_current_thread();
    let mut reader = buffer.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "sensor.out -> sink.in"),
        Arc::clone(&reader_signal),
    );
    let ready = Arc::new(Barrier::new(2));
    let reader_thread = {
        let (clock, ready) = (Arc::clone(clock), Arc::clone(&ready));
        thread::spawn(move || {
            kairos_benches::pin_current_thread(1);
            reader_signal.bind_current_thread();
            ready.wait();
            let mut latencies = Vec::new();
            while let Ok(sample) = reader.read(false) {
                latencies.push(clock.now().nanos_since(sample.timestamp));
            }
            latencies
        })
    };
    ready.wait();
    let mut sequence = 0;
    write_paced(plan, clock, |now| {
        let mut sample = Sample::new(Payload::I64(sequence), Timestamp::from_nanos(now));
        sample.sequence = sequence as u64;
        sequence += 1;
        // A FIFO reader never makes the writer wait, so the write cannot fail.
        let _ = buffer.write(sample, &writer_signal);
    });
    buffer.close();
    let latencies = reader_thread.join().expect("reader thread panicked");
    measured(plan, &latencies)
}

fn run_condvar(plan: &Plan, clock: &Arc<RealTimeClock>) -> Percentiles {
    let slot = Arc::new((Mutex::new((None::<i64>, false)), Condvar::new()));
    let reader_thread = {
        let (clock, slot) = (Arc::clone(clock), Arc::clone(&slot));
        thread::spawn(move || {
            kairos_benches::pin_current_thread(1);
            let (mutex, condvar) = &*slot;
            let mut latencies = Vec::new();
            let mut guard = mutex.lock().unwrap_or_else(PoisonError::into_inner);
            loop {
                if let Some(written) = guard.0.take() {
                    latencies.push(clock.now().as_nanos() - written);
                } else if guard.1 {
                    break;
                } else {
                    guard = condvar.wait(guard).unwrap_or_else(PoisonError::into_inner);
                }
            }
            latencies
        })
    };
    let (mutex, condvar) = &*slot;
    write_paced(plan, clock, |now| {
        mutex.lock().unwrap_or_else(PoisonError::into_inner).0 = Some(now);
        condvar.notify_one();
    });
    mutex.lock().unwrap_or_else(PoisonError::into_inner).1 = true;
    condvar.notify_one();
    let latencies = reader_thread.join().expect("reader thread panicked");
    measured(plan, &latencies)
}

fn run_park(plan: &Plan, clock: &Arc<RealTimeClock>) -> Percentiles {
    // 0 means empty; clock readings are nanoseconds since the epoch, never 0.
    let slot = Arc::new(AtomicI64::new(0));
    let done = Arc::new(AtomicBool::new(false));
    let reader_thread = {
        let (clock, slot, done) = (Arc::clone(clock), Arc::clone(&slot), Arc::clone(&done));
        thread::spawn(move || {
            kairos_benches::pin_current_thread(1);
            let mut latencies = Vec::new();
            loop {
                let written = slot.swap(0, Ordering::AcqRel);
                if written != 0 {
                    latencies.push(clock.now().as_nanos() - written);
                } else if done.load(Ordering::Acquire) {
                    break;
                } else {
                    thread::park();
                }
            }
            latencies
        })
    };
    let reader = reader_thread.thread().clone();
    write_paced(plan, clock, |now| {
        slot.store(now, Ordering::Release);
        reader.unpark();
    });
    done.store(true, Ordering::Release);
    reader.unpark();
    let latencies = reader_thread.join().expect("reader thread panicked");
    measured(plan, &latencies)
}

fn main() {
    kairos_benches::pin_current_thread(0);
    let plan = Plan {
        warmup: size(50, 200),
        samples: size(250, 6_000),
    };
    header(
        "1. one link, reader idle 1 ms between samples",
        "reader idle when the sample arrives (blocking reader, writer at 1 kHz)",
        &format!(
            "{} samples per run after {} warm-up; latency = read return − write start",
            plan.samples, plan.warmup
        ),
    );
    println!("{}", kairos_benches::pinning_note());
    let clock = Arc::new(RealTimeClock::new());
    let mut ours = LatencySeries::new("ours: OutputBuffer write → Reader::read (FIFO)");
    let mut condvar = LatencySeries::new("baseline: Mutex<Option> + Condvar");
    let mut park = LatencySeries::new("baseline: atomic slot + park/unpark");
    for _ in 0..kairos_benches::repetitions() {
        // Interleaved, so slow drifts of the shared machine hit every variant alike.
        ours.reps.push(run_ours(&plan, &clock));
        condvar.reps.push(run_condvar(&plan, &clock));
        park.reps.push(run_park(&plan, &clock));
    }
    print_latency(&[&ours, &condvar, &park]);
    let mut ratios = Ratios::new();
    for (base, label) in [(&park, "park/unpark"), (&condvar, "condvar")] {
        ratios.add(
            format!("p50 ours / {label}"),
            kairos_benches::ratio_spread(&ours, base, |p| p.p50),
            Some(Goal::AtMost(1.1)),
        );
        ratios.add(
            format!("p99 ours / {label}"),
            kairos_benches::ratio_spread(&ours, base, |p| p.p99),
            Some(Goal::AtMost(1.3)),
        );
    }
    ratios.print();
}

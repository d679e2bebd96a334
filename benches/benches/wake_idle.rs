//! Benchmark 1 — one link, reader idle 1 ms between samples (the sensor case).
//!
//! A writer thread writes one sample every millisecond; a reader thread sleeps in a blocking read and
//! wakes when it arrives. Latency = the reader's clock read after the read returns − the writer's clock
//! read just before it writes. Baselines: the same hand-over through a raw `Mutex<VecDeque<_>>` + `Condvar`,
//! and through a ring of atomics + `thread::park`/`unpark` (one futex wake-up). All three queue, so a
//! late reader still sees every sample and the slow wake-ups stay in the figures.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::{Arc, Barrier, Condvar, Mutex, PoisonError};
use std::thread;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, print_latency, size, sleep_until};
use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{Clock, Payload, ReaderPolicy, RealTimeClock, RunSignal, Sample, Timestamp};

const PERIOD: Duration = Duration::from_millis(1);

/// One variant's run: the measured latencies of one chunk, in nanoseconds.
type Variant = fn(&Plan, &Arc<RealTimeClock>) -> Vec<f64>;

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
fn measured(plan: &Plan, latencies: &[i64]) -> Vec<f64> {
    latencies.iter().skip(plan.warmup).map(|&l| l as f64).collect()
}

fn run_ours(plan: &Plan, clock: &Arc<RealTimeClock>) -> Vec<f64> {
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
        thread::Builder::new()
            .name("wake_idle".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                reader_signal.bind_current_thread();
                ready.wait();
                let mut latencies = Vec::new();
                while let Ok(sample) = reader.read(false) {
                    latencies.push(clock.now().nanos_since(sample.timestamp));
                }
                latencies
            })
            .expect("starting a thread")
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

fn run_condvar(plan: &Plan, clock: &Arc<RealTimeClock>) -> Vec<f64> {
    // A queue, not a single slot: a reader late by more than a period must still see every sample,
    // or the slowest wake-ups would drop out of the figures.
    let shared = Arc::new((Mutex::new((VecDeque::<i64>::new(), false)), Condvar::new()));
    let reader_thread = {
        let (clock, shared) = (Arc::clone(clock), Arc::clone(&shared));
        thread::Builder::new()
            .name("wake_idle".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                let (mutex, condvar) = &*shared;
                let mut latencies = Vec::new();
                let mut guard = mutex.lock().unwrap_or_else(PoisonError::into_inner);
                loop {
                    if let Some(written) = guard.0.pop_front() {
                        latencies.push(clock.now().as_nanos() - written);
                    } else if guard.1 {
                        break;
                    } else {
                        guard = condvar.wait(guard).unwrap_or_else(PoisonError::into_inner);
                    }
                }
                latencies
            })
            .expect("starting a thread")
    };
    let (mutex, condvar) = &*shared;
    write_paced(plan, clock, |now| {
        mutex
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .0
            .push_back(now);
        condvar.notify_one();
    });
    mutex.lock().unwrap_or_else(PoisonError::into_inner).1 = true;
    condvar.notify_one();
    let latencies = reader_thread.join().expect("reader thread panicked");
    measured(plan, &latencies)
}

/// A single-producer ring of atomics: the writer stores a slot, publishes its count, and unparks.
struct AtomicRing {
    slots: Vec<AtomicI64>,
    published: AtomicU64,
    done: AtomicBool,
}

impl AtomicRing {
    fn slot(&self, sequence: u64) -> Option<&AtomicI64> {
        self.slots.get((sequence % self.slots.len() as u64) as usize)
    }
}

fn run_park(plan: &Plan, clock: &Arc<RealTimeClock>) -> Vec<f64> {
    let ring = Arc::new(AtomicRing {
        slots: (0..64).map(|_| AtomicI64::new(0)).collect(),
        published: AtomicU64::new(0),
        done: AtomicBool::new(false),
    });
    let reader_thread = {
        let (clock, ring) = (Arc::clone(clock), Arc::clone(&ring));
        thread::Builder::new()
            .name("wake_idle".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                let mut latencies = Vec::new();
                let mut next = 0;
                loop {
                    let published = ring.published.load(Ordering::Acquire);
                    if next < published {
                        let now = clock.now().as_nanos();
                        while next < published {
                            if let Some(slot) = ring.slot(next) {
                                latencies.push(now - slot.load(Ordering::Relaxed));
                            }
                            next += 1;
                        }
                    } else if ring.done.load(Ordering::Acquire) {
                        if ring.published.load(Ordering::Acquire) == next {
                            break;
                        }
                    } else {
                        thread::park();
                    }
                }
                latencies
            })
            .expect("starting a thread")
    };
    let reader = reader_thread.thread().clone();
    let mut sequence = 0;
    write_paced(plan, clock, |now| {
        if let Some(slot) = ring.slot(sequence) {
            slot.store(now, Ordering::Relaxed);
        }
        sequence += 1;
        ring.published.store(sequence, Ordering::Release);
        reader.unpark();
    });
    ring.done.store(true, Ordering::Release);
    reader.unpark();
    let latencies = reader_thread.join().expect("reader thread panicked");
    measured(plan, &latencies)
}

fn main() {
    kairos_benches::pin_current_thread(false);
    let plan = Plan {
        warmup: size(30, 50),
        samples: size(150, 1_500),
    };
    let chunks = size(1, 4);
    header(
        "1. one link, reader idle 1 ms between samples",
        "reader idle when the sample arrives (blocking reader, writer at 1 kHz)",
        &format!(
            "{} samples per repetition and variant, in {chunks} interleaved chunk(s) of {} after {} warm-up each; \
             latency = read return − write start",
            chunks * plan.samples,
            plan.samples,
            plan.warmup
        ),
    );
    println!("{}", kairos_benches::pinning_note());
    let clock = Arc::new(RealTimeClock::new());
    let mut ours = LatencySeries::new("ours: OutputBuffer write → Reader::read (FIFO)");
    let mut condvar = LatencySeries::new("baseline: Mutex<VecDeque> + Condvar");
    let mut park = LatencySeries::new("baseline: atomic ring + park/unpark");
    let variants: [Variant; 3] = [run_ours, run_condvar, run_park];
    for rep in 0..kairos_benches::repetitions() {
        let mut values: [Vec<f64>; 3] = Default::default();
        // Short chunks, interleaved and in a rotating order, so the shared machine's drifts and any
        // order effect hit every variant alike.
        for chunk in 0..chunks {
            for step in 0..variants.len() {
                let which = (rep + chunk + step) % variants.len();
                if let (Some(run), Some(into)) = (variants.get(which), values.get_mut(which)) {
                    into.extend(run(&plan, &clock));
                }
            }
        }
        for (series, mut values) in [&mut ours, &mut condvar, &mut park].into_iter().zip(values) {
            series.reps.push(Percentiles::of(&mut values));
        }
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

//! Benchmark 2 — one link, back-to-back: a ping-pong between two threads.
//!
//! Thread A writes into buffer AB; thread B reads it and writes it back into buffer BA; A reads it. One
//! way = round trip / 2, timed per round trip. Blocking mode: both readers sleep in `Reader::read` (a
//! wake-up per hop), against a condvar ping-pong and a park/unpark ping-pong. Spinning mode, for context:
//! both readers spin on `Reader::try_read`, against two threads spinning on one atomic (a cache-line
//! ping-pong).

use std::hint::spin_loop;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Barrier, Condvar, Mutex, PoisonError};
use std::thread;
use std::time::Instant;

use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, nanos, print_latency, size};
use kairos_sdk_core::host::{OutputBuffer, Reader, ReaderConfig};
use kairos_sdk_core::{Payload, ReaderPolicy, RunSignal, Sample, Timestamp};

#[derive(Clone, Copy)]
struct Plan {
    warmup: usize,
    rounds: usize,
}

impl Plan {
    fn total(self) -> usize {
        self.warmup + self.rounds
    }
}

/// Times `rounds` calls of `round_trip`, after the warm-up; returns the one-way percentiles.
fn time_rounds(plan: Plan, mut round_trip: impl FnMut(u64)) -> Percentiles {
    let mut one_way = Vec::with_capacity(plan.rounds);
    for i in 0..plan.total() {
        let start = Instant::now();
        round_trip(i as u64);
        let elapsed = start.elapsed();
        if i >= plan.warmup {
            one_way.push(nanos(elapsed) / 2.0);
        }
    }
    Percentiles::of(&mut one_way)
}

fn sample(value: u64) -> Sample {
    Sample::new(Payload::I64(value as i64), Timestamp::ZERO)
}

/// Reads one sample, blocking or spinning.
fn take(reader: &mut Reader, spin: bool) -> Option<Sample> {
    if !spin {
        return reader.read(false).ok();
    }
    let mut spins: u32 = 0;
    loop {
        if let Some(sample) = reader.try_read() {
            return Some(sample);
        }
        // Checking for the end takes the lock too: do it rarely, not on every spin.
        spins = spins.wrapping_add(1);
        if spins.is_multiple_of(4096) && reader.is_exhausted() {
            return None;
        }
        spin_loop();
    }
}

fn run_ours(plan: Plan, spin: bool) -> Percentiles {
    let (ab, ba) = (OutputBuffer::new("a.out", 16), OutputBuffer::new("b.out", 16));
    let (signal_a, signal_b) = (Arc::new(RunSignal::new()), Arc::new(RunSignal::new()));
    signal_a.bind_current_thread();
    let mut from_b = ba.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "b.out -> a.in"),
        Arc::clone(&signal_a),
    );
    let mut from_a = ab.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "a.out -> b.in"),
        Arc::clone(&signal_b),
    );
    let ready = Arc::new(Barrier::new(2));
    let echo = {
        let (ba, ready) = (ba.clone(), Arc::clone(&ready));
        thread::Builder::new()
            .name("ping_pong".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                signal_b.bind_current_thread();
                ready.wait();
                while let Some(sample) = take(&mut from_a, spin) {
                    let _ = ba.write(sample, &signal_b);
                }
            })
            .expect("starting a thread")
    };
    ready.wait();
    let result = time_rounds(plan, |i| {
        let _ = ab.write(sample(i), &signal_a);
        let _ = take(&mut from_b, spin);
    });
    ab.close();
    echo.join().expect("echo thread panicked");
    result
}

fn run_condvar(plan: Plan) -> Percentiles {
    // The turn: odd = B's move, even = A's move; u64::MAX = stop.
    let shared = Arc::new((Mutex::new(0_u64), Condvar::new(), Condvar::new()));
    let echo = {
        let shared = Arc::clone(&shared);
        thread::Builder::new()
            .name("ping_pong".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                let (mutex, to_a, to_b) = &*shared;
                let mut turn = mutex.lock().unwrap_or_else(PoisonError::into_inner);
                loop {
                    if *turn == u64::MAX {
                        break;
                    }
                    if *turn % 2 == 1 {
                        *turn += 1;
                        to_a.notify_one();
                    }
                    turn = to_b.wait(turn).unwrap_or_else(PoisonError::into_inner);
                }
            })
            .expect("starting a thread")
    };
    let (mutex, to_a, to_b) = &*shared;
    let result = time_rounds(plan, |i| {
        let mut turn = mutex.lock().unwrap_or_else(PoisonError::into_inner);
        *turn = 2 * i + 1;
        to_b.notify_one();
        while *turn != 2 * i + 2 {
            turn = to_a.wait(turn).unwrap_or_else(PoisonError::into_inner);
        }
    });
    *mutex.lock().unwrap_or_else(PoisonError::into_inner) = u64::MAX;
    to_b.notify_one();
    echo.join().expect("echo thread panicked");
    result
}

/// Park/unpark (`spin` false) or pure spinning (`spin` true) on one atomic turn counter.
fn run_atomic(plan: Plan, spin: bool) -> Percentiles {
    let turn = Arc::new(AtomicU64::new(0));
    let main_thread = thread::current();
    let echo = {
        let turn = Arc::clone(&turn);
        thread::Builder::new()
            .name("ping_pong".to_owned())
            .spawn(move || {
                kairos_benches::pin_current_thread(true);
                loop {
                    let now = turn.load(Ordering::Acquire);
                    if now == u64::MAX {
                        break;
                    }
                    if now % 2 == 1 {
                        turn.store(now + 1, Ordering::Release);
                        if !spin {
                            main_thread.unpark();
                        }
                    } else if spin {
                        spin_loop();
                    } else {
                        thread::park();
                    }
                }
            })
            .expect("starting a thread")
    };
    let echo_thread = echo.thread().clone();
    let result = time_rounds(plan, |i| {
        turn.store(2 * i + 1, Ordering::Release);
        if !spin {
            echo_thread.unpark();
        }
        while turn.load(Ordering::Acquire) != 2 * i + 2 {
            if spin {
                spin_loop();
            } else {
                thread::park();
            }
        }
    });
    turn.store(u64::MAX, Ordering::Release);
    echo_thread.unpark();
    echo.join().expect("echo thread panicked");
    result
}

fn main() {
    kairos_benches::pin_current_thread(false);
    let blocking = Plan {
        warmup: size(200, 2_000),
        rounds: size(2_000, 50_000),
    };
    let spinning = Plan {
        warmup: size(200, 2_000),
        rounds: size(5_000, 100_000),
    };
    header(
        "2. one link, back-to-back ping-pong",
        "back-to-back, blocking reader (a wake-up per hop); spinning reader for context",
        &format!(
            "{} round trips per run (blocking), {} (spinning); figure = round trip / 2",
            blocking.rounds, spinning.rounds
        ),
    );
    println!("{}", kairos_benches::pinning_note());
    let mut ours = LatencySeries::new("ours: OutputBuffer + Reader::read, blocking");
    let mut condvar = LatencySeries::new("baseline: Mutex + 2 Condvars");
    let mut park = LatencySeries::new("baseline: atomic turn + park/unpark");
    let mut ours_spin = LatencySeries::new("ours: OutputBuffer + try_read, spinning");
    let mut atomic_spin = LatencySeries::new("baseline: atomic turn, spinning");
    for _ in 0..kairos_benches::repetitions() {
        ours.reps.push(run_ours(blocking, false));
        condvar.reps.push(run_condvar(blocking));
        park.reps.push(run_atomic(blocking, false));
        ours_spin.reps.push(run_ours(spinning, true));
        atomic_spin.reps.push(run_atomic(spinning, true));
    }
    print_latency(&[&ours, &condvar, &park, &ours_spin, &atomic_spin]);
    let mut ratios = Ratios::new();
    for (base, label) in [(&park, "park/unpark"), (&condvar, "condvar")] {
        ratios.add(
            format!("blocking p50 ours / {label}"),
            kairos_benches::ratio_spread(&ours, base, |p| p.p50),
            Some(Goal::AtMost(1.2)),
        );
        ratios.add(
            format!("blocking mean ours / {label}"),
            kairos_benches::ratio_spread(&ours, base, |p| p.mean),
            Some(Goal::AtMost(1.2)),
        );
        ratios.add(
            format!("blocking p99 ours / {label}"),
            kairos_benches::ratio_spread(&ours, base, |p| p.p99),
            None,
        );
    }
    ratios.add(
        "spinning p50 ours / atomic",
        kairos_benches::ratio_spread(&ours_spin, &atomic_spin, |p| p.p50),
        None,
    );
    ratios.print();
}

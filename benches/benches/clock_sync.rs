//! Benchmark 16 — clock synchronisation on loopback: a master and a slave (`kairos_clock_sync`, the code
//! `kairos serve --clock-master` / `--clock-slave-of` runs), each run in a process of its own (this
//! benchmark run again with `KAIROS_CLOCK_BENCH_RUN` set), the slave started 250 ms off.
//! On one machine the true offset is known: the slave's clock minus the wall clock the master answers
//! from. Reported: how long the slave takes to lock, and the offset error sampled every 10 ms afterwards,
//! for a slave whose crystal agrees with the master's and for one that runs 100 ppm fast (the test-only
//! drift, the rate estimated from the exchanges).

#![allow(
    clippy::unwrap_used,
    reason = "a failure here is a broken benchmark, not something to carry on from"
)]

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use kairos_benches::{Percentiles, Spread, header, size};
use kairos_sdk_core::{Clock as _, ClockState, DisciplinedClock};

fn wall_now() -> i64 {
    i64::try_from(SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_nanos()).unwrap()
}

/// One run in this process: a fresh master and slave drifting `drift_ppm`; the time to lock (ms) and the
/// |offset error| percentiles (ns) over `seconds`.
fn one_run(drift_ppm: f64, seconds: u64) -> (f64, Percentiles) {
    let master = kairos_clock_sync::run_master("127.0.0.1:0").unwrap();
    let clock = Arc::new(
        DisciplinedClock::new(kairos_clock_sync::MASTER_SOURCE)
            .trusting_each_reference()
            .estimating_rate()
            .drifted_by_ppm(drift_ppm)
            .shifted_by(250_000_000),
    );
    let started = Instant::now();
    kairos_clock_sync::run_slave(master, Arc::clone(&clock)).unwrap();
    while clock.clock_status().state != ClockState::Locked || clock.clock_status().references < 8 {
        std::thread::sleep(Duration::from_millis(1));
    }
    let lock_ms = started.elapsed().as_secs_f64() * 1e3;
    // The rate is estimated once the exchanges span 2 s: the error is measured from then on.
    std::thread::sleep(Duration::from_secs(2));
    let until = Instant::now() + Duration::from_secs(seconds);
    let mut run: Vec<f64> = Vec::new();
    while Instant::now() < until {
        // Read the two clocks back to back, in both orders, and keep the mean: the read itself is not the
        // error.
        let (a, w, b) = (clock.now().as_nanos(), wall_now(), clock.now().as_nanos());
        #[allow(clippy::cast_precision_loss, reason = "nanoseconds of error")]
        run.push((i64::midpoint(a, b) - w).abs() as f64);
        std::thread::sleep(Duration::from_millis(10));
    }
    (lock_ms, Percentiles::of(&mut run))
}

/// Set in the child processes, each of which makes one run: `DRIFT_PPM SECONDS`.
const RUN_ALONE: &str = "KAIROS_CLOCK_BENCH_RUN";

fn main() {
    if let Ok(run) = std::env::var(RUN_ALONE) {
        let mut fields = run.split_whitespace();
        let drift_ppm: f64 = fields.next().unwrap().parse().unwrap();
        let seconds: u64 = fields.next().unwrap().parse().unwrap();
        let (lock_ms, errors) = one_run(drift_ppm, seconds);
        println!("{lock_ms} {} {} {}", errors.p50, errors.p99, errors.max);
        return;
    }
    header(
        "16. Clock synchronisation on loopback",
        "a slave started 250 ms off, drifting 0 or 100 ppm: time to lock, then |offset error| every 10 ms",
        "kairos::clock_sync master and slave in a process of their own per run; the error is the slave's clock minus the wall clock",
    );
    let seconds = size(3, 20);
    println!("| slave's drift | figure | median [min–max] over runs | goal |");
    println!("| --- | --- | --- | --- |");
    for drift_ppm in [0.0, 100.0] {
        let mut locks = Vec::new();
        let mut errors = Vec::new();
        for _ in 0..kairos_benches::repetitions() {
            // A process per run: the pairs of earlier runs would go on exchanging beside it.
            let output = std::process::Command::new(std::env::current_exe().unwrap())
                .env(RUN_ALONE, format!("{drift_ppm} {seconds}"))
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&output.stdout);
            let figures: Vec<f64> = text
                .lines()
                .last()
                .unwrap_or_default()
                .split_whitespace()
                .filter_map(|f| f.parse().ok())
                .collect();
            let [lock_ms, p50, p99, max] = figures[..] else {
                panic!("a run printed {text}");
            };
            locks.push(lock_ms);
            errors.push(Percentiles {
                p50,
                p99,
                max,
                ..Percentiles::default()
            });
        }
        let spread = |figure: fn(&Percentiles) -> f64| {
            Spread::of(errors.iter().map(figure)).show(|ns| format!("{:.2} µs", ns / 1e3))
        };
        println!(
            "| {drift_ppm} ppm | time to lock | {} | < 2000 ms |",
            Spread::of(locks.iter().copied()).show(|ms| format!("{ms:.0} ms"))
        );
        println!(
            "| {drift_ppm} ppm | \\|offset error\\| p50 | {} | ≤ 1 µs |",
            spread(|p| p.p50)
        );
        println!(
            "| {drift_ppm} ppm | \\|offset error\\| p99 | {} | ≤ 10 µs |",
            spread(|p| p.p99)
        );
        println!(
            "| {drift_ppm} ppm | \\|offset error\\| max | {} | |",
            spread(|p| p.max)
        );
    }
}

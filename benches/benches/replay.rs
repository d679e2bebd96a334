//! Benchmark 8 — replay timing: how far from its schedule the player emits each sample when replaying in
//! real time at 1×, against how late the machine wakes from a sleep (the floor any sleeping scheduler sits
//! on), both measured in the same run.
//!
//! The recording holds one number every 5 ms. The player runs on the real-time clock, exactly as in a
//! diagram (birth, then `core` in a loop on this thread); each emitted sample's time of issue is read by the
//! player's own clock when it writes. Error of sample i = (`issue[i]` − `issue[0]`) − i × 5 ms. The baseline
//! sleeps 5 ms with `std::thread::sleep` the same number of times and records how late it woke.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_benches::{
    Goal, LatencySeries, Percentiles, Ratios, header, nanos, print_latency, ratio_spread, size,
};
use kairos_pack_recording::player::Player;
use kairos_pack_recording::recorder::Recorder;
use kairos_sdk_core::harness::Harness;
use kairos_sdk_core::host::{ContextHost as _, ContextParts, OutputBuffer, ReaderConfig};
use kairos_sdk_core::{
    Component, ComponentError, Payload, ReaderPolicy, RealTimeClock, RunSignal, Timestamp, Value,
};

const PERIOD_MS: i64 = 5;

fn record(path: &Path, samples: i64) -> Option<()> {
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).ok()?;
    for i in 0..samples {
        harness.push(
            "in1",
            Payload::F64(i as f64),
            Timestamp::from_millis(1_000 + i * PERIOD_MS),
        );
    }
    harness.finish().ok()?;
    Some(())
}

/// How late each sample was emitted against its schedule, in nanoseconds.
fn replay_errors(path: &Path) -> Option<Percentiles> {
    let mut properties: BTreeMap<String, Value> = Player::info()
        .properties
        .iter()
        .map(|p| (p.name.clone(), p.default.clone()))
        .collect();
    properties.insert("path".to_owned(), Value::Text(path.display().to_string()));
    properties.insert("times".to_owned(), Value::Text("replay".to_owned()));
    let info = Player::describe(&properties).ok()?;
    let signal = Arc::new(RunSignal::new());
    signal.bind_current_thread();
    let mut readers = Vec::new();
    let outputs = info
        .outputs
        .iter()
        .map(|o| {
            let buffer = OutputBuffer::with_slots(format!("player.{}", o.name), 16, 1 << 16);
            let mut config = ReaderConfig::new(ReaderPolicy::Fifo, format!("player.{} -> bench", o.name));
            config.capacity = Some(1 << 16);
            readers.push(buffer.attach(config, Arc::new(RunSignal::new())));
            kairos_sdk_core::host::output_port(o.name.clone(), Some(o.data_type.clone()), buffer, 1)
        })
        .collect();
    let mut ctx = kairos_sdk_core::host::context(ContextParts {
        id: "player".to_owned(),
        inputs: Vec::new(),
        outputs,
        properties,
        clock: RealTimeClock::shared(),
        signal,
    });
    let mut player = Player::default();
    player.birth(&mut ctx).ok()?;
    loop {
        ctx.begin_cycle();
        match player.core(&mut ctx) {
            Ok(()) | Err(ComponentError::Interrupted | ComponentError::NoData) => {}
            Err(ComponentError::EndOfStream) => break,
            Err(_) => return None,
        }
    }
    let issued: Vec<Timestamp> = readers
        .iter_mut()
        .flat_map(|r| std::iter::from_fn(|| r.try_read()))
        .map(|s| s.time_of_issue)
        .collect();
    let first = *issued.first()?;
    let mut errors: Vec<f64> = issued
        .iter()
        .enumerate()
        .skip(1)
        .map(|(i, t)| (t.nanos_since(first) - i as i64 * PERIOD_MS * 1_000_000).unsigned_abs() as f64)
        .collect();
    Some(Percentiles::of(&mut errors))
}

fn sleep_overshoot(count: usize) -> Percentiles {
    let period = Duration::from_millis(PERIOD_MS as u64);
    let mut late: Vec<f64> = (0..count)
        .map(|_| {
            let deadline = Instant::now() + period;
            std::thread::sleep(period);
            nanos(Instant::now().saturating_duration_since(deadline))
        })
        .collect();
    Percentiles::of(&mut late)
}

fn main() {
    let samples = size(400, 1_200);
    header(
        "8. Replay timing: the player at 1× against the machine's sleep overshoot",
        "real time, one thread, timing error of each emitted sample",
        &format!("{samples} samples every {PERIOD_MS} ms"),
    );
    let Ok(dir) = tempfile::tempdir() else { return };
    let path = dir.path().join("timing.mcap");
    if record(&path, samples as i64).is_none() {
        println!("recording failed");
        return;
    }
    let mut ours = LatencySeries::new("ours: player emission error");
    let mut baseline = LatencySeries::new("baseline: thread::sleep overshoot");
    for repetition in 0..kairos_benches::repetitions() {
        if repetition % 2 == 1 {
            baseline.reps.push(sleep_overshoot(samples));
        }
        let Some(errors) = replay_errors(&path) else {
            println!("replay failed");
            return;
        };
        ours.reps.push(errors);
        if repetition % 2 == 0 {
            baseline.reps.push(sleep_overshoot(samples));
        }
    }
    print_latency(&[&baseline, &ours]);
    let mut ratios = Ratios::new();
    ratios.add(
        "p99: player error / sleep overshoot",
        ratio_spread(&ours, &baseline, |p| p.p99),
        Some(Goal::AtMost(1.5)),
    );
    ratios.add(
        "p50: player error / sleep overshoot",
        ratio_spread(&ours, &baseline, |p| p.p50),
        None,
    );
    ratios.print();
}

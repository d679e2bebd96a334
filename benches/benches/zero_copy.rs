//! Benchmark 4 — zero copy through a 5-stage chain.
//!
//! source → 5 pass-through stages → sink, each stage a thread that reads its input buffer (FIFO, blocking)
//! and writes the sample on with a new time of issue, as `Context::forward` does; 6 `OutputBuffer` links
//! in all. The main thread is source and sink: it writes one sample and waits for it at the end of the
//! chain; time per sample = that round. An 8 MiB `Payload::Image` against an 8-byte `Payload::F64`: with
//! shared payloads the two must take the same time. Two modes: the source idle 2 ms between samples (each
//! hop is a wake-up of an idle reader), and back-to-back. For context: one `memcpy` of 8 MiB, hot
//! in cache and from memory.

use std::hint::black_box;
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, nanos, print_latency, size, time};
use kairos_sdk_core::host::{OutputBuffer, ReaderConfig};
use kairos_sdk_core::{Clock, Image, Payload, PixelFormat, ReaderPolicy, RealTimeClock, RunSignal, Sample};

const STAGES: usize = 5;
const IMAGE_BYTES: usize = 8 << 20;

#[derive(Clone, Copy)]
struct Plan {
    warmup: usize,
    samples: usize,
    /// `Some(gap)`: the source waits until `gap` after the previous sample was sent; `None`: back-to-back.
    period: Option<Duration>,
}

/// Starts a pass-through stage reading `input` and writing `output`; it closes `output` at the end.
fn stage(
    input: &OutputBuffer,
    output: OutputBuffer,
    clock: Arc<RealTimeClock>,
    index: usize,
) -> thread::JoinHandle<()> {
    let signal = Arc::new(RunSignal::new());
    let mut reader = input.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, format!("stage{index}.in")),
        Arc::clone(&signal),
    );
    thread::Builder::new()
        .name("zero_copy".to_owned())
        .spawn(move || {
            signal.bind_current_thread();
            while let Ok(mut sample) = reader.read(false) {
                sample.time_of_issue = clock.now();
                let _ = output.write(sample, &signal);
            }
            output.close();
        })
        .expect("starting a thread")
}

fn run_chain(plan: Plan, payload: &Payload, clock: &Arc<RealTimeClock>) -> Percentiles {
    let buffers: Vec<OutputBuffer> = (0..=STAGES)
        .map(|i| OutputBuffer::new(format!("link{i}.out"), 16))
        .collect();
    let stages: Vec<thread::JoinHandle<()>> = buffers
        .windows(2)
        .enumerate()
        .filter_map(|(index, pair)| match pair {
            [input, output] => Some(stage(input, output.clone(), Arc::clone(clock), index + 1)),
            _ => None,
        })
        .collect();
    let signal = Arc::new(RunSignal::new());
    signal.bind_current_thread();
    let (Some(first), Some(last)) = (buffers.first(), buffers.last()) else {
        return Percentiles::default();
    };
    let mut sink = last.attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "sink.in"),
        Arc::clone(&signal),
    );
    let mut per_sample = Vec::with_capacity(plan.samples);
    let mut next = Instant::now();
    for i in 0..plan.warmup + plan.samples {
        if let Some(period) = plan.period {
            kairos_benches::sleep_until(next);
            next = Instant::now() + period;
        }
        let start = Instant::now();
        let mut sample = Sample::new(payload.clone(), clock.now());
        sample.sequence = i as u64;
        let _ = first.write(sample, &signal);
        let arrived = sink.read(false);
        let elapsed = start.elapsed();
        black_box(&arrived);
        if i >= plan.warmup {
            per_sample.push(nanos(elapsed));
        }
    }
    first.close();
    for handle in stages {
        handle.join().expect("stage thread panicked");
    }
    Percentiles::of(&mut per_sample)
}

/// Times `copies` copies of 8 MiB. `buffers` source/target pairs are used in turn: 1 keeps both hot in
/// the cache, 4 (64 MiB) makes each copy come from and go to memory.
fn run_memcpy(copies: usize, buffers: usize) -> Percentiles {
    let sources: Vec<Vec<u8>> = (0..buffers).map(|i| vec![i as u8 + 1; IMAGE_BYTES]).collect();
    // Filled, not zeroed, so every page is mapped before timing starts.
    let mut targets: Vec<Vec<u8>> = (0..buffers).map(|_| vec![9_u8; IMAGE_BYTES]).collect();
    let mut times = Vec::with_capacity(copies);
    for i in 0..copies + buffers {
        let (Some(source), Some(target)) = (sources.get(i % buffers), targets.get_mut(i % buffers)) else {
            continue;
        };
        let start = Instant::now();
        target.copy_from_slice(black_box(source));
        black_box(target);
        // The first round over the buffers is the warm-up.
        if i >= buffers {
            times.push(nanos(start.elapsed()));
        }
    }
    Percentiles::of(&mut times)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let idle = Plan {
        warmup: size(10, 100),
        samples: size(100, 2_000),
        period: Some(Duration::from_millis(2)),
    };
    let back_to_back = Plan {
        warmup: size(100, 500),
        samples: size(1_000, 10_000),
        period: None,
    };
    header(
        "4. zero copy: 8 MiB image vs 8-byte scalar through a 5-stage chain",
        "reader idle when the sample arrives (source at 500 Hz; 6 wake-ups per sample); back-to-back too",
        &format!(
            "{STAGES} pass-through stages, {} links; {} samples per run idle, {} back-to-back",
            STAGES + 1,
            idle.samples,
            back_to_back.samples
        ),
    );
    let clock = Arc::new(RealTimeClock::new());
    let image = Payload::Image(Image::packed(
        2048,
        1024,
        PixelFormat::Rgba8,
        vec![7_u8; IMAGE_BYTES],
    )?);
    let scalar = Payload::F64(1.5);
    let mut image_idle = LatencySeries::new("8 MiB image, idle");
    let mut scalar_idle = LatencySeries::new("8-byte F64, idle");
    let mut image_b2b = LatencySeries::new("8 MiB image, back-to-back");
    let mut scalar_b2b = LatencySeries::new("8-byte F64, back-to-back");
    let mut memcpy = LatencySeries::new("context: memcpy of 8 MiB, hot in cache");
    let mut memcpy_cold = LatencySeries::new("context: memcpy of 8 MiB, from memory");
    for _ in 0..kairos_benches::repetitions() {
        image_idle.reps.push(run_chain(idle, &image, &clock));
        scalar_idle.reps.push(run_chain(idle, &scalar, &clock));
        image_b2b.reps.push(run_chain(back_to_back, &image, &clock));
        scalar_b2b.reps.push(run_chain(back_to_back, &scalar, &clock));
        memcpy.reps.push(run_memcpy(size(10, 40), 1));
        memcpy_cold.reps.push(run_memcpy(size(10, 40), 4));
    }
    print_latency(&[
        &image_idle,
        &scalar_idle,
        &image_b2b,
        &scalar_b2b,
        &memcpy,
        &memcpy_cold,
    ]);
    let mut ratios = Ratios::new();
    let goal = Some(Goal::AtMost(1.1));
    ratios.add(
        "idle p50 image / scalar",
        kairos_benches::ratio_spread(&image_idle, &scalar_idle, |p| p.p50),
        goal,
    );
    ratios.add(
        "idle mean image / scalar",
        kairos_benches::ratio_spread(&image_idle, &scalar_idle, |p| p.mean),
        goal,
    );
    ratios.add(
        "back-to-back p50 image / scalar",
        kairos_benches::ratio_spread(&image_b2b, &scalar_b2b, |p| p.p50),
        goal,
    );
    ratios.add(
        "back-to-back mean image / scalar",
        kairos_benches::ratio_spread(&image_b2b, &scalar_b2b, |p| p.mean),
        goal,
    );
    ratios.print();
    let copy = memcpy_cold.spread(|p| p.p50).median;
    println!(
        "context: copying the image at each of the {} links would add ≈ {} per sample (from memory)",
        STAGES + 1,
        time(copy * (STAGES + 1) as f64)
    );
    Ok(())
}

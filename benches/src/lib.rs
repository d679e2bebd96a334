//! The harness shared by the Kairos benchmarks: run sizes, percentiles, spread over repetitions,
//! ratios against a baseline measured in the same run, and plain-text tables.
//!
//! Every benchmark is a `harness = false` binary under `benches/`. `KAIROS_BENCH_QUICK=1` makes each one
//! run for about a second; without it they run the full, documented size.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use kairos_sdk_core::host::{ContextParts, OutputBuffer, Reader};
use kairos_sdk_core::{ComponentInfo, Context, RealTimeClock, RunSignal, Value};

/// Whether the quick (CI-sized) mode was asked for with `KAIROS_BENCH_QUICK=1`.
pub fn quick() -> bool {
    std::env::var("KAIROS_BENCH_QUICK").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// Picks the quick or the full value.
pub fn size<T>(quick_value: T, full_value: T) -> T {
    if quick() { quick_value } else { full_value }
}

/// How many repetitions to run: 3 in quick mode, 5 in full mode.
pub fn repetitions() -> usize {
    size(3, 5)
}

/// The machine, as the protocol asks to record it: core count and CPU model.
pub fn machine() -> String {
    let cores = cores();
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|line| line.starts_with("model name"))
                .and_then(|line| line.split_once(':'))
                .map(|(_, model)| model.trim().to_owned())
        })
        .unwrap_or_else(|| "unknown CPU".to_owned());
    format!("{cores} cores, {model}")
}

/// The machine's core count, read once, before any thread is pinned (pinning narrows what
/// `available_parallelism` reports).
pub fn cores() -> usize {
    static CORES: OnceLock<usize> = OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, std::num::NonZero::get))
}

/// Where two-thread benchmarks run their threads, from `KAIROS_BENCH_PIN`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pinning {
    /// The default: the writer (or initiator) on CPU 0, the reader (or echo) on CPU 1, so every hand-over
    /// crosses cores, as the protocol's reference figures do.
    CrossCore,
    /// `KAIROS_BENCH_PIN=same`: both on CPU 0, so a hand-over is a context switch on one core.
    SameCore,
    /// `KAIROS_BENCH_PIN=0`: the scheduler places the threads (a mix of the two, changing run to run).
    Free,
}

/// The pinning asked for (cross-core unless the machine has a single core).
pub fn pinning() -> Pinning {
    match std::env::var("KAIROS_BENCH_PIN").as_deref() {
        Ok("0" | "off" | "no") => Pinning::Free,
        Ok("same") => Pinning::SameCore,
        _ if cores() < 2 => Pinning::Free,
        _ => Pinning::CrossCore,
    }
}

/// Pins the calling thread for its role: `reader` false for the writer/initiator, true for the
/// reader/echo thread. Returns whether it pinned.
pub fn pin_current_thread(reader: bool) -> bool {
    let cpu = match pinning() {
        Pinning::Free => return false,
        Pinning::SameCore => 0,
        Pinning::CrossCore => usize::from(reader),
    };
    let mut set = nix::sched::CpuSet::new();
    set.set(cpu).is_ok() && nix::sched::sched_setaffinity(nix::unistd::Pid::from_raw(0), &set).is_ok()
}

/// The pinning as the headers print it.
pub fn pinning_note() -> &'static str {
    match pinning() {
        Pinning::CrossCore => "threads pinned cross-core: writer/initiator on CPU 0, reader/echo on CPU 1",
        Pinning::SameCore => "threads pinned same-core: both on CPU 0 (KAIROS_BENCH_PIN=same)",
        Pinning::Free => "threads not pinned (KAIROS_BENCH_PIN=0)",
    }
}

/// Prints the benchmark's title, its latency mode and the run size.
pub fn header(title: &str, mode: &str, detail: &str) {
    println!();
    println!("=== {title} ===");
    println!("mode: {mode}");
    println!(
        "{detail}; {} repetitions ({} mode); machine: {}",
        repetitions(),
        if quick() { "quick" } else { "full" },
        machine()
    );
}

/// Sleeps until `deadline`; returns at once if it has passed.
pub fn sleep_until(deadline: Instant) {
    let now = Instant::now();
    if deadline > now {
        std::thread::sleep(deadline - now);
    }
}

/// Nanoseconds in a duration, as a float.
pub fn nanos(duration: Duration) -> f64 {
    duration.as_secs_f64() * 1e9
}

/// The distribution of one run: percentiles in nanoseconds (or any unit the caller uses).
#[derive(Debug, Clone, Copy, Default)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest value.
    pub max: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// How many values.
    pub count: usize,
}

impl Percentiles {
    /// The percentiles of `values` (sorted in place).
    pub fn of(values: &mut [f64]) -> Self {
        if values.is_empty() {
            return Percentiles::default();
        }
        values.sort_by(f64::total_cmp);
        let rank = |q: f64| -> f64 {
            let index = ((values.len() - 1) as f64 * q).round() as usize;
            values.get(index).copied().unwrap_or(f64::NAN)
        };
        Percentiles {
            p50: rank(0.5),
            p99: rank(0.99),
            max: values.last().copied().unwrap_or(f64::NAN),
            mean: values.iter().sum::<f64>() / values.len() as f64,
            count: values.len(),
        }
    }
}

/// Median, minimum and maximum of one figure over the repetitions.
#[derive(Debug, Clone, Copy)]
pub struct Spread {
    /// Median over repetitions.
    pub median: f64,
    /// Smallest repetition.
    pub min: f64,
    /// Largest repetition.
    pub max: f64,
}

impl Spread {
    /// The spread of `values`.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut values: Vec<f64> = values.into_iter().collect();
        values.sort_by(f64::total_cmp);
        let median = if values.is_empty() {
            f64::NAN
        } else if values.len() % 2 == 1 {
            values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
        } else {
            let upper = values.len() / 2;
            let a = values.get(upper - 1).copied().unwrap_or(f64::NAN);
            let b = values.get(upper).copied().unwrap_or(f64::NAN);
            f64::midpoint(a, b)
        };
        Spread {
            median,
            min: values.first().copied().unwrap_or(f64::NAN),
            max: values.last().copied().unwrap_or(f64::NAN),
        }
    }

    /// `median [min–max]`, each value shown by `show`.
    pub fn show(&self, show: impl Fn(f64) -> String) -> String {
        format!("{} [{}–{}]", show(self.median), show(self.min), show(self.max))
    }
}

/// A duration in nanoseconds shown with a readable unit.
pub fn time(ns: f64) -> String {
    if !ns.is_finite() {
        "n/a".to_owned()
    } else if ns < 1_000.0 {
        format!("{ns:.1} ns")
    } else if ns < 1_000_000.0 {
        format!("{:.2} µs", ns / 1e3)
    } else {
        format!("{:.3} ms", ns / 1e6)
    }
}

/// A ratio shown as `1.07×`.
pub fn ratio(value: f64) -> String {
    format!("{value:.2}×")
}

/// A rate in messages per second shown in millions.
pub fn rate(per_second: f64) -> String {
    format!("{:.2} M/s", per_second / 1e6)
}

/// A plain-text table with aligned columns.
#[derive(Debug, Default)]
pub struct Table {
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these column headers.
    pub fn new(headers: &[&str]) -> Self {
        Table {
            rows: vec![headers.iter().map(|h| (*h).to_owned()).collect()],
        }
    }

    /// Adds a row.
    pub fn row(&mut self, cells: Vec<String>) {
        self.rows.push(cells);
    }

    /// Prints the table as Markdown, so it can be pasted into BENCHMARKS.md.
    pub fn print(&self) {
        let columns = self.rows.iter().map(Vec::len).max().unwrap_or(0);
        let widths: Vec<usize> = (0..columns)
            .map(|c| {
                self.rows
                    .iter()
                    .filter_map(|r| r.get(c))
                    .map(|cell| cell.chars().count())
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        for (index, row) in self.rows.iter().enumerate() {
            let mut line = String::from("|");
            for (c, width) in widths.iter().enumerate() {
                let cell = row.get(c).map_or("", String::as_str);
                let pad = width.saturating_sub(cell.chars().count());
                let _ = write!(line, " {cell}{} |", " ".repeat(pad));
            }
            println!("{line}");
            if index == 0 {
                let mut rule = String::from("|");
                for width in &widths {
                    let _ = write!(rule, " {} |", "-".repeat(*width));
                }
                println!("{rule}");
            }
        }
    }
}

/// One variant of a latency benchmark and its percentiles in each repetition.
#[derive(Debug, Clone)]
pub struct LatencySeries {
    /// What was measured (`ours: OutputBuffer FIFO`).
    pub name: String,
    /// One entry per repetition.
    pub reps: Vec<Percentiles>,
}

impl LatencySeries {
    /// An empty series.
    pub fn new(name: impl Into<String>) -> Self {
        LatencySeries {
            name: name.into(),
            reps: Vec::new(),
        }
    }

    /// The spread of one figure over the repetitions.
    pub fn spread(&self, figure: impl Fn(&Percentiles) -> f64) -> Spread {
        Spread::of(self.reps.iter().map(figure))
    }
}

/// Prints p50, p99, max and mean of each series, as median [min–max] over the repetitions.
pub fn print_latency(series: &[&LatencySeries]) {
    let mut table = Table::new(&["variant", "p50", "p99", "max", "mean", "n/rep"]);
    for s in series {
        table.row(vec![
            s.name.clone(),
            s.spread(|p| p.p50).show(time),
            s.spread(|p| p.p99).show(time),
            s.spread(|p| p.max).show(time),
            s.spread(|p| p.mean).show(time),
            s.reps.first().map_or(0, |p| p.count).to_string(),
        ]);
    }
    table.print();
}

/// The per-repetition ratio `ours / baseline` of one figure.
pub fn ratio_spread(
    ours: &LatencySeries,
    baseline: &LatencySeries,
    figure: impl Fn(&Percentiles) -> f64,
) -> Spread {
    Spread::of(
        ours.reps
            .iter()
            .zip(&baseline.reps)
            .map(|(o, b)| figure(o) / figure(b)),
    )
}

/// A goal on a ratio: `≤ limit` (lower is better) or `≥ limit` (higher is better).
#[derive(Debug, Clone, Copy)]
pub enum Goal {
    /// The ratio must not exceed the limit.
    AtMost(f64),
    /// The ratio must reach the limit.
    AtLeast(f64),
}

impl Goal {
    /// `≤ 1.10×` or `≥ 1.50×`.
    pub fn show(self) -> String {
        match self {
            Goal::AtMost(limit) => format!("≤ {}", ratio(limit)),
            Goal::AtLeast(limit) => format!("≥ {}", ratio(limit)),
        }
    }

    /// Whether the (median) ratio meets the goal.
    pub fn met_by(self, value: f64) -> bool {
        match self {
            Goal::AtMost(limit) => value <= limit,
            Goal::AtLeast(limit) => value >= limit,
        }
    }

    /// `met` or `MISSED`, for the median ratio.
    pub fn verdict(self, value: f64) -> &'static str {
        if self.met_by(value) { "met" } else { "MISSED" }
    }
}

/// A table of ratios: one row per (label, ratio spread, goal).
#[derive(Debug, Default)]
pub struct Ratios {
    rows: Vec<(String, Spread, Option<Goal>)>,
}

impl Ratios {
    /// An empty table.
    pub fn new() -> Self {
        Ratios::default()
    }

    /// Adds a ratio, held against `goal` if any.
    pub fn add(&mut self, label: impl Into<String>, spread: Spread, goal: Option<Goal>) {
        self.rows.push((label.into(), spread, goal));
    }

    /// Prints the ratios with their goals and verdicts.
    pub fn print(&self) {
        let mut table = Table::new(&["ratio", "median [min–max] over reps", "goal", "verdict"]);
        for (label, spread, goal) in &self.rows {
            table.row(vec![
                label.clone(),
                spread.show(ratio),
                goal.map_or_else(|| "—".to_owned(), Goal::show),
                goal.map_or_else(|| "context".to_owned(), |g| g.verdict(spread.median).to_owned()),
            ]);
        }
        table.print();
    }
}

/// The baseline of the recording benchmarks: a bare loop over the `mcap` crate that encodes each of
/// `count` RGB8 frames (`pixels(index)`, `width`×`height`, rows packed) as `foxglove.RawImage`, writes it
/// uncompressed to `path` and syncs the finished file, as the recorder does. The previous file at `path` is
/// removed before the clock starts (truncating hundreds of megabytes is no part of a measurement). Returns
/// message bytes written per second.
pub fn bare_mcap_rate<'p>(
    path: &std::path::Path,
    width: u32,
    height: u32,
    count: usize,
    pixels: impl Fn(usize) -> &'p [u8],
) -> Option<f64> {
    bare_mcap_rate_compressed(path, (width, height), count, pixels, None)
}

/// [`bare_mcap_rate`] with chunks compressed by `compression`: message bytes per second.
pub fn bare_mcap_rate_compressed<'p>(
    path: &std::path::Path,
    (width, height): (u32, u32),
    count: usize,
    pixels: impl Fn(usize) -> &'p [u8],
    compression: Option<mcap::Compression>,
) -> Option<f64> {
    use foxglove::Encode as _;
    let _ = std::fs::remove_file(path);
    let file = std::fs::File::create(path).ok()?;
    let started = Instant::now();
    let mut writer = mcap::WriteOptions::new()
        .compression(compression)
        .create(std::io::BufWriter::new(file))
        .ok()?;
    let schema = foxglove::schemas::RawImage::get_schema()?;
    let schema_id = writer
        .add_schema(&schema.name, &schema.encoding, &schema.data)
        .ok()?;
    let channel = writer
        .add_channel(schema_id, "camera.image", "protobuf", &BTreeMap::new())
        .ok()?;
    let mut buffer = Vec::new();
    let mut bytes = 0;
    for index in 0..count {
        buffer.clear();
        let message = foxglove::schemas::RawImage {
            timestamp: None,
            frame_id: "camera.image".to_owned(),
            width,
            height,
            encoding: "rgb8".to_owned(),
            step: width * 3,
            data: foxglove::bytes::Bytes::copy_from_slice(pixels(index)),
        };
        message.encode(&mut buffer).ok()?;
        let time = index as u64 * 33_000_000;
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: index as u32,
            log_time: time,
            publish_time: time,
        };
        writer.write_to_known_channel(&header, &buffer).ok()?;
        bytes += buffer.len();
    }
    writer.finish().ok()?;
    writer.into_inner().into_inner().ok()?.sync_all().ok()?;
    Some(bytes as f64 / started.elapsed().as_secs_f64())
}

/// Starts `kairos serve` with the built-in packs in this process, on a free loopback port, without a token;
/// returns its address once it listens.
pub fn start_kairos_serve() -> Option<std::net::SocketAddr> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("lib".to_owned())
        .spawn(move || {
            let options = kairos_server::ServeOptions {
                listen: "127.0.0.1:0".to_owned(),
                token_file: None,
                monitor_token_file: None,
                diagram: None,
                start: false,
                max_connections: 16,
                stop_with_stdin: false,
                temporary_token: false,
                clock_master: None,
                clock_slave_of: None,
                clock_system: None,
                tls: None,
                shipped_pack_folder: None,
                host_tokens: kairos_server::HostTokens::Protected,
                foxglove: None,
                foxglove_backlog: kairos_server::DEFAULT_FOXGLOVE_BACKLOG,
            };
            let _ = kairos_server::serve_with(kairos::builtin_registry(), &options, move |address| {
                let _ = tx.send(address);
            });
        })
        .expect("starting a thread");
    rx.recv_timeout(Duration::from_secs(10)).ok()
}

/// A context for `info` with `properties` over the defaults: every output writes into a buffer of its own
/// (nobody reads, so writes never wait); `inputs` feed its inputs in order.
pub fn component_context(
    info: &ComponentInfo,
    properties: &[(&str, Value)],
    inputs: Vec<Option<Reader>>,
) -> (Context, Vec<OutputBuffer>) {
    let mut values: BTreeMap<String, Value> = info
        .properties
        .iter()
        .map(|p| (p.name.clone(), p.default.clone()))
        .collect();
    for (name, value) in properties {
        values.insert((*name).to_owned(), value.clone());
    }
    let buffers: Vec<OutputBuffer> = info
        .outputs
        .iter()
        // As the engine sizes them when no connection asks for more.
        .map(|o| OutputBuffer::new(format!("bench.{}", o.name), o.default_buffer_size))
        .collect();
    let outputs = info
        .outputs
        .iter()
        .zip(&buffers)
        .map(|(o, b)| {
            kairos_sdk_core::host::output_port(o.name.clone(), Some(o.data_type.clone()), b.clone(), 1)
        })
        .collect();
    let inputs = info
        .inputs
        .iter()
        .zip(inputs)
        .map(|(i, reader)| kairos_sdk_core::host::input_port(i.name.clone(), reader))
        .collect();
    let ctx = kairos_sdk_core::host::context(ContextParts {
        id: "bench".to_owned(),
        inputs,
        outputs,
        properties: values,
        clock: RealTimeClock::shared(),
        signal: Arc::new(RunSignal::new()),
    });
    (ctx, buffers)
}

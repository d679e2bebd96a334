//! Benchmark 23: 900 components, a thread each against execution groups, in the same run.
//!
//! The shipped diagrams `examples/scale/threaded_900.ron` (100 chains of a 100 Hz sine through 8 gains,
//! a thread per component) and `examples/scale/grouped_900.ron` (the same, each chain a group), and the
//! threaded one made sequential (every component in one group), run one after the other in each
//! repetition, as `kairos run` runs them: the built-in packs, real time, nothing pinned. Figures over a
//! measured window after a warm-up: the process's CPU (user + system, from `/proc/self/stat`), its
//! threads, the resident memory the diagram added, samples lost on links (overwritten or skipped) and
//! missed ticks, and the hop: along each chain, the link latency (write time − the sine's stamp) of its
//! last link minus that of its first, over the 7 hand-offs between them, the median over chains.
//!
//! Then 10 000 components in 100 groups (1 000 chains of a 10 Hz sine through 9 gains, ten chains a
//! group): the time from the diagram's text to every thread started, and the rate the sines keep.

use std::path::Path;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, Ratios, Spread, Table, header, machine, repetitions, size, time};
use kairos_diagram::Diagram;
use kairos_runtime::{Engine, StatsSnapshot};
use kairos_sdk_core::{RealTimeClock, Registry};

/// The process's CPU time so far (user and system), in nanoseconds.
fn process_cpu_nanos() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // The fields after the command name, which is in parentheses and may hold spaces.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks = |index: usize| {
        fields
            .get(index)
            .and_then(|f| f.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    // utime and stime are fields 14 and 15 of the whole line, 12 and 13 after the name; 100 ticks a second.
    (ticks(11) + ticks(12)) * 1e7
}

/// A field of `/proc/self/status` (`VmRSS`, in kB; `Threads`).
fn status_field(name: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|line| {
            let rest = line.strip_prefix(name)?.strip_prefix(':')?;
            rest.split_whitespace().next()?.parse().ok()
        })
        .unwrap_or(f64::NAN)
}

struct Measured {
    cpu_share: f64,
    threads: f64,
    added_rss_mb: f64,
    lost: u64,
    missed_ticks: u64,
    hop_ns: f64,
}

/// Samples lost on the diagram's links between two snapshots.
fn lost(before: &StatsSnapshot, after: &StatsSnapshot) -> u64 {
    let total = |s: &StatsSnapshot| -> u64 {
        s.links
            .iter()
            .map(|l| l.counters.overwritten + l.counters.skipped)
            .sum()
    };
    total(after).saturating_sub(total(before))
}

fn missed(snapshot: &StatsSnapshot) -> u64 {
    snapshot.components.iter().map(|c| c.missed_ticks).sum()
}

/// The median over chains of (last link's p50 latency − first link's) / the hand-offs between them.
fn hop_nanos(snapshot: &StatsSnapshot, chains: usize, gains: usize) -> f64 {
    let p50 = |link: &str| {
        snapshot
            .links
            .iter()
            .find(|l| l.link == link)
            .map(|l| l.counters.latency.p50_nanos as f64)
    };
    let per_chain = (0..chains).filter_map(|c| {
        let first = p50(&format!("c{c:02}_sine.out -> c{c:02}_gain1.in"))?;
        let last = p50(&format!(
            "c{c:02}_gain{}.out -> c{c:02}_gain{gains}.in",
            gains - 1
        ))?;
        Some((last - first) / (gains - 1) as f64)
    });
    Spread::of(per_chain).median
}

fn run(diagram: &Diagram, registry: &Registry, warm_up: Duration, window: Duration) -> Measured {
    let rss_before = status_field("VmRSS");
    let mut engine = Engine::build(diagram, registry, RealTimeClock::shared()).expect("the diagram builds");
    engine.start().expect("the diagram starts");
    std::thread::sleep(warm_up);
    let before = engine.snapshot();
    let cpu_before = process_cpu_nanos();
    let started = Instant::now();
    std::thread::sleep(window);
    let cpu = process_cpu_nanos() - cpu_before;
    let seconds = started.elapsed().as_secs_f64();
    let after = engine.snapshot();
    let measured = Measured {
        cpu_share: cpu * 1e-9 / seconds,
        threads: status_field("Threads"),
        added_rss_mb: (status_field("VmRSS") - rss_before) / 1024.0,
        lost: lost(&before, &after),
        missed_ticks: missed(&after).saturating_sub(missed(&before)),
        hop_ns: hop_nanos(&after, 100, 8),
    };
    engine.stop();
    measured
}

/// 1 000 chains of a 10 Hz sine through 9 gains, ten chains a group, as diagram text.
fn ten_thousand() -> String {
    use std::fmt::Write as _;
    let mut text =
        String::from("Diagram(format: 1, packs: [Pack(name: \"core\", version: \"^0.1\")], components: [\n");
    let mut links = String::new();
    for chain in 0..1000 {
        let group = chain / 10;
        let _ = writeln!(
            text,
            "Component(id: \"s{chain}\", type: \"core.sine\", group: \"g{group}\", properties: {{\"rate\": 10.0}}),"
        );
        let mut previous = format!("s{chain}");
        for gain in 1..=9 {
            let id = format!("s{chain}_{gain}");
            let _ = writeln!(
                text,
                "Component(id: \"{id}\", type: \"core.gain\", group: \"g{group}\"),"
            );
            let _ = writeln!(links, "Connection(from: \"{previous}.out\", to: \"{id}.in\"),");
            previous = id;
        }
    }
    text.push_str("], connections: [\n");
    text.push_str(&links);
    text.push_str("])\n");
    text
}

fn load(path: &Path) -> Diagram {
    kairos_diagram::load(path).expect("the example loads").1.diagram
}

fn main() {
    header(
        "23. 900 components: a thread each against execution groups",
        "",
        "examples/scale: 100 chains of a 100 Hz sine through 8 gains",
    );
    println!("machine: {}", machine());
    let registry = kairos::builtin_registry();
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/scale");
    let threaded = load(&examples.join("threaded_900.ron"));
    let grouped = load(&examples.join("grouped_900.ron"));
    let mut sequential = threaded.clone();
    sequential.sequential = true;
    let variants = [
        ("threaded", &threaded),
        ("a group per chain", &grouped),
        ("one group (sequential)", &sequential),
    ];
    let warm_up = size(Duration::from_millis(500), Duration::from_secs(2));
    let window = size(Duration::from_secs(1), Duration::from_secs(5));
    let mut results: Vec<Vec<Measured>> = variants.iter().map(|_| Vec::new()).collect();
    for _ in 0..repetitions() {
        for ((_, diagram), into) in variants.iter().zip(&mut results) {
            into.push(run(diagram, &registry, warm_up, window));
        }
    }
    let mut table = Table::new(&[
        "variant",
        "CPU, share of a core",
        "threads",
        "RSS added (MB)",
        "lost",
        "missed ticks",
        "hop p50",
    ]);
    for ((name, _), measured) in variants.iter().zip(&results) {
        let spread = |f: fn(&Measured) -> f64| Spread::of(measured.iter().map(f));
        table.row(vec![
            (*name).to_owned(),
            spread(|m| m.cpu_share * 100.0).show(|v| format!("{v:.1} %")),
            spread(|m| m.threads).show(|v| format!("{v:.0}")),
            spread(|m| m.added_rss_mb).show(|v| format!("{v:.1}")),
            measured.iter().map(|m| m.lost).sum::<u64>().to_string(),
            measured.iter().map(|m| m.missed_ticks).sum::<u64>().to_string(),
            spread(|m| m.hop_ns).show(time),
        ]);
    }
    table.print();
    let mut ratios = Ratios::new();
    let ratio_of = |variant: usize, figure: fn(&Measured) -> f64| {
        Spread::of(
            results
                .get(variant)
                .into_iter()
                .flatten()
                .zip(results.first().into_iter().flatten())
                .map(|(ours, baseline)| figure(ours) / figure(baseline)),
        )
    };
    ratios.add(
        "CPU, a group per chain / threaded",
        ratio_of(1, |m| m.cpu_share),
        None,
    );
    ratios.add("CPU, one group / threaded", ratio_of(2, |m| m.cpu_share), None);
    ratios.add(
        "hop, a group per chain / threaded",
        ratio_of(1, |m| m.hop_ns),
        None,
    );
    ratios.print();
    let grouped_cpu = Spread::of(results.get(1).into_iter().flatten().map(|m| m.cpu_share));
    let hop = Spread::of(results.get(1).into_iter().flatten().map(|m| m.hop_ns));
    println!(
        "goals: grouped ≤ 20 % of a core with 0 losses: {} ({:.1} %, {} lost); a hop in a group ≤ 1 µs p50: {} ({})",
        Goal::AtMost(0.20).verdict(grouped_cpu.median),
        grouped_cpu.median * 100.0,
        results.get(1).into_iter().flatten().map(|m| m.lost).sum::<u64>(),
        Goal::AtMost(1_000.0).verdict(hop.median),
        time(hop.median)
    );

    println!();
    println!("10 000 components in 100 groups (1 000 chains of a 10 Hz sine through 9 gains)");
    let text = ten_thousand();
    let mut loads = Vec::new();
    let mut rates = Vec::new();
    let mut cpus = Vec::new();
    for _ in 0..size(1, 3) {
        let started = Instant::now();
        let diagram = kairos_diagram::parse(&text).expect("the diagram parses").diagram;
        let mut engine = Engine::build(&diagram, &registry, RealTimeClock::shared()).expect("it builds");
        engine.start().expect("it starts");
        loads.push(started.elapsed().as_nanos() as f64);
        std::thread::sleep(warm_up);
        let before = engine.snapshot();
        let cpu_before = process_cpu_nanos();
        let window_started = Instant::now();
        std::thread::sleep(window);
        let seconds = window_started.elapsed().as_secs_f64();
        cpus.push((process_cpu_nanos() - cpu_before) * 1e-9 / seconds);
        let after = engine.snapshot();
        let cycles = |s: &StatsSnapshot| -> u64 {
            s.components
                .iter()
                .filter(|c| c.type_name == "core.sine")
                .map(|c| c.cycles)
                .sum()
        };
        rates.push(cycles(&after).saturating_sub(cycles(&before)) as f64 / 1000.0 / seconds);
        engine.stop();
    }
    let load = Spread::of(loads);
    let rate = Spread::of(rates);
    println!(
        "text to running: {} (goal ≤ 2 s: {}); each sine's rate: {} Hz (goal 10 Hz); CPU: {}",
        load.show(time),
        Goal::AtMost(2e9).verdict(load.median),
        rate.show(|v| format!("{v:.2}")),
        Spread::of(cpus).show(|v| format!("{:.1} %", v * 100.0))
    );
}

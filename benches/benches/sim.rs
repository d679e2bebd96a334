//! Benchmark 25: the closed-loop showcase in simulated time, as fast as it computes.
//!
//! `examples/sim/lane_keeping.ron` run as `kairos run --set vehicle.time_scale=0` runs it: the built-in
//! packs and the example's Python pack (the interpreter `KAIROS_PYTHON` names, with numpy), sequential,
//! nothing pinned. The figure is simulated seconds per wall second, from the engine's start to the
//! simulator's end. The baseline, in the same run: the same diagram open loop (the Python controller and
//! the CAN encoder and decoder removed; the vehicle, the camera and the vision chain as they are), so the
//! ratio is what closing the loop costs.

use std::path::Path;
use std::time::{Duration, Instant};

use kairos_benches::{Ratios, Spread, Table, header, machine, repetitions, size};
use kairos_diagram::{Diagram, Value};
use kairos_runtime::Engine;
use kairos_sdk_core::Registry;

/// The showcase for `seconds` of simulated time, as fast as possible, its CSV in the temporary folder.
fn showcase(path: &Path, seconds: f64) -> Diagram {
    let mut diagram = kairos_diagram::load(path).expect("the example loads").1.diagram;
    let csv = std::env::temp_dir().join("kairos-bench-lane-keeping.csv");
    for component in &mut diagram.components {
        match component.id.as_str() {
            "vehicle" => {
                component
                    .properties
                    .insert("time_scale".to_owned(), Value::F64(0.0));
                component
                    .properties
                    .insert("duration".to_owned(), Value::F64(seconds));
            }
            "csv" => {
                component
                    .properties
                    .insert("path".to_owned(), Value::Text(csv.display().to_string()));
            }
            _ => {}
        }
    }
    diagram
}

/// The showcase without its controller and the CAN path to the vehicle.
fn open_loop(closed: &Diagram) -> Diagram {
    let mut diagram = closed.clone();
    let removed = ["controller", "encoder", "decoder"];
    diagram.components.retain(|c| !removed.contains(&c.id.as_str()));
    diagram.connections.retain(|c| {
        !removed.contains(&c.from.component.as_str()) && !removed.contains(&c.to.component.as_str())
    });
    diagram
}

/// Wall seconds to run `diagram` to the simulator's end.
fn run(diagram: &Diagram, registry: &Registry) -> f64 {
    let clock = kairos_runtime::clock_for(diagram, registry);
    let mut engine = Engine::build(diagram, registry, clock).expect("the diagram builds");
    let started = Instant::now();
    engine.start().expect("the diagram starts");
    while !engine.all_finished() {
        std::thread::sleep(Duration::from_millis(5));
    }
    let wall = started.elapsed().as_secs_f64();
    engine.stop();
    wall
}

fn main() {
    header(
        "25. Lane keeping in closed loop, simulated time as fast as possible",
        "",
        "examples/sim/lane_keeping.ron: 640×480 camera at 20 Hz, vision chain, Python controller, CAN",
    );
    println!("machine: {}", machine());
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sim/lane_keeping.ron");
    let (registry, _) = kairos::registry_with_packs(&[], &[path.as_path()]);
    let seconds = size(20.0, 60.0);
    let closed = showcase(&path, seconds);
    let open = open_loop(&closed);
    // The DBC path in the example is relative to the repository's root, as the README runs it.
    std::env::set_current_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("..")).expect("repository root");
    let mut closed_rates = Vec::new();
    let mut open_rates = Vec::new();
    for _ in 0..repetitions() {
        closed_rates.push(seconds / run(&closed, &registry));
        open_rates.push(seconds / run(&open, &registry));
    }
    let mut table = Table::new(&["variant", "simulated s per wall s"]);
    for (name, rates) in [
        ("closed loop (the showcase)", &closed_rates),
        ("open loop (no controller, no CAN)", &open_rates),
    ] {
        table.row(vec![
            name.to_owned(),
            Spread::of(rates.iter().copied()).show(|v| format!("{v:.2}")),
        ]);
    }
    table.print();
    let mut ratios = Ratios::new();
    ratios.add(
        "closed loop / open loop, simulated s per wall s",
        Spread::of(closed_rates.iter().zip(&open_rates).map(|(c, o)| c / o)),
        None,
    );
    ratios.print();
    println!("{seconds} simulated seconds a run; faster than real time when above 1");
}

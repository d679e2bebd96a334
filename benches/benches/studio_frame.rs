//! Benchmark 11 — one studio frame with a 200-component, 300-connection diagram.
//!
//! Ours: a whole frame of the studio (`StudioApp::show`: menus, palette, inspector, log and the node editor
//! with every node, port and connection in view, the pointer moving over the canvas) plus the tessellation
//! of its shapes into triangles, on one thread. Baselines in the same run: the same window with an empty
//! diagram (what the studio's panels cost alone), and a bare egui frame that paints the same canvas content
//! (200 node boxes with their titles, ports and port names, 300 curves with their policy badges) straight
//! onto a painter, with no interaction, document or widget logic (the raw drawing the editor needs). And the
//! same studio frame with live telemetry for every link and component arriving at 10 Hz (figures drawn on
//! every node and connection, the monitor's history kept). The goal is absolute as well: ≤ 8 ms per frame.

use std::hint::black_box;
use std::time::Instant;

use egui::{Align2, Color32, FontId, Pos2, Rect, Stroke, Vec2};
use kairos_benches::{Goal, LatencySeries, Percentiles, Ratios, header, nanos, print_latency, size};
use kairos_diagram::{ComponentInstance, Connection, Diagram, LibraryInfo, PortRef, Position};
use kairos_studio::{Document, StudioApp};

const BLOCKS: usize = 50;
const WINDOW: Vec2 = Vec2::new(1600.0, 1000.0);

/// 50 blocks of sine, sine → add → csv writer (the csv also takes the previous block's sum): 200
/// components, 300 connections, laid out on a 20 × 10 grid.
fn diagram() -> Diagram {
    let mut diagram = Diagram::default();
    let place = |index: usize| Position {
        x: (index % 20) as f32 * 230.0,
        y: (index / 20) as f32 * 170.0,
    };
    for block in 0..BLOCKS {
        for (offset, (id, type_name)) in [
            (format!("sine{}", 2 * block), "core.sine"),
            (format!("sine{}", 2 * block + 1), "core.sine"),
            (format!("add{block}"), "core.add"),
            (format!("csv{block}"), "core.csv_writer"),
        ]
        .into_iter()
        .enumerate()
        {
            let mut component = ComponentInstance::new(id, type_name);
            component.position = place(4 * block + offset);
            diagram.components.push(component);
        }
        let previous = (block + BLOCKS - 1) % BLOCKS;
        for (from, to) in [
            (format!("sine{}.out", 2 * block), format!("add{block}.a")),
            (format!("sine{}.out", 2 * block + 1), format!("add{block}.b")),
            (format!("sine{}.out", 2 * block), format!("csv{block}.in1")),
            (format!("sine{}.out", 2 * block + 1), format!("csv{block}.in2")),
            (format!("add{block}.out"), format!("csv{block}.in3")),
            (format!("add{previous}.out"), format!("csv{block}.in4")),
        ] {
            let (Some(from), Some(to)) = (PortRef::parse(&from), PortRef::parse(&to)) else {
                continue;
            };
            diagram.connections.push(Connection::new(from, to));
        }
    }
    diagram
}

fn input(frame: usize) -> egui::RawInput {
    // The pointer sweeps the canvas, so hover tests run as they do under a user's hand.
    let x = 300.0 + (frame % 100) as f32 * 11.0;
    egui::RawInput {
        screen_rect: Some(Rect::from_min_size(Pos2::ZERO, WINDOW)),
        events: vec![egui::Event::PointerMoved(Pos2::new(x, 500.0))],
        ..Default::default()
    }
}

/// Telemetry for every link and component of `diagram`, as the runtime sends it; `tick` varies the figures.
/// One link in fifty loses samples, as an overloaded consumer would.
fn telemetry(diagram: &Diagram, tick: u64) -> kairos_protocol::Telemetry {
    kairos_protocol::Telemetry {
        at_ns: i64::try_from(tick).unwrap_or(0) * 100_000_000,
        state: kairos_protocol::RuntimeState::Running,
        links: diagram
            .connections
            .iter()
            .enumerate()
            .map(|(index, c)| kairos_protocol::LinkTelemetry {
                link: format!("{} -> {}", c.from, c.to),
                policy: kairos_diagram::ReaderPolicy::Fifo,
                written: tick * 10,
                read: if index % 50 == 0 { tick * 5 } else { tick * 10 },
                skipped: 0,
                overwritten: if index % 50 == 0 { tick * 5 } else { 0 },
                queued: 0,
                repeated: 0,
                rate_hz: 100.0 + (tick % 7) as f64,
                latency: kairos_protocol::LatencyTelemetry {
                    count: tick * 10,
                    min_ns: 2_000,
                    mean_ns: 9_000,
                    p50_ns: 8_000,
                    p99_ns: 25_000,
                    max_ns: 60_000,
                },
            })
            .collect(),
        components: diagram
            .components
            .iter()
            .map(|c| kairos_protocol::ComponentTelemetry {
                id: c.id.clone(),
                type_name: c.type_name.clone(),
                state: kairos_protocol::ComponentState::Running,
                error: None,
                cycles: tick * 10,
                cycle_rate_hz: 100.0,
                cpu_share: 0.01,
                missed_ticks: 0,
                status: None,
                group: None,
            })
            .collect(),
        clock: None,
        groups: Vec::new(),
        hosts: Vec::new(),
        cross_links: Vec::new(),
    }
}

/// Per-frame time of `frame` (run the pass, tessellate its shapes), over `frames` frames.
fn frames(ctx: &egui::Context, frames: usize, mut frame: impl FnMut(&mut egui::Ui)) -> Percentiles {
    let mut times = Vec::with_capacity(frames);
    for n in 0..frames {
        let start = Instant::now();
        let output = ctx.run_ui(input(n), &mut frame);
        let primitives = ctx.tessellate(output.shapes, output.pixels_per_point);
        black_box(primitives);
        times.push(nanos(start.elapsed()));
    }
    Percentiles::of(&mut times)
}

/// The canvas content painted directly: what the editor draws, without the editor.
fn paint_bare(ui: &mut egui::Ui, diagram: &Diagram, to_screen: egui::emath::TSTransform) {
    let painter = ui.painter();
    let place = |p: Position| to_screen * Pos2::new(p.x, p.y);
    let scale = to_screen.scaling;
    let font = |size: f32| FontId::proportional(size * scale);
    let stroke = Stroke::new(1.0, Color32::GRAY);
    let ports = |c: &ComponentInstance| match c.type_name.as_str() {
        "core.add" => (2, 1),
        "core.csv_writer" => (4, 0),
        _ => (0, 1),
    };
    for connection in &diagram.connections {
        let (Some(a), Some(b)) = (
            diagram.component(&connection.from.component),
            diagram.component(&connection.to.component),
        ) else {
            continue;
        };
        let from = place(a.position) + Vec2::new(180.0, 48.0) * scale;
        let to = place(b.position) + Vec2::new(0.0, 48.0) * scale;
        let bend = ((to.x - from.x).abs() * 0.5).max(40.0 * scale);
        painter.add(egui::epaint::CubicBezierShape::from_points_stroke(
            [from, from + Vec2::new(bend, 0.0), to - Vec2::new(bend, 0.0), to],
            false,
            Color32::TRANSPARENT,
            Stroke::new(2.0 * scale, Color32::LIGHT_BLUE),
        ));
        let middle = from + (to - from) * 0.5;
        painter.rect_filled(
            Rect::from_center_size(middle, Vec2::new(34.0, 16.0) * scale),
            4.0,
            Color32::BLACK,
        );
        painter.text(
            middle,
            Align2::CENTER_CENTER,
            "LoN",
            font(11.0),
            Color32::LIGHT_BLUE,
        );
    }
    for component in &diagram.components {
        let (inputs, outputs) = ports(component);
        let rows = inputs.max(outputs) as f32;
        let min = place(component.position);
        let rect = Rect::from_min_size(min, Vec2::new(180.0, 44.0 + 20.0 * rows) * scale);
        painter.rect_filled(rect, 6.0, Color32::from_gray(30));
        painter.rect_stroke(rect, 6.0, stroke, egui::StrokeKind::Inside);
        painter.text(min, Align2::LEFT_TOP, &component.id, font(14.0), Color32::WHITE);
        painter.text(
            min,
            Align2::LEFT_TOP,
            &component.type_name,
            font(10.5),
            Color32::GRAY,
        );
        for row in 0..inputs.max(outputs) {
            let y = min.y + (48.0 + 20.0 * row as f32) * scale;
            for (present, x) in [(row < inputs, rect.left()), (row < outputs, rect.right())] {
                if present {
                    painter.circle_filled(Pos2::new(x, y), 5.5 * scale, Color32::LIGHT_BLUE);
                    painter.text(
                        Pos2::new(x, y),
                        Align2::LEFT_CENTER,
                        "in1",
                        font(11.5),
                        Color32::WHITE,
                    );
                }
            }
        }
    }
}

fn main() {
    let frame_count = size(60, 300);
    header(
        "11. studio frame, 200 components and 300 connections",
        "single thread, CPU-bound (layout, interaction, painting and tessellation of one frame)",
        &format!("{frame_count} frames per run, {WINDOW:?} window, the whole diagram in view"),
    );
    let library: LibraryInfo = match serde_json::from_str(include_str!("../../studio/tests/library.json")) {
        Ok(library) => library,
        Err(error) => {
            eprintln!("the component library fixture does not parse: {error}");
            return;
        }
    };
    let diagram = diagram();
    let mut document = Document::default();
    document.edit(|d| *d = diagram.clone());
    let mut studio = StudioApp::new(
        document.clone(),
        library.clone(),
        None,
        "benchmark".to_owned(),
        None,
    );
    studio.canvas.fit(&studio.session.document, &library);
    // The same diagram with telemetry arriving: its own studio, so the figures it shows stay out of `ours`.
    let mut live_studio = StudioApp::new(document, library.clone(), None, "benchmark".to_owned(), None);
    live_studio.canvas.fit(&live_studio.session.document, &library);
    let live_ctx = egui::Context::default();
    let mut empty = StudioApp::new(Document::default(), library, None, "benchmark".to_owned(), None);
    let ours_ctx = egui::Context::default();
    let empty_ctx = egui::Context::default();
    let bare_ctx = egui::Context::default();

    // Warm-up: fonts, galley caches, the scene's fit; and the canvas transform the bare painter reuses.
    let _ = frames(&ours_ctx, 20, |ui| studio.show(ui));
    let _ = live_studio.session.monitor.update(&telemetry(&diagram, 0));
    let _ = frames(&live_ctx, 20, |ui| live_studio.show(ui));
    let _ = frames(&empty_ctx, 20, |ui| empty.show(ui));
    let to_screen = {
        let transform = studio.canvas.to_screen(Pos2::new(1.0, 0.0)) - studio.canvas.to_screen(Pos2::ZERO);
        egui::emath::TSTransform::new(studio.canvas.to_screen(Pos2::ZERO).to_vec2(), transform.x)
    };
    let _ = frames(&bare_ctx, 20, |ui| paint_bare(ui, &diagram, to_screen));

    let mut ours = LatencySeries::new("ours: studio frame, 200 components");
    let mut panels = LatencySeries::new("baseline: studio frame, empty diagram");
    let mut bare = LatencySeries::new("baseline: bare painter, same canvas content");
    let mut live = LatencySeries::new("ours: studio frame, telemetry at 10 Hz");
    let mut tick = 0_u64;
    let mut frame_number = 0_u64;
    for _ in 0..kairos_benches::repetitions() {
        ours.reps
            .push(frames(&ours_ctx, frame_count, |ui| studio.show(ui)));
        panels
            .reps
            .push(frames(&empty_ctx, frame_count, |ui| empty.show(ui)));
        bare.reps.push(frames(&bare_ctx, frame_count, |ui| {
            paint_bare(ui, &diagram, to_screen);
        }));
        // Telemetry at 10 Hz with frames at 60 Hz: every sixth frame takes one event in.
        live.reps.push(frames(&live_ctx, frame_count, |ui| {
            frame_number += 1;
            if frame_number.is_multiple_of(6) {
                tick += 1;
                let _ = live_studio.session.monitor.update(&telemetry(&diagram, tick));
            }
            live_studio.show(ui);
        }));
    }
    print_latency(&[&ours, &live, &panels, &bare]);
    let mut ratios = Ratios::new();
    ratios.add(
        "p50 ours / bare painter",
        kairos_benches::ratio_spread(&ours, &bare, |p| p.p50),
        None,
    );
    ratios.add(
        "p50 ours / empty diagram",
        kairos_benches::ratio_spread(&ours, &panels, |p| p.p50),
        None,
    );
    ratios.add(
        "p99 ours with telemetry / 8 ms (the absolute goal)",
        kairos_benches::Spread::of(live.reps.iter().map(|p| p.p99 / 8e6)),
        Some(Goal::AtMost(1.0)),
    );
    ratios.add(
        "p50 ours with telemetry / ours without",
        kairos_benches::ratio_spread(&live, &ours, |p| p.p50),
        None,
    );
    ratios.add(
        "p99 ours / 8 ms (the absolute goal)",
        kairos_benches::Spread::of(ours.reps.iter().map(|p| p.p99 / 8e6)),
        Some(Goal::AtMost(1.0)),
    );
    ratios.print();
}

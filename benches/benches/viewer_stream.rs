//! Benchmark 12 — a 1920×1080 RGB camera at 30 Hz watched in an image viewer, through the socket and through
//! shared memory, against a real `kairos serve` in this process.
//!
//! The studio side is the studio's own code: a `RuntimeClient` (its network thread, and its shared-memory
//! reader thread) and `Viewers` fed with every frame and shown in a headless egui frame at 60 Hz (the frame's
//! conversion to a texture and its tessellation included; the GPU upload is not). Measured over the same
//! window for each transport, interleaved:
//! - the runtime's cost of the stream: CPU time of the server's transport threads (`k:net`, the network and
//!   blocking pools; `k:shm`, the shared-memory publishers), as a share of one core; the camera's own thread
//!   is not counted, it is the same either way;
//! - the studio's cost: its network and shared-memory threads plus the viewer's thread.
//!
//! Three paths: the socket; shared memory with the pixels copied into each iceoryx2 sample; shared memory
//! with the pixels left where the camera drew them (the frame names the camera's shared buffer), which is
//! what the studio uses when it may map the runtime's buffers.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, Ratios, Spread, Table, header, size};
use kairos_protocol::{RequestBody, SampleTransport};
use kairos_studio::client::{ClientEvent, RuntimeClient};
use kairos_studio::viewers::Viewers;

const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const RATE_HZ: f64 = 30.0;

/// CPU time of this process's threads by group of names, from each thread's `schedstat` (nanoseconds on a
/// CPU). Sampled often and summed per thread, so a thread that ends (tokio retires idle blocking threads)
/// keeps what it used up to the last sample.
#[derive(Debug, Default)]
struct CpuMeter {
    last: std::collections::HashMap<String, f64>,
    runtime: f64,
    studio: f64,
}

impl CpuMeter {
    fn sample(&mut self) {
        let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
            return;
        };
        for task in tasks.flatten() {
            let path = task.path();
            let name = std::fs::read_to_string(path.join("comm")).unwrap_or_default();
            let runtime = name.starts_with("k:net") || name.starts_with("k:shm");
            let studio = name.starts_with("studio:net") || name.starts_with("studio:shm");
            if !runtime && !studio {
                continue;
            }
            let on_cpu: f64 = std::fs::read_to_string(path.join("schedstat"))
                .ok()
                .and_then(|s| s.split_whitespace().next().and_then(|f| f.parse().ok()))
                .unwrap_or(0.0);
            let key = task.file_name().to_string_lossy().into_owned();
            let before = self.last.insert(key, on_cpu);
            // A thread seen for the first time counts from now.
            let spent = before.map_or(0.0, |b| (on_cpu - b).max(0.0));
            if runtime {
                self.runtime += spent;
            } else {
                self.studio += spent;
            }
        }
    }
}

fn this_thread_cpu_nanos() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map_or(0.0, |t| t.tv_sec() as f64 * 1e9 + t.tv_nsec() as f64)
}

fn wait_for_reply(client: &RuntimeClient, id: u64) -> Option<kairos_protocol::ReplyBody> {
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(20) {
        for event in client.poll() {
            if let ClientEvent::Reply(answer) = event
                && answer.id == Some(id)
            {
                return answer.outcome.ok();
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

/// How the frames reach the viewer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Path {
    /// Binary messages on the WebSocket.
    Socket,
    /// iceoryx2 samples holding the whole frame, pixels copied in by the publisher.
    SharedCopied,
    /// iceoryx2 samples holding the header and a reference to the camera's own shared pixel buffer (what
    /// the studio asks for when it may map the runtime's buffers).
    SharedInPlace,
}

impl Path {
    fn name(self) -> &'static str {
        match self {
            Path::Socket => "socket",
            Path::SharedCopied => "shared memory, pixels copied",
            Path::SharedInPlace => "shared memory, pixels in place",
        }
    }
}

/// One measurement: (runtime transport CPU share, studio CPU share, frames shown per second).
fn measure(
    address: SocketAddr,
    path: Path,
    window: Duration,
    output: &str,
    data_type: &str,
) -> Option<(f64, f64, f64)> {
    let mut client = RuntimeClient::connect(&format!("ws://{address}"), None, || {});
    let transport = if path == Path::Socket {
        SampleTransport::Socket
    } else {
        SampleTransport::SharedMemory
    };
    let subscribe = client.request(RequestBody::SubscribeSamples {
        outputs: vec![output.to_owned()],
        max_rate_hz: RATE_HZ,
        max_image_width: None,
        transport,
        shared_pixels: path == Path::SharedInPlace,
    });
    let kairos_protocol::ReplyBody::SubscribeSamples(subscribed) = wait_for_reply(&client, subscribe)? else {
        return None;
    };
    if transport == SampleTransport::SharedMemory {
        client.receive_shared(subscribed.services?).ok()?;
    }
    let mut viewers = Viewers::default();
    viewers.open(output.to_owned(), data_type);
    let ctx = egui::Context::default();
    let frame = |ctx: &egui::Context, viewers: &mut Viewers| {
        let output = ctx.run_ui(egui::RawInput::default(), |ui| viewers.show_docked(ui, &[]));
        std::hint::black_box(ctx.tessellate(output.shapes, output.pixels_per_point));
    };
    // Warm up: the stream flowing, the texture made.
    let warm = Instant::now();
    while warm.elapsed() < Duration::from_millis(800) {
        for event in client.poll() {
            if let ClientEvent::Sample(header, payload) = event {
                viewers.receive(&header, &payload);
            }
        }
        frame(&ctx, &mut viewers);
        std::thread::sleep(Duration::from_millis(16));
    }
    let received_before = viewers.list.first().map_or(0, |v| v.received);
    let mut meter = CpuMeter::default();
    meter.sample();
    let main_before = this_thread_cpu_nanos();
    let started = Instant::now();
    let mut next = started;
    let mut frames = 0_u64;
    while started.elapsed() < window {
        frames += 1;
        if frames.is_multiple_of(6) {
            meter.sample();
        }
        for event in client.poll() {
            if let ClientEvent::Sample(header, payload) = event {
                viewers.receive(&header, &payload);
            }
        }
        frame(&ctx, &mut viewers);
        next += Duration::from_micros(16_667);
        if let Some(rest) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(rest);
        }
    }
    meter.sample();
    let seconds = started.elapsed().as_secs_f64();
    let runtime = meter.runtime / 1e9 / seconds;
    let studio = (meter.studio + this_thread_cpu_nanos() - main_before) / 1e9 / seconds;
    let shown = viewers.list.first().map_or(0, |v| v.received) - received_before;
    Some((runtime, studio, shown as f64 / seconds))
}

/// A lidar of 64 × 1600 rays at 30 Hz (up to 102 400 points a scan) into the 3D viewer, over shared memory.
fn clouds(address: SocketAddr, window: Duration) {
    let mut clouds = Table::new(&["rep", "points per cloud", "studio CPU", "clouds shown/s"]);
    for rep in 0..kairos_benches::repetitions() {
        if let Some((_, studio, shown)) = measure(
            address,
            Path::SharedInPlace,
            window,
            "lidar.points",
            "point_cloud",
        ) {
            clouds.row(vec![
                rep.to_string(),
                "≤ 102 400".to_owned(),
                format!("{:.1} %", studio * 100.0),
                format!("{shown:.1}"),
            ]);
        }
    }
    clouds.print();
}

fn main() {
    let window = Duration::from_secs(size(2, 5));
    header(
        "12. a 1080p camera in an image viewer: socket vs shared memory",
        "throughput at 30 Hz; CPU shares of one core",
        &format!(
            "{WIDTH}×{HEIGHT} RGB8 at {RATE_HZ} Hz, {} s windows, transports interleaved",
            window.as_secs()
        ),
    );
    let Some(address) = kairos_benches::start_kairos_serve() else {
        eprintln!("the server did not start");
        return;
    };
    let mut control = RuntimeClient::connect(&format!("ws://{address}"), None, || {});
    let diagram = format!(
        "Diagram(format: 1, packs: [Pack(name: \"sensors\", version: \"^0.1\")], components: [\
         Component(id: \"camera\", type: \"sensors.camera\", position: (x: 0.0, y: 0.0), \
         properties: {{\"width\": {WIDTH}, \"height\": {HEIGHT}, \"rate\": {RATE_HZ:.1}, \"pattern\": \"color_bars\"}}), \
         Component(id: \"lidar\", type: \"sensors.lidar\", position: (x: 0.0, y: 100.0), \
         properties: {{\"channels\": 64, \"columns\": 1600, \"rate\": {RATE_HZ:.1}}})], connections: [])"
    );
    let deploy = control.request(RequestBody::Deploy {
        diagram,
        network: None,
        folder: None,
    });
    let deployed = wait_for_reply(&control, deploy).is_some();
    let start = control.request(RequestBody::Start {
        at_ns: None,
        forced: None,
        start_unlocked: false,
        lock_bound_ns: None,
    });
    if !deployed || wait_for_reply(&control, start).is_none() {
        eprintln!("the camera diagram did not start");
        return;
    }
    let mut table = Table::new(&[
        "rep",
        "transport",
        "runtime transport CPU",
        "studio CPU",
        "frames shown/s",
    ]);
    let mut runtime_by_path: [Vec<f64>; 3] = Default::default();
    let mut studio_by_path: [Vec<f64>; 3] = Default::default();
    let paths = [Path::Socket, Path::SharedCopied, Path::SharedInPlace];
    for rep in 0..kairos_benches::repetitions() {
        for (index, path) in paths.into_iter().enumerate() {
            let Some((runtime, studio, shown)) = measure(address, path, window, "camera.image", "image")
            else {
                eprintln!("{}: no measurement", path.name());
                continue;
            };
            table.row(vec![
                rep.to_string(),
                path.name().to_owned(),
                format!("{:.2} %", runtime * 100.0),
                format!("{:.1} %", studio * 100.0),
                format!("{shown:.1}"),
            ]);
            runtime_by_path[index].push(runtime);
            studio_by_path[index].push(studio);
        }
    }
    table.print();
    clouds(address, window);
    let [socket_runtime, copied_runtime, in_place_runtime] = &runtime_by_path;
    let [socket_studio, _, in_place_studio] = &studio_by_path;
    let per_rep = |over: &[f64]| Spread::of(socket_runtime.iter().zip(over).map(|(s, m)| s / m.max(1e-5)));
    let mut ratios = Ratios::new();
    ratios.add(
        "runtime CPU: socket / shared memory (pixels in place, the studio's path)",
        per_rep(in_place_runtime),
        Some(Goal::AtLeast(5.0)),
    );
    ratios.add(
        "runtime CPU: socket / shared memory (pixels copied)",
        per_rep(copied_runtime),
        None,
    );
    ratios.add(
        "studio CPU share, shared memory in place (of one core) / 25 %",
        Spread::of(in_place_studio.iter().map(|s| s / 0.25)),
        Some(Goal::AtMost(1.0)),
    );
    ratios.add(
        "studio CPU share, socket (of one core) / 25 %",
        Spread::of(socket_studio.iter().map(|s| s / 0.25)),
        None,
    );
    ratios.print();
}

//! `sensors.camera`: a simulated forward-looking camera on the simulated vehicle.

use std::time::Instant;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, ExecutionMode, Image,
    Payload, PixelFormat, PixelsMut, Value,
};

use crate::render::{Canvas, Pattern, Scene, read_barcode, render};
use crate::trajectory::Trajectory;
use crate::world::WorldView;
use crate::{Seen, TimeBase, apply_rate, rate_changed, rate_property, seen, with_vehicle_input};

/// The component's type name.
pub const TYPE_NAME: &str = "sensors.camera";

/// The descriptor of `sensors.camera`.
pub fn descriptor() -> ComponentInfo {
    with_vehicle_input(Descriptor::new(
        TYPE_NAME,
        "sensors",
        "Simulated forward camera on the simulated vehicle: a road scene (sky, mountains that turn with the \
         heading, a scrolling road that bends with the path, a car ahead; with a simulator, its road and \
         obstacles) or colour bars, with the frame number as a bar code along the top-left edge",
    ))
    .label("Simulated camera")
    .mode(ExecutionMode::Periodic)
    .output_with_buffer("image", DataType::Image, 8, "RGB8 frames, rows packed tightly")
    .property(rate_property(30.0, 240.0, "frames"))
    .property(
        Property::i64("width", 640)
            .unit("px")
            .int_range(80, 4096)
            .doc("Image width, pixels"),
    )
    .property(
        Property::i64("height", 480)
            .unit("px")
            .int_range(60, 4096)
            .doc("Image height, pixels"),
    )
    .property(
        Property::choice("pattern", &Pattern::NAMES, "scene")
            .live()
            .doc("What to draw: the road scene or colour bars"),
    )
    .build()
}

/// Reads the frame number a `sensors.camera` image carries in its bar code (the first frame is 0);
/// `None` for an image without one. Works on every pixel format the camera could be converted to
/// without resizing.
pub fn decode_frame_number(image: &Image) -> Option<u32> {
    read_barcode(
        &image.pixels,
        usize::try_from(image.width).ok()?,
        usize::try_from(image.height).ok()?,
        usize::try_from(image.stride).ok()?,
        usize::try_from(image.format.bytes_per_pixel()).ok()?,
    )
}

/// The `sensors.camera` component. See [`descriptor`].
#[derive(Debug)]
pub struct CameraSensor {
    trajectory: Trajectory,
    time: TimeBase,
    width: u32,
    height: u32,
    pattern: Pattern,
    frame: u32,
    /// Metres driven up to `last`, and the trajectory time and speed of the last frame.
    travelled_m: f64,
    last: Option<(f64, f64)>,
    /// A simulator's newest world, when the `vehicle` input is connected.
    world: Option<WorldView>,
}

impl Default for CameraSensor {
    fn default() -> Self {
        CameraSensor {
            trajectory: Trajectory::default(),
            time: TimeBase::default(),
            width: 640,
            height: 480,
            pattern: Pattern::Scene,
            frame: 0,
            travelled_m: 0.0,
            last: None,
            world: None,
        }
    }
}

fn pattern_of(name: &str) -> Result<Pattern, ComponentError> {
    Pattern::from_name(name).ok_or_else(|| ComponentError::failed(format_args!("unknown pattern '{name}'")))
}

fn dimension(ctx: &Context, name: &str) -> Result<u32, ComponentError> {
    let value = ctx.i64_property(name)?;
    u32::try_from(value)
        .ok()
        .filter(|v| *v > 0)
        .ok_or_else(|| ComponentError::failed(format_args!("{name} {value} is not a positive size")))
}

/// Renders one frame into a new buffer and hands it to a shared image.
fn render_image(width: u32, height: u32, pattern: Pattern, scene: &Scene) -> Result<Image, ComponentError> {
    let (w, h) = (width as usize, height as usize);
    let len = w
        .checked_mul(h)
        .and_then(|n| n.checked_mul(3))
        .ok_or_else(|| ComponentError::failed("image too large"))?;
    // A recycled buffer (shared memory for a large frame) still holds an earlier frame: every pixel is
    // drawn over.
    let mut pixels = PixelsMut::new(len);
    let mut canvas =
        Canvas::new(&mut pixels, w, h).ok_or_else(|| ComponentError::failed("pixel buffer size"))?;
    render(&mut canvas, pattern, scene);
    // From here on samples share the buffer and nothing copies pixels.
    Image::packed(width, height, PixelFormat::Rgb8, pixels.freeze()).map_err(ComponentError::failed)
}

impl Component for CameraSensor {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.width = dimension(ctx, "width")?;
        self.height = dimension(ctx, "height")?;
        self.pattern = pattern_of(&ctx.text_property("pattern")?)?;
        self.time = TimeBase::default();
        self.frame = 0;
        self.travelled_m = 0.0;
        self.last = None;
        apply_rate(ctx)?;
        tracing::debug!(
            component = ctx.id(),
            width = self.width,
            height = self.height,
            period = ?ctx.period(),
            "simulated camera started"
        );
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let Some(seen) = seen(ctx, &self.trajectory, &mut self.time, &mut self.world)? else {
            // The simulator has not stepped yet: nothing to show.
            return Ok(());
        };
        let state = *seen.state();
        let time_s = state.time_s;
        let world = match &seen {
            Seen::Trajectory(_) => None,
            Seen::World(view) => Some(&**view),
        };
        // Distance driven, by the trapezoid rule between frames (the path has no closed-form length).
        if let Some((last_time, last_speed)) = self.last {
            self.travelled_m += 0.5 * (last_speed + state.speed()) * (time_s - last_time).max(0.0);
        }
        self.last = Some((time_s, state.speed()));
        let scene = Scene {
            frame: self.frame,
            state,
            travelled_m: world.map_or(self.travelled_m, |w| w.station_m),
            world,
        };
        let started = Instant::now();
        let image = render_image(self.width, self.height, self.pattern, &scene)?;
        tracing::trace!(frame = self.frame, elapsed = ?started.elapsed(), "frame rendered");
        self.frame = self.frame.wrapping_add(1);
        ctx.write_at("image", Payload::Image(image), now)
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        rate_changed(name, value, ctx);
        if name == "pattern" {
            self.pattern = pattern_of(&ctx.text_property(name)?)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use kairos_sdk::harness::{Harness, HarnessOutput};
    use kairos_sdk::{Image, Payload, PixelFormat, Value};

    use super::{CameraSensor, decode_frame_number, descriptor, render_image};
    use crate::render::{Pattern, Scene};
    use crate::trajectory::Trajectory;

    fn images(out: &HarnessOutput) -> Vec<Image> {
        out.samples("image")
            .iter()
            .map(|s| match &s.payload {
                Payload::Image(image) => image.clone(),
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn harness(properties: &[(&str, Value)]) -> Harness {
        let mut harness = Harness::new(descriptor(), CameraSensor::default());
        harness.leave_unconnected("vehicle");
        for (name, value) in properties {
            harness.set_property(name, value.clone()).expect("property");
        }
        harness
    }

    /// The RGB of pixel (x, y).
    fn pixel(image: &Image, x: usize, y: usize) -> [u8; 3] {
        let at = y * image.stride as usize + x * 3;
        [image.pixels[at], image.pixels[at + 1], image.pixels[at + 2]]
    }

    #[test]
    fn frames_have_the_right_size_and_differ() {
        let out = harness(&[]).run_periodic(5).expect("runs");
        let frames = images(&out);
        assert_eq!(frames.len(), 5);
        for (index, frame) in frames.iter().enumerate() {
            assert_eq!(
                (frame.width, frame.height, frame.format),
                (640, 480, PixelFormat::Rgb8)
            );
            assert_eq!((frame.stride, frame.pixels.len()), (640 * 3, 640 * 480 * 3));
            assert_eq!(decode_frame_number(frame), Some(index as u32));
        }
        for pair in frames.windows(2) {
            assert_ne!(pair[0].pixels, pair[1].pixels);
        }
        // A plausible picture: blue sky at the top, green grass at the bottom left, grey road in front.
        let sky = pixel(&frames[0], 320, 60);
        assert!(sky[2] > sky[0] && sky[2] > 150, "sky {sky:?}");
        let grass = pixel(&frames[0], 5, 470);
        assert!(grass[1] > grass[0] && grass[1] > grass[2], "grass {grass:?}");
        let road = pixel(&frames[0], 200, 470);
        assert!(
            road[0].abs_diff(road[1]) < 10 && road[0] > 60 && road[0] < 130,
            "road {road:?}"
        );
        // Timestamps are 1/30 s apart and the frames are shared, not copied, downstream.
        let samples = out.samples("image");
        assert_eq!(samples[1].timestamp.0 - samples[0].timestamp.0, 33_333_333);
    }

    #[test]
    fn the_scene_moves_when_the_vehicle_drives() {
        let mut harness = harness(&[("width", Value::I64(320)), ("height", Value::I64(240))]);
        let frames = images(&harness.run_periodic(30 * 20).expect("runs"));
        assert_eq!((frames[0].width, frames[0].height), (320, 240));
        // Later, at speed, consecutive frames differ over a large part of the road area.
        let changed = |a: &Image, b: &Image| {
            a.pixels
                .chunks_exact(3)
                .zip(b.pixels.chunks_exact(3))
                .filter(|(p, q)| p != q)
                .count()
        };
        let at_rest = changed(&frames[10], &frames[11]);
        let driving = changed(&frames[400], &frames[401]);
        assert!(
            driving > 5 * at_rest.max(100),
            "at rest {at_rest}, driving {driving}"
        );
        assert_eq!(decode_frame_number(&frames[599]), Some(599));
    }

    #[test]
    fn color_bars_and_live_changes() {
        let mut harness = harness(&[("pattern", Value::Text("color_bars".to_owned()))]);
        let first = images(&harness.run_periodic(2).expect("runs"));
        assert_eq!(pixel(&first[0], 40, 240), [235, 235, 235]);
        assert_eq!(pixel(&first[0], 600, 240), [16, 16, 16]);
        assert_ne!(first[0].pixels, first[1].pixels);
        harness
            .set_property("pattern", Value::Text("scene".to_owned()))
            .expect("live");
        harness.set_property("rate", Value::F64(10.0)).expect("live");
        let out = harness.run_periodic(3).expect("runs");
        let second = images(&out);
        assert_ne!(pixel(&second[0], 40, 240), [235, 235, 235]);
        assert_eq!(decode_frame_number(&second[0]), Some(2));
        let stamps: Vec<i64> = out.samples("image").iter().map(|s| s.timestamp.0).collect();
        assert_eq!(stamps[2] - stamps[1], 100_000_000);
        assert!(
            harness.set_property("width", Value::I64(10)).is_err(),
            "out of range"
        );
    }

    #[test]
    fn frame_render_time() {
        let trajectory = Trajectory::default();
        for (pattern, name) in [(Pattern::Scene, "scene"), (Pattern::ColorBars, "color_bars")] {
            let count = 30_u32;
            let started = Instant::now();
            for frame in 0..count {
                let scene = Scene {
                    frame,
                    state: trajectory.state(20.0 + f64::from(frame) / 30.0),
                    travelled_m: 100.0 + f64::from(frame) * 0.3,
                    world: None,
                };
                let image = render_image(640, 480, pattern, &scene).expect("renders");
                assert_eq!(decode_frame_number(&image), Some(frame));
            }
            let each = started.elapsed() / count;
            let budget = Duration::from_secs(1) / 30;
            println!(
                "sensors.camera {name}: one 640x480 RGB8 frame renders in {:.2} ms ({:.0}% of the 30 Hz period)",
                each.as_secs_f64() * 1e3,
                100.0 * each.as_secs_f64() / budget.as_secs_f64()
            );
        }
    }
}

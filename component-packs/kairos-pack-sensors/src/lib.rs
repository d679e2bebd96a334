//! Simulated sensors, so that a meaningful diagram runs with no hardware attached.
//!
//! Pack `sensors`, registered by [`register`]. Every component is periodic and samples one shared,
//! deterministic vehicle [`trajectory`]: a figure-eight of about 525 m driven at about 10 m/s around a
//! reference point, after two seconds at rest. A component's trajectory time is the timestamp of its
//! sample minus that of its first sample, so sensors started together see the same vehicle. Every sample
//! is written with its acquisition time as timestamp. Noise comes from a seeded generator (`kairos_sdk::rng`):
//! the same seed gives the same output.
//!
//! | Component | Outputs | Properties | Actions |
//! |---|---|---|---|
//! | [`sensors.imu`](imu::ImuSensor) | `imu` (`imu`), `pose` (`pose`) | `rate` = 100 Hz (live), `gyro_noise`, `accel_noise` (live), `seed` | |
//! | [`sensors.gnss`](gnss::GnssSensor) | `fix` (`gnss_fix`) | `rate` = 10 Hz (live), `noise_m`, `noise_correlation_s` (live), `seed`, `latitude`, `longitude`, `altitude` | `outage` |
//! | [`sensors.camera`](camera::CameraSensor) | `image` (`image`, RGB8) | `rate` = 30 Hz (live), `width` = 640, `height` = 480, `pattern` (live) | |
//!
//! Supporting modules: [`trajectory`] (the vehicle), [`geo`] (local ENU ↔ WGS84), and `kairos_sdk::rng` (noise).

#![warn(missing_docs)]

pub mod camera;
pub mod geo;
pub mod gnss;
pub mod imu;
pub mod lidar;
mod render;
pub mod trajectory;
pub mod world;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    ComponentError, ComponentResult, Context, ReaderPolicy, Registry, Timestamp, TypeFilter, Value,
};

pub use camera::{CameraSensor, decode_frame_number};
pub use geo::{GeoPoint, LocalFrame};
pub use gnss::GnssSensor;
pub use imu::ImuSensor;
pub use kairos_sdk::rng::NoiseRng;
pub use render::Pattern;
pub use trajectory::{Trajectory, VehicleState};
pub use world::WorldView;

/// The pack's name.
pub const PACK_NAME: &str = "sensors";

/// Registers the `sensors` pack and its components.
pub fn register(registry: &mut Registry) {
    registry
        .pack(PACK_NAME, env!("CARGO_PKG_VERSION"), "built-in")
        .component::<ImuSensor>(imu::descriptor())
        .component::<GnssSensor>(gnss::descriptor())
        .component::<CameraSensor>(camera::descriptor())
        .component::<lidar::LidarSensor>(lidar::descriptor())
        .custom_type(world::TYPE_NAME);
}

/// The input every sensor has for a simulator's world.
const VEHICLE: &str = "vehicle";

/// Adds the `vehicle` input: connected to a simulator, the sensor sees its world.
fn with_vehicle_input(descriptor: Descriptor) -> Descriptor {
    descriptor.input_with_policy(
        VEHICLE,
        TypeFilter::only(world::data_type()),
        ReaderPolicy::LastOrNext,
        "Optional: a simulator's world (sim.vehicle's `world`); connected, the sensor sees the simulated \
         vehicle and its world instead of following the fixed figure-eight",
    )
}

/// Where a sensor's vehicle is at a tick.
#[derive(Debug, Clone)]
enum Seen {
    /// On the fixed trajectory (no simulator connected).
    Trajectory(VehicleState),
    /// In a simulator's world.
    World(Box<WorldView>),
}

/// What a sensor sees at `now`: the simulator's newest world when its `vehicle` input is connected
/// (`None` until the first one arrives), else the fixed trajectory at the sensor's own time. A
/// simulator that finished ends the sensor's stream.
fn seen(
    ctx: &mut Context,
    trajectory: &Trajectory,
    time: &mut TimeBase,
    held: &mut Option<WorldView>,
) -> Result<Option<Seen>, ComponentError> {
    if !ctx.is_connected(VEHICLE) {
        let now = ctx.now();
        return Ok(Some(Seen::Trajectory(trajectory.state(time.elapsed_s(now)))));
    }
    if let Some(sample) = ctx.try_read(VEHICLE)? {
        let view = WorldView::from_payload(&sample.payload)
            .map_err(|e| ComponentError::failed(format_args!("input 'vehicle': {e}")))?;
        *held = Some(view);
    } else if ctx.input_ended(VEHICLE) {
        return Err(ComponentError::EndOfStream);
    }
    Ok(held.clone().map(|view| Seen::World(Box::new(view))))
}

impl Seen {
    fn state(&self) -> &VehicleState {
        match self {
            Seen::Trajectory(state) => state,
            Seen::World(view) => &view.state,
        }
    }
}

/// The live `rate` property every sensor has, in hertz.
fn rate_property(default: f64, max: f64, what: &str) -> Property {
    Property::f64("rate", default)
        .unit("Hz")
        .range(0.1, max)
        .live()
        .doc(&format!("How many {what} per second (Hz)"))
}

/// Sets the period from the `rate` property.
fn apply_rate(ctx: &mut Context) -> ComponentResult {
    let rate = ctx.f64_property("rate")?;
    ctx.set_frequency(rate);
    Ok(())
}

/// Applies a live change of `rate`; other properties are left to the caller.
fn rate_changed(name: &str, value: &Value, ctx: &mut Context) {
    if name == "rate"
        && let Some(rate) = value.as_f64()
    {
        ctx.set_frequency(rate);
    }
}

/// The trajectory time of a component: seconds since its first sample.
#[derive(Debug, Clone, Copy, Default)]
struct TimeBase {
    start: Option<Timestamp>,
}

impl TimeBase {
    /// Seconds from the first call's `now` to this one's (zero on the first call).
    fn elapsed_s(&mut self, now: Timestamp) -> f64 {
        let start = *self.start.get_or_insert(now);
        now.nanos_since(start) as f64 * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use kairos_sdk::{DataType, ExecutionMode, Registry};

    #[test]
    fn registers_the_pack_and_its_components() {
        let mut registry = Registry::new();
        super::register(&mut registry);
        let pack = registry.packs().find(|p| p.name == "sensors").expect("pack");
        assert_eq!(pack.version, env!("CARGO_PKG_VERSION"));
        assert_eq!(pack.origin, "built-in");
        let expected = [
            (
                "sensors.imu",
                vec![("imu", DataType::Imu), ("pose", DataType::Pose)],
            ),
            ("sensors.gnss", vec![("fix", DataType::GnssFix)]),
            ("sensors.camera", vec![("image", DataType::Image)]),
            ("sensors.lidar", vec![("points", DataType::PointCloud)]),
        ];
        for (name, outputs) in expected {
            let component = registry.component(name).expect(name);
            assert_eq!(component.info.pack, "sensors");
            assert_eq!(component.info.category, "sensors");
            assert_eq!(component.info.mode, ExecutionMode::Periodic);
            let inputs: Vec<(&str, kairos_sdk::TypeFilter)> = component
                .info
                .inputs
                .iter()
                .map(|i| (i.name.as_str(), i.filter.clone()))
                .collect();
            let world = kairos_sdk::TypeFilter::only(super::world::data_type());
            assert_eq!(inputs, [("vehicle", world)], "{name}");
            let found: Vec<(&str, DataType)> = component
                .info
                .outputs
                .iter()
                .map(|o| (o.name.as_str(), o.data_type.clone()))
                .collect();
            assert_eq!(found, outputs);
            let rate = component.info.property("rate").expect("rate");
            assert!(rate.live);
            assert!(matches!(
                rate.kind,
                kairos_sdk::PropertyKind::F64 {
                    min: Some(_),
                    max: Some(_)
                }
            ));
            // The registered factory makes a working component.
            let mut harness =
                kairos_sdk::harness::Harness::boxed(component.info.clone(), (component.factory)());
            harness.leave_unconnected("vehicle");
            let out = harness.run_periodic(2).expect("runs");
            assert!(out.all().values().all(|samples| samples.len() == 2), "{name}");
        }
        assert!(registry.duplicates().is_empty());
    }
}

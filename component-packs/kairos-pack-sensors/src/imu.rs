//! `sensors.imu`: a simulated inertial measurement unit on the simulated vehicle.

use glam::DVec3;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentInfo, ComponentResult, Context, DataType, ExecutionMode, Imu, Payload, Pose, Value,
};

use crate::trajectory::Trajectory;
use crate::world::WorldView;
use crate::{TimeBase, apply_rate, rate_changed, rate_property, seen, with_vehicle_input};
use kairos_sdk::rng::NoiseRng;

/// The component's type name.
pub const TYPE_NAME: &str = "sensors.imu";

/// Separates the IMU's noise stream from other sensors given the same seed.
const NOISE_SALT: u64 = 0x1A1B_1C1D;

/// The descriptor of `sensors.imu`.
pub fn descriptor() -> ComponentInfo {
    with_vehicle_input(Descriptor::new(
        TYPE_NAME,
        "sensors",
        "Simulated IMU on the simulated vehicle: body-frame angular velocity and specific force (gravity \
         included, +9.81 m/s² on z at rest), true orientation, plus the ground-truth pose",
    ))
    .label("Simulated IMU")
    .mode(ExecutionMode::Periodic)
    .output(
        "imu",
        DataType::Imu,
        "Angular velocity (rad/s) and linear acceleration (m/s², gravity included) in the body frame \
         (x forward, y left, z up), with the true orientation in the local ENU frame",
    )
    .output(
        "pose",
        DataType::Pose,
        "Ground-truth position (m) and orientation in the local ENU frame",
    )
    .property(rate_property(100.0, 2000.0, "measurements"))
    .property(
        Property::f64("gyro_noise", 0.002)
            .unit("rad/s")
            .range(0.0, 1.0)
            .live()
            .doc("Standard deviation of the white noise on each gyroscope axis, rad/s"),
    )
    .property(
        Property::f64("accel_noise", 0.02)
            .unit("m/s²")
            .range(0.0, 10.0)
            .live()
            .doc("Standard deviation of the white noise on each accelerometer axis, m/s²"),
    )
    .property(
        Property::i64("seed", 1).doc("Seed of the noise generator: the same seed gives the same output"),
    )
    .build()
}

/// The `sensors.imu` component. See [`descriptor`].
#[derive(Debug)]
pub struct ImuSensor {
    trajectory: Trajectory,
    time: TimeBase,
    rng: NoiseRng,
    gyro_noise: f64,
    accel_noise: f64,
    /// A simulator's newest world, when the `vehicle` input is connected.
    world: Option<WorldView>,
}

impl Default for ImuSensor {
    fn default() -> Self {
        ImuSensor {
            trajectory: Trajectory::default(),
            time: TimeBase::default(),
            rng: NoiseRng::new(1, NOISE_SALT),
            gyro_noise: 0.0,
            accel_noise: 0.0,
            world: None,
        }
    }
}

impl ImuSensor {
    fn noise(&mut self, sigma: f64) -> DVec3 {
        DVec3::new(
            self.rng.normal(sigma),
            self.rng.normal(sigma),
            self.rng.normal(sigma),
        )
    }
}

impl Component for ImuSensor {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.time = TimeBase::default();
        self.rng = NoiseRng::new(ctx.i64_property("seed")?, NOISE_SALT);
        self.gyro_noise = ctx.f64_property("gyro_noise")?;
        self.accel_noise = ctx.f64_property("accel_noise")?;
        apply_rate(ctx)?;
        tracing::debug!(component = ctx.id(), period = ?ctx.period(), "simulated IMU started");
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let Some(seen) = seen(ctx, &self.trajectory, &mut self.time, &mut self.world)? else {
            return Ok(());
        };
        let state = *seen.state();
        let imu = Imu {
            angular_velocity: state.angular_velocity_body + self.noise(self.gyro_noise),
            linear_acceleration: state.specific_force_body + self.noise(self.accel_noise),
            orientation: Some(state.orientation),
        };
        ctx.write_at("imu", Payload::Imu(imu), now)?;
        let pose = Pose {
            position: state.position,
            orientation: state.orientation,
        };
        ctx.write_at("pose", Payload::Pose(pose), now)
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        rate_changed(name, value, ctx);
        match name {
            "gyro_noise" => self.gyro_noise = ctx.f64_property(name)?,
            "accel_noise" => self.accel_noise = ctx.f64_property(name)?,
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use glam::DQuat;
    use kairos_sdk::harness::{Harness, HarnessOutput};
    use kairos_sdk::{Imu, Payload, Pose, Value};

    use super::{ImuSensor, descriptor};
    use crate::trajectory::GRAVITY;

    fn imus(out: &HarnessOutput) -> Vec<Imu> {
        out.samples("imu")
            .iter()
            .map(|s| match &s.payload {
                Payload::Imu(imu) => *imu,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn poses(out: &HarnessOutput) -> Vec<Pose> {
        out.samples("pose")
            .iter()
            .map(|s| match &s.payload {
                Payload::Pose(pose) => *pose,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn yaw(orientation: DQuat) -> f64 {
        let forward = orientation * glam::DVec3::X;
        forward.y.atan2(forward.x)
    }

    fn run(properties: &[(&str, Value)], cycles: usize) -> HarnessOutput {
        let mut harness = Harness::new(descriptor(), ImuSensor::default());
        harness.leave_unconnected("vehicle");
        for (name, value) in properties {
            harness.set_property(name, value.clone()).expect("property");
        }
        harness.run_periodic(cycles).expect("runs")
    }

    #[test]
    fn at_rest_it_reads_gravity_on_z() {
        let out = run(&[], 150);
        let samples = imus(&out);
        assert_eq!(samples.len(), 150);
        let n = samples.len() as f64;
        let mean_acc = samples.iter().map(|s| s.linear_acceleration).sum::<glam::DVec3>() / n;
        let mean_gyro = samples.iter().map(|s| s.angular_velocity).sum::<glam::DVec3>() / n;
        assert!((mean_acc.z - 9.81).abs() < 0.01, "{mean_acc}");
        assert!(mean_acc.x.abs() < 0.01 && mean_acc.y.abs() < 0.01, "{mean_acc}");
        assert!(mean_gyro.length() < 0.001, "{mean_gyro}");
        // Noise is there, with about the configured spread.
        let spread = (samples
            .iter()
            .map(|s| (s.linear_acceleration.z - GRAVITY).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        assert!((0.01..0.03).contains(&spread), "{spread}");
        // Without noise, exactly gravity.
        let exact = imus(&run(
            &[("gyro_noise", Value::F64(0.0)), ("accel_noise", Value::F64(0.0))],
            10,
        ));
        assert!(
            exact
                .iter()
                .all(|s| (s.linear_acceleration.z - GRAVITY).abs() < 1e-12)
        );
    }

    #[test]
    fn turning_shows_in_the_gyro_and_the_accelerometer() {
        let out = run(
            &[("gyro_noise", Value::F64(0.0)), ("accel_noise", Value::F64(0.0))],
            4000,
        );
        let samples = imus(&out);
        let poses = poses(&out);
        let mut left = 0;
        let mut right = 0;
        for i in 1..samples.len() {
            let gyro_z = samples[i].angular_velocity.z;
            if gyro_z.abs() < 0.05 {
                continue;
            }
            let change = yaw(poses[i].orientation) - yaw(poses[i - 1].orientation);
            let change =
                (change + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
            assert_eq!(gyro_z > 0.0, change > 0.0, "sample {i}");
            assert!(
                (change / 0.01 - gyro_z).abs() < 0.01,
                "sample {i}: {change} vs {gyro_z}"
            );
            // Turning left pushes the body to the left: the accelerometer reads +y.
            assert_eq!(samples[i].linear_acceleration.y > 0.0, gyro_z > 0.0, "sample {i}");
            if gyro_z > 0.0 {
                left += 1;
            } else {
                right += 1;
            }
            assert!((samples[i].linear_acceleration.z - GRAVITY).abs() < 0.5);
        }
        assert!(left > 100 && right > 100, "left {left} right {right}");
        // The orientation output is the pose's.
        assert!(
            samples
                .iter()
                .zip(&poses)
                .all(|(s, p)| s.orientation == Some(p.orientation))
        );
    }

    #[test]
    fn same_seed_same_output() {
        let a = run(&[("seed", Value::I64(7))], 50);
        let b = run(&[("seed", Value::I64(7))], 50);
        let c = run(&[("seed", Value::I64(8))], 50);
        assert_eq!(imus(&a), imus(&b));
        assert_ne!(imus(&a), imus(&c));
        assert_eq!(poses(&a), poses(&c));
    }

    #[test]
    fn timestamps_follow_the_live_rate() {
        let mut harness = Harness::new(descriptor(), ImuSensor::default());
        harness.leave_unconnected("vehicle");
        let first = harness.run_periodic(5).expect("runs");
        harness.set_property("rate", Value::F64(20.0)).expect("live");
        let second = harness.run_periodic(5).expect("runs");
        let stamps: Vec<i64> = first
            .samples("imu")
            .iter()
            .chain(second.samples("imu"))
            .map(|s| s.timestamp.0)
            .collect();
        let steps: Vec<i64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
        let ms = |n: u64| i64::try_from(Duration::from_millis(n).as_nanos()).expect("fits");
        assert_eq!(
            steps,
            vec![
                ms(10),
                ms(10),
                ms(10),
                ms(10),
                ms(10),
                ms(50),
                ms(50),
                ms(50),
                ms(50)
            ]
        );
        // Timestamp and time of issue are both the acquisition time on the harness clock.
        assert!(
            second
                .samples("imu")
                .iter()
                .all(|s| s.time_of_issue == s.timestamp)
        );
    }
}

//! Navigation components: the GNSS + IMU filter, dead reckoning, and resampling a stream at another's
//! timestamps.

use std::collections::VecDeque;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, FixStatus, GnssFix, Imu,
    Payload, Pose, Sample, Timestamp, TypeFilter,
};

use crate::geo_components::{describe, fixed_reference, geodetic_of, reference_properties};
use crate::geodesy::EnuFrame;
use crate::ins::{FixOutcome, InitialUncertainty, Ins, InsConfig};

fn seconds(t: Timestamp) -> f64 {
    t.as_nanos() as f64 * 1e-9
}

/// Compass heading (degrees clockwise from north, 0–360) of an ENU yaw (radians counter-clockwise from
/// east).
fn compass_deg(yaw: f64) -> f64 {
    (90.0 - yaw.to_degrees()).rem_euclid(360.0)
}

/// `fusion.gnss_imu_ekf`.
#[derive(Debug, Default)]
pub struct GnssImuEkf {
    frame: Option<EnuFrame>,
    ins: Option<Ins>,
    /// The last fix before the filter started: where it starts, and with the next one the course.
    first_fix: Option<(f64, DVec3)>,
    /// The latest IMU sample before the filter started: its tilt (and orientation, when it gives one).
    last_imu: Option<Imu>,
    skipped_before_start: u64,
}

impl GnssImuEkf {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        reference_properties(
            Descriptor::new(
                "fusion.gnss_imu_ekf",
                "navigation",
                "GNSS + IMU Kalman filter: position, velocity and heading with their uncertainty, at the IMU's rate",
            )
            .label("GNSS + IMU fusion (EKF)")
            .input("imu", TypeFilter::only(DataType::Imu), "Angular rate and specific force in the body frame (x forward, y left, z up)")
            .input("gnss", TypeFilter::only(DataType::GnssFix), "GNSS fixes with their accuracies")
            .output("pose", DataType::Pose, "Position (m) and orientation in the local ENU frame, at each IMU sample's timestamp")
            .output("fix", DataType::GnssFix, "The fused position as a WGS84 fix, its accuracy from the filter")
            .output("velocity", DataType::Vector, "Velocity east, north, up (m/s)")
            .output("heading_deg", DataType::F64, "Heading, degrees clockwise from north")
            .output("sigma", DataType::Vector, "One-sigma uncertainty: east, north, up (m), velocity east, north, up (m/s), heading (deg)"),
        )
        .property(Property::f64("gyro_noise", 0.002).unit("rad/s/√Hz").range(1e-6, 1.0).doc("Gyroscope noise density"))
        .property(Property::f64("accel_noise", 0.02).unit("m/s²/√Hz").range(1e-5, 10.0).doc("Accelerometer noise density"))
        .property(Property::f64("gate", 16.3).range(1.0, 1000.0).doc("χ² bound on a fix's innovation: fixes beyond it are rejected (16.3: one good fix in 1000)"))
        .property(Property::f64("reset_after", 10.0).unit("s").range(0.5, 3600.0).doc("After this long with every fix rejected, the filter restarts at the fixes"))
        .action("restart", "Forgets the solution and starts again from the next fixes")
        .build()
    }

    fn config(ctx: &Context) -> Result<InsConfig, ComponentError> {
        Ok(InsConfig {
            gyro_noise: ctx.f64_property("gyro_noise")?,
            accel_noise: ctx.f64_property("accel_noise")?,
            gate: ctx.f64_property("gate")?,
            reset_after_s: ctx.f64_property("reset_after")?,
            ..InsConfig::default()
        })
    }

    /// Starts the filter once it knows where it is and which way it faces: the IMU's orientation when
    /// it gives one, else tilt from gravity and the heading from two fixes far enough apart.
    fn try_start(&mut self, ctx: &Context, time_s: f64, position: DVec3) -> Result<(), ComponentError> {
        let Some(imu) = self.last_imu else { return Ok(()) };
        let (attitude, velocity, heading_sigma) = if let Some(orientation) = imu.orientation {
            (orientation, DVec3::ZERO, 5_f64.to_radians())
        } else {
            let Some((then, start)) = self.first_fix else {
                return Ok(());
            };
            let moved = position - start;
            if moved.truncate().length() < 5.0 || time_s <= then {
                return Ok(());
            }
            let yaw = moved.y.atan2(moved.x);
            let f = imu.linear_acceleration;
            let pitch = (-f.x).atan2(f.y.hypot(f.z));
            let roll = f.y.atan2(f.z);
            let attitude = DQuat::from_euler(glam::EulerRot::ZYX, yaw, pitch, roll);
            (attitude, moved / (time_s - then), 10_f64.to_radians())
        };
        let uncertainty = InitialUncertainty {
            position_m: 3.0,
            velocity_m_s: if velocity == DVec3::ZERO { 2.0 } else { 1.0 },
            tilt_rad: 2_f64.to_radians(),
            heading_rad: heading_sigma,
        };
        self.ins = Some(Ins::new(
            Self::config(ctx)?,
            (position, velocity, attitude),
            uncertainty,
            time_s,
        ));
        Ok(())
    }

    fn on_imu(&mut self, ctx: &mut Context, sample: &Sample, imu: &Imu) -> ComponentResult {
        let time_s = seconds(sample.timestamp);
        let Some(ins) = self.ins.as_mut() else {
            if imu.angular_velocity.is_finite() && imu.linear_acceleration.is_finite() {
                self.last_imu = Some(*imu);
            } else {
                self.skipped_before_start += 1;
            }
            return Ok(());
        };
        if !ins.propagate(time_s, imu.angular_velocity, imu.linear_acceleration) {
            return Ok(());
        }
        let (position, velocity, yaw) = (ins.position(), ins.velocity(), ins.yaw());
        let (p_sigma, v_sigma, heading_sigma) = ins.sigmas();
        let pose = Pose {
            position,
            orientation: ins.attitude(),
        };
        ctx.write_processed("pose", sample, Payload::Pose(pose))?;
        ctx.write_processed(
            "velocity",
            sample,
            Payload::Vector(Arc::from([velocity.x, velocity.y, velocity.z].as_slice())),
        )?;
        ctx.write_processed("heading_deg", sample, Payload::F64(compass_deg(yaw)))?;
        let sigma = [
            p_sigma[0],
            p_sigma[1],
            p_sigma[2],
            v_sigma[0],
            v_sigma[1],
            v_sigma[2],
            heading_sigma.to_degrees(),
        ];
        ctx.write_processed("sigma", sample, Payload::Vector(Arc::from(sigma.as_slice())))?;
        if let Some(frame) = self.frame {
            let point = frame.to_geodetic(position);
            let fix = GnssFix {
                latitude_deg: point.latitude_deg,
                longitude_deg: point.longitude_deg,
                altitude_m: point.altitude_m,
                horizontal_accuracy_m: f64::midpoint(p_sigma[0].powi(2), p_sigma[1].powi(2)).sqrt(),
                vertical_accuracy_m: p_sigma[2],
                status: FixStatus::Fix,
            };
            ctx.write_processed("fix", sample, Payload::GnssFix(fix))?;
        }
        Ok(())
    }

    fn on_fix(&mut self, ctx: &mut Context, sample: &Sample, fix: &GnssFix) -> ComponentResult {
        let usable = geodetic_of(fix)
            .filter(|_| fix.horizontal_accuracy_m.is_finite() && fix.vertical_accuracy_m.is_finite());
        let Some(point) = usable else {
            match self.ins.as_mut() {
                Some(ins) => {
                    ins.correct_position(0.0, DVec3::NAN, DVec3::ONE);
                }
                None => self.skipped_before_start += 1,
            }
            return Ok(());
        };
        let frame = *self.frame.get_or_insert_with(|| EnuFrame::new(point));
        let position = frame.to_enu(&point);
        let sigma = DVec3::new(
            fix.horizontal_accuracy_m,
            fix.horizontal_accuracy_m,
            fix.vertical_accuracy_m,
        )
        .max(DVec3::splat(0.05));
        let time_s = seconds(sample.timestamp);
        if let Some(ins) = self.ins.as_mut() {
            // The filter's time is its last IMU sample's: the fix is applied there (IMU samples come
            // every few milliseconds, so at most that late).
            if let FixOutcome::Rejected(chi2) = ins.correct_position(ins.time_s(), position, sigma) {
                tracing::debug!(component = ctx.id(), chi2, "fix rejected by the gate");
            }
        } else {
            self.try_start(ctx, time_s, position)?;
            if self.ins.is_none() && self.first_fix.is_none() {
                self.first_fix = Some((time_s, position));
            }
        }
        Ok(())
    }
}

impl Component for GnssImuEkf {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        *self = GnssImuEkf {
            frame: fixed_reference(ctx)?,
            ..GnssImuEkf::default()
        };
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let (which, sample) = ctx.read_any(&["imu", "gnss"])?;
        match (&sample.payload, which) {
            (Payload::Imu(imu), 0) => self.on_imu(ctx, &sample, imu)?,
            (Payload::GnssFix(fix), 1) => self.on_fix(ctx, &sample, fix)?,
            (other, _) => {
                return Err(ComponentError::failed(format_args!(
                    "unexpected {} on {}",
                    describe(other),
                    ["imu", "gnss"][which]
                )));
            }
        }
        let counters = self.ins.as_ref().map(Ins::counters).unwrap_or_default();
        ctx.set_status(serde_json::json!({
            "started": self.ins.is_some(),
            "imu_used": counters.imu_used,
            "imu_skipped": counters.imu_skipped,
            "fixes_used": counters.fixes_used,
            "fixes_rejected": counters.fixes_rejected,
            "fixes_skipped": counters.fixes_skipped + self.skipped_before_start,
            "resets": counters.resets,
        }));
        Ok(())
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        if name == "restart" {
            self.birth(ctx)?;
        }
        Ok(())
    }
}

/// `fusion.dead_reckoning`.
#[derive(Debug, Default)]
pub struct DeadReckoning {
    speed: Option<f64>,
    last: Option<(Timestamp, f64)>,
    position: DVec3,
    yaw: f64,
}

impl DeadReckoning {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "fusion.dead_reckoning",
            "navigation",
            "Odometry: integrates speed and yaw rate into a planar position and heading",
        )
        .label("Dead reckoning")
        .input("speed", TypeFilter::OneOf(vec![DataType::F64, DataType::I64]), "Forward speed, m/s (e.g. from the wheels)")
        .input("yaw_rate", TypeFilter::OneOf(vec![DataType::F64, DataType::Imu]), "Yaw rate, rad/s, positive turning left; or IMU samples (their z rate)")
        .output("pose", DataType::Pose, "Position (m) and heading in the start frame, at each yaw-rate sample")
        .property(Property::f64("start_heading", 90.0).unit("deg").range(0.0, 360.0).doc("Heading at the start, degrees clockwise from north (90: the start frame's x axis points east)"))
        .action("reset", "Back to the origin and the start heading")
        .build()
    }
}

impl Component for DeadReckoning {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        *self = DeadReckoning {
            yaw: (90.0 - ctx.f64_property("start_heading")?).to_radians(),
            ..DeadReckoning::default()
        };
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let (which, sample) = ctx.read_any(&["speed", "yaw_rate"])?;
        let value = match &sample.payload {
            Payload::Imu(imu) => imu.angular_velocity.z,
            other => other.as_f64().unwrap_or(f64::NAN),
        };
        if !value.is_finite() {
            return Ok(());
        }
        if which == 0 {
            self.speed = Some(value);
            return Ok(());
        }
        let Some(speed) = self.speed else { return Ok(()) };
        if let Some((then, last_rate)) = self.last {
            let dt = sample.timestamp.nanos_since(then) as f64 * 1e-9;
            if dt > 0.0 && dt < 10.0 {
                // Midpoint rule: the heading halfway through the step.
                let mid = self.yaw + 0.5 * (last_rate + value) * 0.5 * dt;
                self.position += DVec3::new(mid.cos(), mid.sin(), 0.0) * speed * dt;
                self.yaw += 0.5 * (last_rate + value) * dt;
            }
        }
        self.last = Some((sample.timestamp, value));
        let pose = Pose {
            position: self.position,
            orientation: DQuat::from_rotation_z(self.yaw),
        };
        ctx.write_processed("pose", &sample, Payload::Pose(pose))
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        if name == "reset" {
            self.birth(ctx)?;
        }
        Ok(())
    }
}

/// `fusion.interpolate`.
#[derive(Debug, Default)]
pub struct Interpolate {
    history: VecDeque<Sample>,
    too_early: u64,
}

impl Interpolate {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "fusion.interpolate",
            "navigation",
            "Resamples a stream at the timestamps of another: the value it had at each of those instants, interpolated",
        )
        .label("Interpolate at timestamps")
        .input(
            "in",
            TypeFilter::OneOf(vec![DataType::F64, DataType::I64, DataType::Vector, DataType::Pose, DataType::GnssFix, DataType::Imu]),
            "The stream to resample",
        )
        .input("at", TypeFilter::Any, "Any stream: its timestamps are the instants to resample at")
        .output_following("out", "in", "The value of `in` at each `at` timestamp (linear; poses: orientation by slerp), stamped with it")
        .build()
    }
}

/// `a` and `b` mixed at `t` (0: `a`, 1: `b`), when they are of one kind.
fn mix(earlier: &Payload, later: &Payload, fraction: f64) -> Option<Payload> {
    let lerp = |x: f64, y: f64| x + (y - x) * fraction;
    Some(match (earlier, later) {
        (Payload::F64(x), Payload::F64(y)) => Payload::F64(lerp(*x, *y)),
        (Payload::I64(x), Payload::I64(y)) => Payload::F64(lerp(*x as f64, *y as f64)),
        (Payload::Vector(x), Payload::Vector(y)) if x.len() == y.len() => {
            Payload::Vector(x.iter().zip(y.iter()).map(|(p, q)| lerp(*p, *q)).collect())
        }
        (Payload::Pose(x), Payload::Pose(y)) => Payload::Pose(Pose {
            position: x.position.lerp(y.position, fraction),
            orientation: x.orientation.slerp(y.orientation, fraction),
        }),
        (Payload::GnssFix(x), Payload::GnssFix(y)) => Payload::GnssFix(GnssFix {
            latitude_deg: lerp(x.latitude_deg, y.latitude_deg),
            longitude_deg: lerp(x.longitude_deg, y.longitude_deg),
            altitude_m: lerp(x.altitude_m, y.altitude_m),
            horizontal_accuracy_m: x.horizontal_accuracy_m.max(y.horizontal_accuracy_m),
            vertical_accuracy_m: x.vertical_accuracy_m.max(y.vertical_accuracy_m),
            status: if fraction < 0.5 { x.status } else { y.status },
        }),
        (Payload::Imu(x), Payload::Imu(y)) => Payload::Imu(Imu {
            angular_velocity: x.angular_velocity.lerp(y.angular_velocity, fraction),
            linear_acceleration: x.linear_acceleration.lerp(y.linear_acceleration, fraction),
            orientation: x
                .orientation
                .zip(y.orientation)
                .map(|(p, q)| p.slerp(q, fraction)),
        }),
        _ => return None,
    })
}

impl Component for Interpolate {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let at = ctx.read("at")?;
        let when = at.timestamp;
        // Read the stream until it reaches the instant: a sample at or after it.
        while self.history.back().is_none_or(|s| s.timestamp < when) {
            let sample = ctx.read("in")?;
            self.history.push_back(sample);
            while self.history.len() > 2 && self.history[1].timestamp <= when {
                self.history.pop_front();
            }
        }
        let after = self.history.iter().position(|s| s.timestamp >= when).unwrap_or(0);
        let Some(before) = after.checked_sub(1).map(|i| &self.history[i]) else {
            let exact = &self.history[after];
            if exact.timestamp == when {
                return ctx.write_at("out", exact.payload.clone(), when);
            }
            // Before the stream's first sample: nothing to interpolate from.
            self.too_early += 1;
            ctx.set_status(serde_json::json!({ "before_the_first_sample": self.too_early }));
            return Ok(());
        };
        let next = &self.history[after];
        let span = next.timestamp.nanos_since(before.timestamp) as f64;
        let t = if span > 0.0 {
            when.nanos_since(before.timestamp) as f64 / span
        } else {
            1.0
        };
        let value = mix(&before.payload, &next.payload, t).ok_or_else(|| {
            ComponentError::failed(format_args!(
                "cannot interpolate between {} and {}",
                describe(&before.payload),
                describe(&next.payload)
            ))
        })?;
        ctx.write_at("out", value, when)
    }
}

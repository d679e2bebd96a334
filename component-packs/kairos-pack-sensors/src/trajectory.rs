//! The simulated vehicle: one deterministic path that every simulated sensor samples.
//!
//! The vehicle stands still for [`Trajectory::rest_s`] seconds, accelerates smoothly for
//! [`Trajectory::ramp_s`] seconds, then drives a figure-eight forever, about 525 m per lap at about
//! 10 m/s (slower at the tips of the loops, where it turns hardest, faster through the crossing), climbing
//! and descending a few metres once per lap so that the crossing is an overpass.
//!
//! The path is a closed curve of a parameter θ:
//!
//! ```text
//! east  = A sin θ
//! north = B sin 2θ
//! up    = C (1 − cos θ) / 2
//! ```
//!
//! and θ is a smooth function of time, so position, velocity, acceleration, attitude and the rates all
//! have exact closed forms: nothing is integrated, and any time can be evaluated on its own.
//!
//! Frames: positions, velocities and accelerations are in the local east-north-up (ENU) frame of the
//! reference point (see [`crate::geo`]); the body frame is x forward, y left, z up. Yaw is measured in the
//! ENU frame, counter-clockwise from east; pitch is positive nose up; the vehicle does not roll.

use std::f64::consts::TAU;

use glam::{DQuat, DVec3};

/// Standard gravity, m/s².
pub const GRAVITY: f64 = 9.806_65;

/// The shape and timing of the vehicle's path. [`Trajectory::default`] is the one the sensors use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trajectory {
    /// Half the east-west extent of the figure-eight (A), metres.
    pub half_length_m: f64,
    /// Half the north-south extent of the figure-eight (B), metres.
    pub half_width_m: f64,
    /// How much the vehicle climbs over half a lap and descends over the other half (C), metres.
    pub climb_m: f64,
    /// Seconds per lap once at cruise.
    pub lap_s: f64,
    /// Seconds standing still at the start.
    pub rest_s: f64,
    /// Seconds spent accelerating from rest to cruise.
    pub ramp_s: f64,
}

impl Default for Trajectory {
    fn default() -> Self {
        Trajectory {
            half_length_m: 100.0,
            half_width_m: 35.0,
            climb_m: 6.0,
            lap_s: 52.0,
            rest_s: 2.0,
            ramp_s: 5.0,
        }
    }
}

/// Where the vehicle is and how it moves at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleState {
    /// Seconds since the start of the trajectory.
    pub time_s: f64,
    /// Position in the local ENU frame, metres.
    pub position: DVec3,
    /// Velocity in the local ENU frame, m/s.
    pub velocity: DVec3,
    /// Acceleration in the local ENU frame, m/s² (gravity not included).
    pub acceleration: DVec3,
    /// Yaw: the direction of travel, radians counter-clockwise from east, in (−π, π].
    pub yaw: f64,
    /// Yaw rate, rad/s (positive turning left).
    pub yaw_rate: f64,
    /// Pitch, radians, positive nose up.
    pub pitch: f64,
    /// Pitch rate, rad/s.
    pub pitch_rate: f64,
    /// Orientation of the body frame (x forward, y left, z up) in the ENU frame.
    pub orientation: DQuat,
    /// Angular velocity in the body frame, rad/s: what a perfect gyroscope reads.
    pub angular_velocity_body: DVec3,
    /// Specific force in the body frame, m/s²: what a perfect accelerometer reads (+g on z at rest).
    pub specific_force_body: DVec3,
}

impl VehicleState {
    /// Ground speed (norm of the velocity), m/s.
    pub fn speed(&self) -> f64 {
        self.velocity.length()
    }

    /// Compass heading, degrees clockwise from north, in [0, 360).
    pub fn heading_deg(&self) -> f64 {
        (90.0 - self.yaw.to_degrees()).rem_euclid(360.0)
    }

    /// Curvature of the path being driven, 1/m (positive turning left); zero when nearly stopped.
    pub fn curvature(&self) -> f64 {
        let speed = self.speed();
        if speed > 0.1 { self.yaw_rate / speed } else { 0.0 }
    }
}

/// The path parameter θ and its first two time derivatives.
#[derive(Debug, Clone, Copy)]
struct Phase {
    theta: f64,
    rate: f64,
    accel: f64,
}

/// A point of the curve at θ and its first two derivatives with respect to θ.
#[derive(Debug, Clone, Copy)]
struct Curve {
    value: DVec3,
    d1: DVec3,
    d2: DVec3,
}

impl Trajectory {
    /// θ's rate at cruise, rad/s.
    fn cruise_rate(&self) -> f64 {
        if self.lap_s > 0.0 { TAU / self.lap_s } else { 0.0 }
    }

    fn phase(&self, time_s: f64) -> Phase {
        let omega = self.cruise_rate();
        let tau = time_s - self.rest_s.max(0.0);
        if tau <= 0.0 {
            return Phase {
                theta: 0.0,
                rate: 0.0,
                accel: 0.0,
            };
        }
        let ramp = self.ramp_s.max(0.0);
        if tau < ramp {
            // θ' follows a smoothstep from 0 to ω: θ' = ω (3u² − 2u³), u = τ / ramp.
            let u = tau / ramp;
            Phase {
                theta: omega * ramp * (u.powi(3) - 0.5 * u.powi(4)),
                rate: omega * (3.0 * u * u - 2.0 * u.powi(3)),
                accel: omega * (6.0 * u - 6.0 * u * u) / ramp,
            }
        } else {
            Phase {
                theta: omega * (0.5 * ramp + (tau - ramp)),
                rate: omega,
                accel: 0.0,
            }
        }
    }

    fn curve(&self, theta: f64) -> Curve {
        let (a, b, c) = (self.half_length_m, self.half_width_m, self.climb_m);
        let (sin1, cos1) = theta.sin_cos();
        let (sin2, cos2) = (2.0 * theta).sin_cos();
        Curve {
            value: DVec3::new(a * sin1, b * sin2, 0.5 * c * (1.0 - cos1)),
            d1: DVec3::new(a * cos1, 2.0 * b * cos2, 0.5 * c * sin1),
            d2: DVec3::new(-a * sin1, -4.0 * b * sin2, 0.5 * c * cos1),
        }
    }

    /// The vehicle's state `time_s` seconds after the start (negative times are the start).
    pub fn state(&self, time_s: f64) -> VehicleState {
        let time_s = if time_s.is_finite() { time_s.max(0.0) } else { 0.0 };
        let phase = self.phase(time_s);
        let curve = self.curve(phase.theta);
        let (d1, d2) = (curve.d1, curve.d2);

        let position = curve.value;
        let velocity = d1 * phase.rate;
        let acceleration = d2 * (phase.rate * phase.rate) + d1 * phase.accel;

        // Attitude follows the tangent of the curve, which is defined even at rest.
        let horizontal_sq = d1.x * d1.x + d1.y * d1.y;
        let horizontal = horizontal_sq.sqrt().max(f64::EPSILON);
        let yaw = d1.y.atan2(d1.x);
        let yaw_per_theta = (d1.x * d2.y - d1.y * d2.x) / horizontal_sq.max(f64::EPSILON);
        let pitch = d1.z.atan2(horizontal);
        let horizontal_d = (d1.x * d2.x + d1.y * d2.y) / horizontal;
        let pitch_per_theta =
            (horizontal * d2.z - d1.z * horizontal_d) / (horizontal_sq + d1.z * d1.z).max(f64::EPSILON);
        let yaw_rate = yaw_per_theta * phase.rate;
        let pitch_rate = pitch_per_theta * phase.rate;

        // Body x forward, y left, z up: yaw about the world z axis, then pitch about the body y axis
        // (a negative rotation about +y lifts the nose).
        let yaw_rotation = DQuat::from_rotation_z(yaw);
        let orientation = (yaw_rotation * DQuat::from_rotation_y(-pitch)).normalize();
        let angular_velocity_world =
            DVec3::new(0.0, 0.0, yaw_rate) + yaw_rotation * DVec3::new(0.0, -pitch_rate, 0.0);
        let to_body = orientation.inverse();
        let angular_velocity_body = to_body * angular_velocity_world;
        let specific_force_body = to_body * (acceleration + DVec3::new(0.0, 0.0, GRAVITY));

        VehicleState {
            time_s,
            position,
            velocity,
            acceleration,
            yaw,
            yaw_rate,
            pitch,
            pitch_rate,
            orientation,
            angular_velocity_body,
            specific_force_body,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numeric_derivative(f: impl Fn(f64) -> DVec3, t: f64) -> DVec3 {
        let h = 1e-4;
        (f(t + h) - f(t - h)) / (2.0 * h)
    }

    fn wrap(angle: f64) -> f64 {
        (angle + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI
    }

    #[test]
    fn at_rest_the_vehicle_reads_gravity_only() {
        let trajectory = Trajectory::default();
        let state = trajectory.state(1.0);
        assert!(state.speed() < 1e-12);
        assert!(state.position.length() < 1e-12);
        assert!(state.angular_velocity_body.length() < 1e-12);
        assert!((state.specific_force_body - DVec3::new(0.0, 0.0, GRAVITY)).length() < 1e-9);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        let trajectory = Trajectory::default();
        for t in [2.5, 4.0, 6.9, 7.0, 10.0, 20.3, 33.3, 47.0, 61.0, 200.0] {
            let state = trajectory.state(t);
            let velocity = numeric_derivative(|s| trajectory.state(s).position, t);
            let acceleration = numeric_derivative(|s| trajectory.state(s).velocity, t);
            assert!((velocity - state.velocity).length() < 1e-5, "velocity at {t}");
            assert!(
                (acceleration - state.acceleration).length() < 1e-4,
                "acceleration at {t}"
            );
            let yaw_rate = wrap(trajectory.state(t + 1e-4).yaw - trajectory.state(t - 1e-4).yaw) / 2e-4;
            assert!((yaw_rate - state.yaw_rate).abs() < 1e-5, "yaw rate at {t}");
            let pitch_rate = (trajectory.state(t + 1e-4).pitch - trajectory.state(t - 1e-4).pitch) / 2e-4;
            assert!((pitch_rate - state.pitch_rate).abs() < 1e-6, "pitch rate at {t}");
            // The body x axis points along the velocity.
            let forward = state.orientation * DVec3::X;
            assert!(
                (forward - state.velocity.normalize()).length() < 1e-9,
                "attitude at {t}"
            );
        }
    }

    #[test]
    fn the_path_is_closed_and_drives_about_ten_metres_per_second() {
        let trajectory = Trajectory::default();
        let start = 2.0 + 5.0 + 10.0;
        let a = trajectory.state(start);
        let b = trajectory.state(start + trajectory.lap_s);
        assert!((a.position - b.position).length() < 1e-9);
        let steps = 5200;
        let dt = trajectory.lap_s / f64::from(steps);
        let speeds: Vec<f64> = (0..steps)
            .map(|i| trajectory.state(start + f64::from(i) * dt).speed())
            .collect();
        let mean = speeds.iter().sum::<f64>() / f64::from(steps);
        let (min, max) = speeds
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), s| (lo.min(*s), hi.max(*s)));
        assert!((9.0..11.0).contains(&mean), "mean speed {mean}");
        assert!(min > 6.0 && max < 15.0, "speed range {min}..{max}");
        let lateral = (0..steps)
            .map(|i| {
                trajectory
                    .state(start + f64::from(i) * dt)
                    .specific_force_body
                    .y
                    .abs()
            })
            .fold(0.0, f64::max);
        assert!(lateral < 3.0, "lateral acceleration {lateral}");
    }
}

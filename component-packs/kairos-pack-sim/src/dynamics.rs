//! Vehicle dynamics: a bicycle model, kinematic at low speed and dynamic (with tyre forces that
//! saturate at the road's friction) at speed, and a longitudinal model with engine power, brakes,
//! drag and rolling resistance; the actuators have limits, lags and a delay.
//!
//! Frames: the world is east-north-up, yaw counter-clockwise from east; the body frame is x forward,
//! y left. Below [`KINEMATIC_BELOW`] the tyres' slip is meaningless (it divides by the speed), so the
//! lateral state follows the kinematic model; above [`DYNAMIC_ABOVE`] the dynamic one; in between a
//! blend of both. The usual treatment, e.g. in Rajamani, *Vehicle Dynamics and Control* (2012), §2–3.

use std::collections::VecDeque;

/// Standard gravity, m/s².
const GRAVITY: f64 = 9.806_65;
/// Air density, kg/m³.
const AIR_DENSITY: f64 = 1.2;
/// Below this speed the lateral model is the kinematic one, m/s.
pub const KINEMATIC_BELOW: f64 = 3.0;
/// Above this speed the lateral model is the dynamic one, m/s.
pub const DYNAMIC_ABOVE: f64 = 6.0;

/// A vehicle's build: a mid-size car by default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleParameters {
    /// Mass, kg.
    pub mass_kg: f64,
    /// Distance from the centre of mass to the front axle, metres.
    pub front_axle_m: f64,
    /// Distance from the centre of mass to the rear axle, metres.
    pub rear_axle_m: f64,
    /// Yaw moment of inertia, kg·m².
    pub yaw_inertia: f64,
    /// Cornering stiffness of the front axle, N/rad.
    pub front_cornering: f64,
    /// Cornering stiffness of the rear axle, N/rad.
    pub rear_cornering: f64,
    /// Tyre-road friction coefficient: the most lateral force an axle gives is this times its load.
    pub friction: f64,
    /// Largest road-wheel steering angle, radians.
    pub max_steering: f64,
    /// Fastest change of the road-wheel angle, rad/s.
    pub steering_rate: f64,
    /// Largest drive force at the wheels, N.
    pub max_drive_force: f64,
    /// Largest power at the wheels, W: above a few m/s it limits the drive force.
    pub max_power: f64,
    /// Largest brake force, N.
    pub max_brake_force: f64,
    /// Time constant of the drive and brake forces following their commands, seconds.
    pub actuator_lag_s: f64,
    /// Delay between a command's arrival and the actuators starting to follow it, seconds.
    pub actuator_delay_s: f64,
    /// Drag area (drag coefficient times frontal area), m².
    pub drag_area: f64,
    /// Rolling resistance coefficient.
    pub rolling: f64,
}

impl Default for VehicleParameters {
    fn default() -> Self {
        VehicleParameters {
            mass_kg: 1500.0,
            front_axle_m: 1.2,
            rear_axle_m: 1.5,
            yaw_inertia: 2250.0,
            front_cornering: 80_000.0,
            rear_cornering: 90_000.0,
            friction: 0.9,
            max_steering: 0.5,
            steering_rate: 0.6,
            max_drive_force: 5000.0,
            max_power: 90_000.0,
            max_brake_force: 12_000.0,
            actuator_lag_s: 0.1,
            actuator_delay_s: 0.05,
            drag_area: 0.7,
            rolling: 0.012,
        }
    }
}

impl VehicleParameters {
    /// The wheelbase, metres.
    pub fn wheelbase(&self) -> f64 {
        self.front_axle_m + self.rear_axle_m
    }
}

/// What the driver (or a controller) asks for.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Commands {
    /// Road-wheel angle, radians, positive to the left.
    pub steering: f64,
    /// Accelerator, 0 to 1.
    pub throttle: f64,
    /// Brake, 0 to 1.
    pub brake: f64,
}

/// The vehicle's state.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct VehicleDynamics {
    /// East, metres.
    pub x: f64,
    /// North, metres.
    pub y: f64,
    /// Yaw, radians counter-clockwise from east.
    pub yaw: f64,
    /// Longitudinal speed (body x), m/s; never negative (the model does not reverse).
    pub vx: f64,
    /// Lateral speed (body y), m/s.
    pub vy: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate: f64,
    /// The road-wheel angle the steering reached, radians.
    pub steering: f64,
    /// The drive force the powertrain reached, N.
    pub drive_force: f64,
    /// The brake force the brakes reached, N.
    pub brake_force: f64,
    /// Body-frame acceleration of the last step (x forward, y left), m/s².
    pub acceleration: (f64, f64),
}

/// The vehicle and the commands on their way to its actuators.
#[derive(Debug, Clone)]
pub struct Vehicle {
    /// Its build.
    pub parameters: VehicleParameters,
    /// Its state.
    pub state: VehicleDynamics,
    /// Commands received, with the simulated time they arrived, not yet acting.
    pending: VecDeque<(f64, Commands)>,
    /// The commands the actuators follow now.
    acting: Commands,
    /// Simulated seconds since the start.
    time_s: f64,
}

/// Smoothstep from 0 at `from` to 1 at `to`.
fn blend(value: f64, from: f64, to: f64) -> f64 {
    let t = ((value - from) / (to - from)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

impl Vehicle {
    /// A vehicle at rest at `(x, y)` heading `yaw`, or rolling at `speed` m/s.
    pub fn new(parameters: VehicleParameters, x: f64, y: f64, yaw: f64, speed: f64) -> Vehicle {
        Vehicle {
            parameters,
            state: VehicleDynamics {
                x,
                y,
                yaw,
                vx: speed.max(0.0),
                ..VehicleDynamics::default()
            },
            pending: VecDeque::new(),
            acting: Commands::default(),
            time_s: 0.0,
        }
    }

    /// Simulated seconds since the start.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// The speed over the ground, m/s.
    pub fn speed(&self) -> f64 {
        self.state.vx.hypot(self.state.vy)
    }

    /// Whether the lateral model is the dynamic one (else kinematic or a blend).
    pub fn is_dynamic(&self) -> bool {
        self.state.vx >= DYNAMIC_ABOVE
    }

    /// Hands the actuators `commands` now; they act after the actuator delay.
    pub fn command(&mut self, commands: Commands) {
        self.pending.push_back((self.time_s, commands));
    }

    /// Advances `duration` seconds in steps of at most `step` seconds.
    pub fn advance(&mut self, duration: f64, step: f64) {
        let step = step.max(1e-4);
        let mut left = duration.max(0.0);
        while left > 1e-12 {
            let dt = left.min(step);
            self.step(dt);
            left -= dt;
        }
    }

    /// One integration step of `dt` seconds (semi-implicit Euler: speeds first, then positions).
    fn step(&mut self, dt: f64) {
        self.time_s += dt;
        let delay = self.parameters.actuator_delay_s;
        while let Some(&(arrived, commands)) = self.pending.front() {
            if arrived + delay > self.time_s + 1e-12 {
                break;
            }
            self.acting = commands;
            self.pending.pop_front();
        }
        let p = self.parameters;
        let s = &mut self.state;

        // Actuators: the steering turns at a limited rate, the forces follow with a lag.
        let target = self.acting.steering.clamp(-p.max_steering, p.max_steering);
        let turn = p.steering_rate * dt;
        s.steering += (target - s.steering).clamp(-turn, turn);
        let follow = 1.0 - (-dt / p.actuator_lag_s.max(1e-3)).exp();
        let drive = self.acting.throttle.clamp(0.0, 1.0) * p.max_drive_force.min(p.max_power / s.vx.max(1.0));
        s.drive_force += (drive - s.drive_force) * follow;
        let brake = self.acting.brake.clamp(0.0, 1.0) * p.max_brake_force;
        s.brake_force += (brake - s.brake_force) * follow;

        // Longitudinal: drive against brakes, drag and rolling resistance, which only hold a car still.
        let resisting =
            s.brake_force + 0.5 * AIR_DENSITY * p.drag_area * s.vx * s.vx + p.rolling * p.mass_kg * GRAVITY;
        let mut force = s.drive_force;
        if s.vx > 1e-3 || s.drive_force > resisting {
            force -= resisting;
        } else {
            force = 0.0;
        }

        // Lateral, dynamic: slip angles, axle forces saturating at the friction limit.
        let wheelbase = p.wheelbase();
        let (front_load, rear_load) = (
            p.mass_kg * GRAVITY * p.rear_axle_m / wheelbase,
            p.mass_kg * GRAVITY * p.front_axle_m / wheelbase,
        );
        let vx = s.vx.max(0.5);
        let front_slip = s.steering - ((s.vy + p.front_axle_m * s.yaw_rate) / vx).atan();
        let rear_slip = -((s.vy - p.rear_axle_m * s.yaw_rate) / vx).atan();
        let front_force =
            (p.front_cornering * front_slip).clamp(-p.friction * front_load, p.friction * front_load);
        let rear_force =
            (p.rear_cornering * rear_slip).clamp(-p.friction * rear_load, p.friction * rear_load);
        let (sin, cos) = s.steering.sin_cos();
        let ax = (force - front_force * sin) / p.mass_kg;
        let ay = (front_force * cos + rear_force) / p.mass_kg;
        let yaw_accel = (p.front_axle_m * front_force * cos - p.rear_axle_m * rear_force) / p.yaw_inertia;

        let forward_speed = (s.vx + (ax + s.vy * s.yaw_rate) * dt).max(0.0);
        let dynamic_vy = s.vy + (ay - s.vx * s.yaw_rate) * dt;
        let dynamic_r = s.yaw_rate + yaw_accel * dt;

        // Lateral, kinematic: the velocity at the centre of mass points at the slip angle the
        // geometry gives, the yaw rate follows the path's curvature.
        let slip = (p.rear_axle_m * s.steering.tan() / wheelbase).atan();
        let kinematic_vy = forward_speed * slip.tan();
        let kinematic_r = forward_speed * s.steering.tan() / wheelbase;

        let w = blend(forward_speed, KINEMATIC_BELOW, DYNAMIC_ABOVE);
        let lateral_speed = w * dynamic_vy + (1.0 - w) * kinematic_vy;
        let turn_rate = w * dynamic_r + (1.0 - w) * kinematic_r;
        s.acceleration = (
            (forward_speed - s.vx) / dt - s.vy * s.yaw_rate,
            (lateral_speed - s.vy) / dt + s.vx * s.yaw_rate,
        );
        s.vx = forward_speed;
        s.vy = lateral_speed;
        s.yaw_rate = turn_rate;
        s.yaw += s.yaw_rate * dt;
        let (sin_yaw, cos_yaw) = s.yaw.sin_cos();
        s.x += (s.vx * cos_yaw - s.vy * sin_yaw) * dt;
        s.y += (s.vx * sin_yaw + s.vy * cos_yaw) * dt;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(vehicle: &mut Vehicle, seconds: f64, commands: Commands) {
        for _ in 0..(seconds * 100.0).round() as usize {
            vehicle.command(commands);
            vehicle.advance(0.01, 0.001);
        }
    }

    #[test]
    fn full_throttle_accelerates_within_the_power_limit_and_brakes_stop() {
        let mut car = Vehicle::new(VehicleParameters::default(), 0.0, 0.0, 0.0, 0.0);
        let throttle = Commands {
            throttle: 1.0,
            ..Commands::default()
        };
        run(&mut car, 10.0, throttle);
        // 0–100 km/h in about 9 s for 60 kW/t; no faster than the power allows.
        let speed = car.speed();
        assert!((22.0..30.0).contains(&speed), "speed after 10 s: {speed}");
        assert!(car.state.y.abs() < 1e-9 && car.state.yaw.abs() < 1e-12);
        let brake = Commands {
            brake: 1.0,
            ..Commands::default()
        };
        run(&mut car, 4.0, brake);
        assert!(car.speed() < 1e-9, "stopped: {}", car.speed());
        let stopped_at = car.state.x;
        run(&mut car, 1.0, brake);
        assert!((car.state.x - stopped_at).abs() < 1e-9, "does not roll back");
    }

    #[test]
    fn steady_cornering_matches_the_bicycle_model() {
        // At 15 m/s with a small steering angle the dynamic model's yaw rate is the textbook steady
        // state: r = v δ / (L + K v²), with the understeer gradient K = m (lr Cr − lf Cf) / (L Cf Cr).
        let p = VehicleParameters::default();
        let mut car = Vehicle::new(p, 0.0, 0.0, 0.0, 15.0);
        let steering = 0.02;
        let mut commands = Commands {
            steering,
            throttle: 0.0,
            brake: 0.0,
        };
        // Hold the speed with a little throttle against drag.
        for _ in 0..1000 {
            commands.throttle = (0.5 * (15.0 - car.state.vx) + 0.07).clamp(0.0, 1.0);
            car.command(commands);
            car.advance(0.01, 0.001);
        }
        let l = p.wheelbase();
        let k = p.mass_kg * (p.rear_axle_m * p.rear_cornering - p.front_axle_m * p.front_cornering)
            / (l * p.front_cornering * p.rear_cornering);
        let v = car.state.vx;
        let expected = v * steering / (l + k * v * v);
        assert!(car.is_dynamic());
        assert!(
            (car.state.yaw_rate - expected).abs() < 0.01 * expected,
            "yaw rate {} vs {expected}",
            car.state.yaw_rate
        );
    }

    #[test]
    fn at_walking_pace_the_path_follows_the_geometry() {
        let p = VehicleParameters::default();
        let mut car = Vehicle::new(p, 0.0, 0.0, 0.0, 2.0);
        let steering = 0.3;
        run(
            &mut car,
            3.0,
            Commands {
                steering,
                throttle: 0.05,
                brake: 0.0,
            },
        );
        let curvature = car.state.yaw_rate / car.state.vx;
        let expected = steering.tan() / p.wheelbase();
        assert!(
            (curvature - expected).abs() < 0.01 * expected,
            "{curvature} vs {expected}"
        );
    }

    #[test]
    fn the_tyres_saturate_and_the_steering_is_slow_and_late() {
        let p = VehicleParameters::default();
        let mut car = Vehicle::new(p, 0.0, 0.0, 0.0, 25.0);
        let hard = Commands {
            steering: 0.5,
            throttle: 0.3,
            brake: 0.0,
        };
        car.command(hard);
        car.advance(0.04, 0.001);
        assert!(
            car.state.steering.abs() < 1e-12,
            "the delay holds the command back"
        );
        car.advance(0.11, 0.001);
        assert!((car.state.steering - 0.06).abs() < 1e-3, "0.6 rad/s for 0.1 s");
        run(&mut car, 2.0, hard);
        // Lateral acceleration cannot pass the friction limit.
        let lateral = car.state.acceleration.1.abs();
        assert!(lateral <= 0.9 * GRAVITY * 1.05, "lateral acceleration {lateral}");
        assert!(lateral > 0.6 * GRAVITY, "at the limit: {lateral}");
    }
}

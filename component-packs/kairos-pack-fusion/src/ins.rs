//! A GNSS + IMU navigation filter: an error-state extended Kalman filter over 15 states.
//!
//! The IMU drives a strapdown solution (position, velocity and attitude in a local ENU frame, integrated
//! from the body-frame angular rate and specific force, less their estimated biases). The filter keeps
//! the covariance of its errors: position, velocity, attitude (a small rotation), gyroscope bias and
//! accelerometer bias, 3 each. A GNSS position corrects them all through their correlations: this is how
//! the heading and the biases become known while the vehicle moves. A fix whose innovation is too
//! unlikely for the covariance (χ² gate, 3 degrees of freedom) is rejected and counted; if every fix is
//! rejected for `reset_after_s`, the filter trusts GNSS again and restarts its position there.
//!
//! Frames: ENU as in the rest of Kairos; body x forward, y left, z up; `q` rotates body vectors into ENU.

use glam::{DMat3, DQuat, DVec3};

use crate::matrix::Matrix;

/// Standard gravity, m/s².
const GRAVITY: f64 = 9.806_65;

const POSITION: usize = 0;
const VELOCITY: usize = 3;
const ATTITUDE: usize = 6;
const GYRO_BIAS: usize = 9;
const ACCEL_BIAS: usize = 12;

type Covariance = Matrix<15, 15>;

/// The sensors' noise and the filter's limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsConfig {
    /// Gyroscope noise density, rad/s/√Hz.
    pub gyro_noise: f64,
    /// Accelerometer noise density, m/s²/√Hz.
    pub accel_noise: f64,
    /// Gyroscope bias random walk, rad/s/√s.
    pub gyro_bias_walk: f64,
    /// Accelerometer bias random walk, m/s²/√s.
    pub accel_bias_walk: f64,
    /// χ² bound on a fix's innovation (3 degrees of freedom; 16.3 rejects one good fix in 1000).
    pub gate: f64,
    /// After this long with every fix rejected, the next fix resets the position, seconds.
    pub reset_after_s: f64,
}

impl Default for InsConfig {
    fn default() -> Self {
        InsConfig {
            gyro_noise: 0.002,
            accel_noise: 0.02,
            gyro_bias_walk: 1e-5,
            accel_bias_walk: 1e-4,
            gate: 16.3,
            reset_after_s: 10.0,
        }
    }
}

/// What the filter did with its inputs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InsCounters {
    /// IMU samples integrated.
    pub imu_used: u64,
    /// IMU samples skipped: not a number, or out of time order.
    pub imu_skipped: u64,
    /// Fixes that corrected the solution.
    pub fixes_used: u64,
    /// Fixes rejected by the gate.
    pub fixes_rejected: u64,
    /// Fixes skipped: not a number, no fix, or no accuracy.
    pub fixes_skipped: u64,
    /// Times the position restarted at a fix after a run of rejections.
    pub resets: u64,
}

/// What a fix did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixOutcome {
    /// It corrected the solution.
    Used,
    /// Its innovation failed the gate (the χ² value).
    Rejected(f64),
    /// It restarted the position after a run of rejections.
    Reset,
    /// It was not usable.
    Skipped,
}

/// The filter.
#[derive(Debug, Clone)]
pub struct Ins {
    config: InsConfig,
    position: DVec3,
    velocity: DVec3,
    attitude: DQuat,
    gyro_bias: DVec3,
    accel_bias: DVec3,
    covariance: Covariance,
    /// Seconds of the last IMU sample integrated.
    time_s: f64,
    /// When the current run of rejected fixes began.
    rejecting_since_s: Option<f64>,
    counters: InsCounters,
}

/// One-sigma uncertainties to start from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialUncertainty {
    /// Position, metres (each axis).
    pub position_m: f64,
    /// Velocity, m/s.
    pub velocity_m_s: f64,
    /// Roll and pitch, radians.
    pub tilt_rad: f64,
    /// Heading, radians.
    pub heading_rad: f64,
}

fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, v.z, -v.y),
        DVec3::new(-v.z, 0.0, v.x),
        DVec3::new(v.y, -v.x, 0.0),
    )
}

fn block(m: DMat3) -> Matrix<3, 3> {
    // glam stores columns; ours are rows.
    Matrix(m.transpose().to_cols_array_2d())
}

fn vector(m: &Matrix<3, 1>) -> DVec3 {
    DVec3::new(m.0[0][0], m.0[1][0], m.0[2][0])
}

impl Ins {
    /// A filter starting at `position`, `velocity` and `attitude` at `time_s`.
    pub fn new(
        config: InsConfig,
        (position, velocity, attitude): (DVec3, DVec3, DQuat),
        uncertainty: InitialUncertainty,
        time_s: f64,
    ) -> Self {
        let square = |v: f64| v * v;
        let mut diagonal = [0.0; 15];
        diagonal[POSITION..POSITION + 3].fill(square(uncertainty.position_m));
        diagonal[VELOCITY..VELOCITY + 3].fill(square(uncertainty.velocity_m_s));
        diagonal[ATTITUDE..ATTITUDE + 2].fill(square(uncertainty.tilt_rad));
        diagonal[ATTITUDE + 2] = square(uncertainty.heading_rad);
        diagonal[GYRO_BIAS..GYRO_BIAS + 3].fill(square(0.01));
        diagonal[ACCEL_BIAS..ACCEL_BIAS + 3].fill(square(0.1));
        Ins {
            config,
            position,
            velocity,
            attitude: attitude.normalize(),
            gyro_bias: DVec3::ZERO,
            accel_bias: DVec3::ZERO,
            covariance: Covariance::diagonal(diagonal),
            time_s,
            rejecting_since_s: None,
            counters: InsCounters::default(),
        }
    }

    /// Position in the local ENU frame, metres.
    pub fn position(&self) -> DVec3 {
        self.position
    }

    /// Velocity in the local ENU frame, m/s.
    pub fn velocity(&self) -> DVec3 {
        self.velocity
    }

    /// Body-to-ENU rotation.
    pub fn attitude(&self) -> DQuat {
        self.attitude
    }

    /// Direction the body's x axis points, radians counter-clockwise from east.
    pub fn yaw(&self) -> f64 {
        let forward = self.attitude * DVec3::X;
        forward.y.atan2(forward.x)
    }

    /// Estimated gyroscope and accelerometer biases.
    pub fn biases(&self) -> (DVec3, DVec3) {
        (self.gyro_bias, self.accel_bias)
    }

    /// One-sigma uncertainties: position (3), velocity (3), heading (radians).
    pub fn sigmas(&self) -> ([f64; 3], [f64; 3], f64) {
        let p = &self.covariance.0;
        let sd = |i: usize| p[i][i].max(0.0).sqrt();
        (
            [sd(POSITION), sd(POSITION + 1), sd(POSITION + 2)],
            [sd(VELOCITY), sd(VELOCITY + 1), sd(VELOCITY + 2)],
            sd(ATTITUDE + 2),
        )
    }

    /// The covariance of position, velocity and attitude errors (9×9).
    pub fn navigation_covariance(&self) -> Matrix<9, 9> {
        self.covariance.block(0, 0)
    }

    /// What the filter did so far.
    pub fn counters(&self) -> InsCounters {
        self.counters
    }

    /// Seconds of the last IMU sample.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Integrates one IMU sample taken at `time_s`: `angular_rate` (rad/s) and `specific_force` (m/s²,
    /// gravity included) in the body frame. A sample with a non-finite value, or not after the last, is
    /// skipped and counted. Returns whether it was used.
    pub fn propagate(&mut self, time_s: f64, angular_rate: DVec3, specific_force: DVec3) -> bool {
        let dt = time_s - self.time_s;
        if !(angular_rate.is_finite() && specific_force.is_finite() && time_s.is_finite()) || dt <= 0.0 {
            self.counters.imu_skipped += 1;
            return false;
        }
        // A gap longer than a second (a stalled sensor) is integrated in one step of at most a second:
        // the covariance grows for the whole gap all the same.
        let step = dt.min(1.0);
        let rate = angular_rate - self.gyro_bias;
        let force = specific_force - self.accel_bias;
        let rotation = DMat3::from_quat(self.attitude);
        let acceleration = rotation * force - DVec3::new(0.0, 0.0, GRAVITY);
        self.position += self.velocity * step + 0.5 * acceleration * step * step;
        self.velocity += acceleration * step;
        self.attitude = (self.attitude * DQuat::from_scaled_axis(rate * step)).normalize();

        let mut transition = Covariance::identity();
        transition.set_block(POSITION, VELOCITY, &block(DMat3::IDENTITY * step));
        transition.set_block(VELOCITY, ATTITUDE, &block(-(rotation * skew(force)) * step));
        transition.set_block(VELOCITY, ACCEL_BIAS, &block(-rotation * step));
        transition.set_block(ATTITUDE, ATTITUDE, &block(DMat3::IDENTITY - skew(rate) * step));
        transition.set_block(ATTITUDE, GYRO_BIAS, &block(DMat3::IDENTITY * -step));
        let c = &self.config;
        let mut noise = [0.0; 15];
        noise[VELOCITY..VELOCITY + 3].fill(c.accel_noise * c.accel_noise * dt);
        noise[ATTITUDE..ATTITUDE + 3].fill(c.gyro_noise * c.gyro_noise * dt);
        noise[GYRO_BIAS..GYRO_BIAS + 3].fill(c.gyro_bias_walk * c.gyro_bias_walk * dt);
        noise[ACCEL_BIAS..ACCEL_BIAS + 3].fill(c.accel_bias_walk * c.accel_bias_walk * dt);
        let propagated = &(&transition * &self.covariance) * &transition.transpose();
        self.covariance = (propagated + Covariance::diagonal(noise)).symmetrised();
        self.time_s = time_s;
        self.counters.imu_used += 1;
        true
    }

    /// Corrects the solution with a GNSS position (ENU, metres) and its one-sigma accuracies (east,
    /// north, up), taken at `time_s`.
    pub fn correct_position(&mut self, time_s: f64, measured: DVec3, sigma: DVec3) -> FixOutcome {
        if !(measured.is_finite() && sigma.is_finite()) || sigma.min_element() <= 0.0 {
            self.counters.fixes_skipped += 1;
            return FixOutcome::Skipped;
        }
        let innovation = measured - self.position;
        let noise = DMat3::from_diagonal(sigma * sigma);
        let p = &self.covariance;
        let position_block = p.block::<3, 3>(POSITION, POSITION);
        let innovation_covariance = DMat3::from_cols_array_2d(&position_block.transpose().0) + noise;
        let inverse = innovation_covariance.inverse();
        let chi2 = innovation.dot(inverse * innovation);
        if !chi2.is_finite() || chi2 > self.config.gate {
            let since = *self.rejecting_since_s.get_or_insert(time_s);
            if time_s - since >= self.config.reset_after_s {
                self.reset_position(measured, sigma);
                return FixOutcome::Reset;
            }
            self.counters.fixes_rejected += 1;
            return FixOutcome::Rejected(chi2);
        }
        self.rejecting_since_s = None;
        // K = P Hᵀ S⁻¹, with H picking the position: P Hᵀ is P's first three columns.
        let columns: Matrix<15, 3> = p.block(0, POSITION);
        let gain = &columns * &block(inverse);
        let innovation_column = Matrix([[innovation.x], [innovation.y], [innovation.z]]);
        let correction = &gain * &innovation_column;
        // Joseph form: (I − KH) P (I − KH)ᵀ + K R Kᵀ stays positive definite despite rounding.
        let mut kh = Covariance::zeros();
        kh.set_block(0, POSITION, &gain);
        let keep = Covariance::identity() - kh;
        let updated = &(&keep * p) * &keep.transpose();
        let measurement = &(&gain * &block(noise)) * &gain.transpose();
        let covariance = (updated + measurement).symmetrised();
        let delta = |at: usize| vector(&correction.block::<3, 1>(at, 0));
        let next = (
            self.position + delta(POSITION),
            self.velocity + delta(VELOCITY),
            (self.attitude * DQuat::from_scaled_axis(delta(ATTITUDE))).normalize(),
            self.gyro_bias + delta(GYRO_BIAS),
            self.accel_bias + delta(ACCEL_BIAS),
        );
        if !(covariance.is_finite() && next.0.is_finite() && next.1.is_finite() && next.2.is_finite()) {
            // Never let a bad number in: keep the solution as it was.
            self.counters.fixes_skipped += 1;
            return FixOutcome::Skipped;
        }
        (
            self.position,
            self.velocity,
            self.attitude,
            self.gyro_bias,
            self.accel_bias,
        ) = next;
        self.covariance = covariance;
        self.counters.fixes_used += 1;
        FixOutcome::Used
    }

    fn reset_position(&mut self, measured: DVec3, sigma: DVec3) {
        self.position = measured;
        let mut p = Covariance::zeros();
        p.set_block(POSITION, POSITION, &block(DMat3::from_diagonal(sigma * sigma)));
        // Forget every correlation with the old position.
        for i in 0..15 {
            for j in 0..15 {
                let in_position = |k: usize| (POSITION..POSITION + 3).contains(&k);
                if !in_position(i) && !in_position(j) {
                    p.0[i][j] = self.covariance.0[i][j];
                }
            }
        }
        self.covariance = p;
        self.rejecting_since_s = None;
        self.counters.resets += 1;
    }
}

#[cfg(test)]
mod tests {
    use glam::{DQuat, DVec3};

    use super::{FixOutcome, InitialUncertainty, Ins, InsConfig};

    fn still() -> Ins {
        let uncertainty = InitialUncertainty {
            position_m: 1.0,
            velocity_m_s: 0.1,
            tilt_rad: 0.01,
            heading_rad: 0.1,
        };
        Ins::new(
            InsConfig::default(),
            (DVec3::ZERO, DVec3::ZERO, DQuat::IDENTITY),
            uncertainty,
            0.0,
        )
    }

    #[test]
    fn at_rest_it_stays_put_and_fixes_shrink_the_uncertainty() {
        let mut ins = still();
        let gravity = DVec3::new(0.0, 0.0, 9.806_65);
        for k in 1..=1000 {
            assert!(ins.propagate(f64::from(k) * 0.01, DVec3::ZERO, gravity));
            if k % 10 == 0 {
                assert_eq!(
                    ins.correct_position(f64::from(k) * 0.01, DVec3::ZERO, DVec3::splat(0.5)),
                    FixOutcome::Used
                );
            }
        }
        assert!(ins.position().length() < 0.01, "{}", ins.position());
        assert!(ins.sigmas().0[0] < 0.2, "{:?}", ins.sigmas());
    }

    #[test]
    fn nan_samples_are_skipped_and_a_far_fix_is_rejected_until_it_persists() {
        let mut ins = still();
        let gravity = DVec3::new(0.0, 0.0, 9.806_65);
        assert!(!ins.propagate(0.01, DVec3::NAN, gravity));
        assert!(!ins.propagate(0.0, DVec3::ZERO, gravity), "not after the last");
        assert_eq!(
            ins.correct_position(0.0, DVec3::new(f64::NAN, 0.0, 0.0), DVec3::ONE),
            FixOutcome::Skipped
        );
        let far = DVec3::new(1000.0, 0.0, 0.0);
        let mut outcome = FixOutcome::Skipped;
        for k in 1..=1200 {
            let t = f64::from(k) * 0.01;
            ins.propagate(t, DVec3::ZERO, gravity);
            if k % 10 == 0 {
                outcome = ins.correct_position(t, far, DVec3::splat(0.5));
                if k < 1000 {
                    assert!(matches!(outcome, FixOutcome::Rejected(_)), "{k}: {outcome:?}");
                }
            }
            assert!(ins.position().is_finite() && ins.velocity().is_finite());
        }
        let counters = ins.counters();
        assert_eq!(
            (counters.imu_skipped, counters.fixes_skipped, counters.resets),
            (2, 1, 1),
            "{counters:?}"
        );
        assert!(counters.fixes_rejected >= 99, "{counters:?}");
        assert_eq!(outcome, FixOutcome::Used, "after the reset, fixes there are used");
        assert!((ins.position() - far).length() < 1.0, "{}", ins.position());
    }
}

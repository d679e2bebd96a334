//! `sensors.gnss`: a simulated satellite navigation receiver on the simulated vehicle.

use glam::DVec3;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, ExecutionMode, FixStatus,
    GnssFix, Payload, Value,
};

use crate::geo::{GeoPoint, LocalFrame};
use crate::trajectory::Trajectory;
use crate::world::WorldView;
use crate::{Seen, TimeBase, apply_rate, rate_changed, rate_property, seen, with_vehicle_input};
use kairos_sdk::rng::NoiseRng;

/// The component's type name.
pub const TYPE_NAME: &str = "sensors.gnss";

/// Separates the receiver's noise stream from other sensors given the same seed.
const NOISE_SALT: u64 = 0x6E55_F1C5;

/// Vertical error relative to horizontal error, as receivers typically report.
const VERTICAL_FACTOR: f64 = 1.5;

/// The descriptor of `sensors.gnss`.
pub fn descriptor() -> ComponentInfo {
    with_vehicle_input(Descriptor::new(
        TYPE_NAME,
        "sensors",
        "Simulated GNSS receiver on the simulated vehicle: WGS84 fixes around a reference point (with a \
         simulator, its world's origin), with time-correlated noise and an outage action",
    ))
    .label("Simulated GNSS receiver")
    .mode(ExecutionMode::Periodic)
    .output(
        "fix",
        DataType::GnssFix,
        "Latitude, longitude, altitude, one-sigma accuracies and fix status",
    )
    .property(rate_property(10.0, 100.0, "fixes"))
    .property(
        Property::f64("noise_m", 0.5).unit("m").range(0.0, 100.0).live().doc(
            "Standard deviation of the horizontal position error per axis, m (vertical: 1.5 times as much)",
        ),
    )
    .property(
        Property::f64("noise_correlation_s", 5.0).unit("s")
            .range(0.0, 3600.0)
            .live()
            .doc("Time constant of the position error (first-order Gauss-Markov), s; 0 gives white noise"),
    )
    .property(
        Property::i64("seed", 2).doc("Seed of the noise generator: the same seed gives the same output"),
    )
    .property(
        Property::f64("latitude", 48.7167).unit("deg N")
            .range(-89.0, 89.0)
            .doc("Latitude of the reference point (the start of the trajectory), degrees north"),
    )
    .property(
        Property::f64("longitude", 2.2333).unit("deg E")
            .range(-180.0, 180.0)
            .doc("Longitude of the reference point, degrees east"),
    )
    .property(
        Property::f64("altitude", 150.0).unit("m")
            .range(-500.0, 9000.0)
            .doc("Height of the reference point above the WGS84 ellipsoid, m"),
    )
    .action(
        "outage",
        "Toggles a simulated loss of fix: status NoFix, the last position repeated",
    )
    .build()
}

/// The `sensors.gnss` component. See [`descriptor`].
#[derive(Debug)]
pub struct GnssSensor {
    trajectory: Trajectory,
    frame: LocalFrame,
    time: TimeBase,
    rng: NoiseRng,
    noise_m: f64,
    correlation_s: f64,
    /// The current position error (east, north, up), metres, and the trajectory time it belongs to.
    error: Option<(DVec3, f64)>,
    outage: bool,
    last_fix: Option<GnssFix>,
    /// A simulator's newest world, when the `vehicle` input is connected.
    world: Option<WorldView>,
}

impl Default for GnssSensor {
    fn default() -> Self {
        GnssSensor {
            trajectory: Trajectory::default(),
            frame: LocalFrame::new(GeoPoint::new(48.7167, 2.2333, 150.0)),
            time: TimeBase::default(),
            rng: NoiseRng::new(2, NOISE_SALT),
            noise_m: 0.0,
            correlation_s: 0.0,
            error: None,
            outage: false,
            last_fix: None,
            world: None,
        }
    }
}

impl GnssSensor {
    /// Whether a simulated outage is in progress.
    pub fn in_outage(&self) -> bool {
        self.outage
    }

    /// One standard-normal vector scaled to the horizontal and vertical error.
    fn draw(&mut self, scale: f64) -> DVec3 {
        let horizontal = scale * self.noise_m;
        DVec3::new(
            self.rng.normal(horizontal),
            self.rng.normal(horizontal),
            self.rng.normal(VERTICAL_FACTOR * horizontal),
        )
    }

    /// Advances the first-order Gauss-Markov error to `time_s`; its steady-state spread is `noise_m`.
    fn error_at(&mut self, time_s: f64) -> DVec3 {
        let error = match self.error {
            None => self.draw(1.0),
            Some((previous, at)) => {
                let step = (time_s - at).max(0.0);
                let keep = if self.correlation_s > 0.0 {
                    (-step / self.correlation_s).exp()
                } else {
                    0.0
                };
                previous * keep + self.draw((1.0 - keep * keep).sqrt())
            }
        };
        self.error = Some((error, time_s));
        error
    }
}

impl Component for GnssSensor {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let origin = GeoPoint::new(
            ctx.f64_property("latitude")?,
            ctx.f64_property("longitude")?,
            ctx.f64_property("altitude")?,
        );
        self.frame = LocalFrame::new(origin);
        self.time = TimeBase::default();
        self.rng = NoiseRng::new(ctx.i64_property("seed")?, NOISE_SALT);
        self.noise_m = ctx.f64_property("noise_m")?;
        self.correlation_s = ctx.f64_property("noise_correlation_s")?;
        self.error = None;
        self.outage = false;
        self.last_fix = None;
        apply_rate(ctx)?;
        tracing::debug!(component = ctx.id(), ?origin, period = ?ctx.period(), "simulated GNSS started");
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let Some(seen) = seen(ctx, &self.trajectory, &mut self.time, &mut self.world)? else {
            return Ok(());
        };
        if let Seen::World(view) = &seen
            && self.frame.origin() != view.origin
        {
            self.frame = LocalFrame::new(view.origin);
        }
        let state = *seen.state();
        let time_s = state.time_s;
        // The error keeps evolving during an outage, so the fix resumes where the noise would be.
        let error = self.error_at(time_s);
        let fix = if self.outage {
            let last = self.last_fix.unwrap_or_else(|| {
                let origin = self.frame.origin();
                GnssFix {
                    latitude_deg: origin.latitude_deg,
                    longitude_deg: origin.longitude_deg,
                    altitude_m: origin.altitude_m,
                    horizontal_accuracy_m: self.noise_m,
                    vertical_accuracy_m: VERTICAL_FACTOR * self.noise_m,
                    status: FixStatus::NoFix,
                }
            });
            GnssFix {
                status: FixStatus::NoFix,
                ..last
            }
        } else {
            let point = self.frame.to_geodetic(state.position + error);
            let fix = GnssFix {
                latitude_deg: point.latitude_deg,
                longitude_deg: point.longitude_deg,
                altitude_m: point.altitude_m,
                horizontal_accuracy_m: self.noise_m,
                vertical_accuracy_m: VERTICAL_FACTOR * self.noise_m,
                status: FixStatus::Fix,
            };
            self.last_fix = Some(fix);
            fix
        };
        ctx.write_at("fix", Payload::GnssFix(fix), now)
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        rate_changed(name, value, ctx);
        match name {
            "noise_m" => self.noise_m = ctx.f64_property(name)?,
            "noise_correlation_s" => self.correlation_s = ctx.f64_property(name)?,
            _ => {}
        }
        Ok(())
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        if name != "outage" {
            return Err(ComponentError::failed(format_args!("no action named '{name}'")));
        }
        self.outage = !self.outage;
        tracing::info!(
            component = ctx.id(),
            outage = self.outage,
            "simulated GNSS outage toggled"
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use kairos_sdk::harness::{Harness, HarnessOutput};
    use kairos_sdk::{FixStatus, GnssFix, Payload, Value};

    use super::{GnssSensor, descriptor};
    use crate::geo::{GeoPoint, LocalFrame};
    use crate::trajectory::Trajectory;

    fn fixes(out: &HarnessOutput) -> Vec<GnssFix> {
        out.samples("fix")
            .iter()
            .map(|s| match &s.payload {
                Payload::GnssFix(fix) => *fix,
                other => panic!("unexpected {other:?}"),
            })
            .collect()
    }

    fn harness(properties: &[(&str, Value)]) -> Harness {
        let mut harness = Harness::new(descriptor(), GnssSensor::default());
        harness.leave_unconnected("vehicle");
        for (name, value) in properties {
            harness.set_property(name, value.clone()).expect("property");
        }
        harness
    }

    fn local(fix: &GnssFix) -> DVec3 {
        LocalFrame::new(GeoPoint::new(48.7167, 2.2333, 150.0)).to_enu(GeoPoint::new(
            fix.latitude_deg,
            fix.longitude_deg,
            fix.altitude_m,
        ))
    }

    #[test]
    fn consecutive_fixes_imply_the_trajectory_speed() {
        let trajectory = Trajectory::default();
        // Without noise: every pair of consecutive fixes.
        let exact = fixes(
            &harness(&[("noise_m", Value::F64(0.0))])
                .run_periodic(300)
                .expect("runs"),
        );
        assert_eq!(exact.len(), 300);
        assert!(exact.iter().all(|f| f.status == FixStatus::Fix));
        for i in 1..exact.len() {
            let speed = (local(&exact[i]) - local(&exact[i - 1])).length() / 0.1;
            let expected = trajectory.state((i as f64 - 0.5) * 0.1).speed();
            assert!((speed - expected).abs() < 0.05, "fix {i}: {speed} vs {expected}");
        }
        // With the default noise: consecutive pairs are noisy, their average is close.
        let noisy = fixes(&harness(&[]).run_periodic(300).expect("runs"));
        let (from, to) = (100, 300);
        let measured: f64 = (from + 1..to)
            .map(|i| (local(&noisy[i]) - local(&noisy[i - 1])).length() / 0.1)
            .sum::<f64>()
            / (to - from - 1) as f64;
        let truth: f64 = (from + 1..to)
            .map(|i| trajectory.state((i as f64 - 0.5) * 0.1).speed())
            .sum::<f64>()
            / (to - from - 1) as f64;
        assert!((measured - truth).abs() < 1.0, "{measured} vs {truth}");
        // And the noise has about the configured size.
        let spread = (0..300)
            .map(|i| {
                (local(&noisy[i]) - trajectory.state(i as f64 * 0.1).position)
                    .truncate()
                    .length()
            })
            .fold(0.0, f64::max);
        assert!(spread > 0.05 && spread < 3.0, "{spread}");
        assert!(
            noisy
                .iter()
                .all(|f| (f.horizontal_accuracy_m - 0.5).abs() < 1e-12)
        );
    }

    #[test]
    fn starts_at_the_reference_point() {
        let out = harness(&[
            ("noise_m", Value::F64(0.0)),
            ("latitude", Value::F64(-33.9)),
            ("longitude", Value::F64(151.2)),
            ("altitude", Value::F64(20.0)),
        ])
        .run_periodic(1)
        .expect("runs");
        let fix = fixes(&out)[0];
        assert!((fix.latitude_deg + 33.9).abs() < 1e-12 && (fix.longitude_deg - 151.2).abs() < 1e-12);
        assert!((fix.altitude_m - 20.0).abs() < 1e-9);
    }

    #[test]
    fn same_seed_same_output() {
        let a = fixes(
            &harness(&[("seed", Value::I64(11))])
                .run_periodic(40)
                .expect("runs"),
        );
        let b = fixes(
            &harness(&[("seed", Value::I64(11))])
                .run_periodic(40)
                .expect("runs"),
        );
        let c = fixes(
            &harness(&[("seed", Value::I64(12))])
                .run_periodic(40)
                .expect("runs"),
        );
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn outage_holds_the_position_without_a_fix() {
        let mut harness = harness(&[]);
        let before = fixes(&harness.run_periodic(100).expect("runs"));
        harness.action("outage").expect("action");
        let during = fixes(&harness.run_periodic(20).expect("runs"));
        harness.action("outage").expect("action");
        let after = fixes(&harness.run_periodic(5).expect("runs"));
        let last = *before.last().expect("fixes");
        let held = GnssFix {
            status: FixStatus::NoFix,
            ..last
        };
        assert!(during.iter().all(|f| *f == held));
        assert!(after.iter().all(|f| f.status == FixStatus::Fix));
        assert!(
            (local(&after[0]) - local(&last)).length() > 10.0,
            "the vehicle drove on"
        );
        assert!(harness.action("nope").is_err());
    }

    #[test]
    fn rate_changes_live() {
        let mut harness = harness(&[]);
        let first = harness.run_periodic(3).expect("runs");
        harness.set_property("rate", Value::F64(2.0)).expect("live");
        let second = harness.run_periodic(3).expect("runs");
        let stamps: Vec<i64> = first
            .samples("fix")
            .iter()
            .chain(second.samples("fix"))
            .map(|s| s.timestamp.0)
            .collect();
        assert_eq!(
            stamps,
            vec![
                0,
                100_000_000,
                200_000_000,
                300_000_000,
                800_000_000,
                1_300_000_000
            ]
        );
    }
}

//! The GNSS + IMU filter on the simulated vehicle, whose true path is known: the simulated IMU writes
//! it beside its measurements. Prints the errors it measures (`cargo test -- --nocapture`).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::collections::BTreeMap;

use kairos_pack_fusion::navigation::GnssImuEkf;
use kairos_pack_sensors::{GnssSensor, ImuSensor, gnss, imu};
use kairos_sdk::harness::Harness;
use kairos_sdk::{GnssFix, Payload, Pose, Sample};

const SECONDS: usize = 90;

/// The simulated IMU (100 Hz) and GNSS (10 Hz) for `SECONDS`, in time order, with the true poses.
fn drive(gnss_properties: &[(&str, f64)]) -> (Vec<(&'static str, Sample)>, BTreeMap<i64, Pose>) {
    let mut imu = Harness::new(imu::descriptor(), ImuSensor::default());
    imu.leave_unconnected("vehicle");
    let imu_out = imu.run_periodic(SECONDS * 100).unwrap();
    let mut receiver = Harness::new(gnss::descriptor(), GnssSensor::default());
    receiver.leave_unconnected("vehicle");
    for (name, value) in gnss_properties {
        receiver.set_property(name, *value).unwrap();
    }
    let gnss_out = receiver.run_periodic(SECONDS * 10).unwrap();
    let truth = imu_out
        .samples("pose")
        .iter()
        .map(|s| match s.payload {
            Payload::Pose(pose) => (s.timestamp.as_nanos(), pose),
            _ => unreachable!(),
        })
        .collect();
    let mut samples: Vec<(&str, Sample)> = imu_out
        .samples("imu")
        .iter()
        .map(|s| ("imu", s.clone()))
        .collect();
    samples.extend(gnss_out.samples("fix").iter().map(|s| ("gnss", s.clone())));
    // A fix goes after the IMU sample of the same instant, as a receiver's latency would put it.
    samples.sort_by_key(|(input, s)| (s.timestamp, *input == "gnss"));
    (samples, truth)
}

fn filter(samples: &[(&str, Sample)]) -> (Harness, kairos_sdk::harness::HarnessOutput) {
    let mut ekf = Harness::new(GnssImuEkf::info(), GnssImuEkf::default());
    ekf.set_property("reference", "fixed").unwrap();
    for (input, sample) in samples {
        ekf.push_sample(input, sample.clone());
    }
    let out = ekf.run().unwrap();
    (ekf, out)
}

struct Errors {
    horizontal_rms: f64,
    horizontal_max: f64,
    heading_rms_deg: f64,
}

/// Errors of the filter's poses against the truth from `from_s` seconds on.
fn errors(out: &kairos_sdk::harness::HarnessOutput, truth: &BTreeMap<i64, Pose>, from_s: f64) -> Errors {
    let (mut sum, mut max, mut heading_sum, mut n) = (0.0, 0.0_f64, 0.0, 0);
    let first = *truth.keys().next().unwrap();
    for sample in out.samples("pose") {
        let t = sample.timestamp.as_nanos();
        if ((t - first) as f64) * 1e-9 < from_s {
            continue;
        }
        let (Payload::Pose(estimate), Some(true_pose)) = (&sample.payload, truth.get(&t)) else {
            continue;
        };
        let d = (estimate.position - true_pose.position).truncate().length();
        let yaw = |q: glam::DQuat| {
            let f = q * glam::DVec3::X;
            f.y.atan2(f.x)
        };
        let mut dh = (yaw(estimate.orientation) - yaw(true_pose.orientation)).to_degrees();
        dh = (dh + 180.0).rem_euclid(360.0) - 180.0;
        sum += d * d;
        heading_sum += dh * dh;
        max = max.max(d);
        n += 1;
    }
    assert!(n > 1000, "{n} poses compared");
    Errors {
        horizontal_rms: (sum / f64::from(n)).sqrt(),
        horizontal_max: max,
        heading_rms_deg: (heading_sum / f64::from(n)).sqrt(),
    }
}

/// RMS horizontal error of the raw fixes, from `from_s` on.
fn gnss_error(samples: &[(&str, Sample)], truth: &BTreeMap<i64, Pose>, from_s: f64) -> f64 {
    let frame =
        kairos_pack_sensors::LocalFrame::new(kairos_pack_sensors::GeoPoint::new(48.7167, 2.2333, 150.0));
    let first = *truth.keys().next().unwrap();
    let (mut sum, mut n) = (0.0, 0);
    for (input, sample) in samples {
        let t = sample.timestamp.as_nanos();
        let (Payload::GnssFix(fix), Some(true_pose)) = (&sample.payload, truth.get(&t)) else {
            continue;
        };
        if *input != "gnss" || ((t - first) as f64) * 1e-9 < from_s {
            continue;
        }
        let enu = frame.to_enu(kairos_pack_sensors::GeoPoint::new(
            fix.latitude_deg,
            fix.longitude_deg,
            fix.altitude_m,
        ));
        sum += (enu - true_pose.position).truncate().length_squared();
        n += 1;
    }
    (sum / f64::from(n)).sqrt()
}

/// The filter's and the raw fixes' errors on a drive whose GNSS has `gnss_properties`.
fn compare(
    gnss_properties: &[(&str, f64)],
    what: &str,
) -> (Errors, f64, Harness, kairos_sdk::harness::HarnessOutput) {
    let (samples, truth) = drive(gnss_properties);
    let (ekf, out) = filter(&samples);
    let fused = errors(&out, &truth, 20.0);
    let raw = gnss_error(&samples, &truth, 20.0);
    println!(
        "simulated drive, {what}, {SECONDS} s, errors from 20 s on: fused horizontal RMS {:.2} m (max {:.2} m), heading RMS {:.2}°; raw GNSS horizontal RMS {raw:.2} m",
        fused.horizontal_rms, fused.horizontal_max, fused.heading_rms_deg
    );
    (fused, raw, ekf, out)
}

#[test]
fn with_white_gnss_noise_the_filter_follows_the_true_path_much_closer_than_the_fixes() {
    let (fused, raw, _, _) = compare(&[("noise_correlation_s", 0.0)], "white GNSS noise");
    assert!(
        fused.horizontal_rms < 0.7 * raw,
        "{} vs {raw}",
        fused.horizontal_rms
    );
    assert!(fused.heading_rms_deg < 2.0, "{}", fused.heading_rms_deg);
}

#[test]
fn with_slowly_wandering_gnss_errors_the_filter_stays_with_the_fixes_and_keeps_its_heading() {
    // The receiver's error wanders with a 5 s time constant: no filter that trusts GNSS for position
    // can tell that wander from motion, so the fused path follows it; it must not add to it.
    let (fused, raw, ekf, out) = compare(&[], "GNSS errors correlated over 5 s");
    assert!(
        fused.horizontal_rms < 1.1 * raw,
        "{} vs {raw}",
        fused.horizontal_rms
    );
    assert!(fused.horizontal_max < 3.0, "{}", fused.horizontal_max);
    assert!(fused.heading_rms_deg < 3.0, "{}", fused.heading_rms_deg);
    let status = ekf.status().unwrap();
    assert_eq!(status["started"], true, "{status}");
    assert_eq!(status["fixes_rejected"], 0, "{status}");
    // The uncertainty it reports is of the size of the errors it makes.
    let sigma = match &out.samples("sigma").last().unwrap().payload {
        Payload::Vector(v) => v.to_vec(),
        other => panic!("{other:?}"),
    };
    assert!(sigma[0] > 0.05 && sigma[0] < 2.0, "{sigma:?}");
    // The fused fixes are WGS84 near the reference point.
    let Payload::GnssFix(GnssFix { latitude_deg, .. }) = out.samples("fix").last().unwrap().payload else {
        panic!()
    };
    assert!((latitude_deg - 48.7167).abs() < 0.01);
}

#[test]
fn nan_samples_and_a_one_kilometre_jump_are_counted_and_never_reach_the_solution() {
    let (mut samples, truth) = drive(&[]);
    let first = samples[0].1.timestamp;
    let mut jumped = 0;
    for (input, sample) in &mut samples {
        let t = sample.timestamp.nanos_since(first) as f64 * 1e-9;
        match (&mut sample.payload, *input) {
            // Every 50th IMU sample from 30 s on is not a number.
            (Payload::Imu(imu), "imu") if t > 30.0 && (t * 100.0).round() as i64 % 50 == 0 => {
                imu.angular_velocity.x = f64::NAN;
            }
            // Fixes between 40 and 41 s are a kilometre north; one at 45 s has no latitude.
            (Payload::GnssFix(fix), "gnss") if (40.0..41.0).contains(&t) => {
                fix.latitude_deg += 1000.0 / 111_200.0;
                jumped += 1;
            }
            (Payload::GnssFix(fix), "gnss") if (t - 45.0).abs() < 0.05 => fix.latitude_deg = f64::NAN,
            _ => {}
        }
    }
    let (ekf, out) = filter(&samples);
    let status = ekf.status().unwrap();
    assert_eq!(status["fixes_rejected"], jumped, "{status}");
    assert!(status["imu_skipped"].as_u64().unwrap() >= 100, "{status}");
    assert!(status["fixes_skipped"].as_u64().unwrap() >= 1, "{status}");
    assert_eq!(status["resets"], 0, "{status}");
    let fused = errors(&out, &truth, 20.0);
    assert!(
        fused.horizontal_max < 3.0,
        "the jump never pulled the solution: {}",
        fused.horizontal_max
    );
    for sample in out.samples("pose") {
        let Payload::Pose(pose) = sample.payload else {
            panic!()
        };
        assert!(pose.position.is_finite() && pose.orientation.is_finite());
    }
}

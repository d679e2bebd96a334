//! The simulated sensors connected to `sim.vehicle` see the simulated vehicle and its world, not the
//! fixed figure-eight.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use kairos_pack_sensors::geo::{GeoPoint, LocalFrame};
use kairos_pack_sensors::trajectory::GRAVITY;
use kairos_pack_sensors::world::WorldView;
use kairos_pack_sensors::{camera, gnss, imu, lidar};
use kairos_pack_sim::vehicle::{SimVehicle, descriptor};
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Sample, Value};

/// Two seconds of the vehicle at 100 Hz: rolling at 12 m/s, steering gently left, a parked car in its
/// lane 40 m ahead of its start.
fn drive() -> Vec<Sample> {
    let mut vehicle = Harness::new(descriptor().build(), SimVehicle::default());
    vehicle.set_property("initial_speed", 12.0).unwrap();
    vehicle.set_property("obstacles", "40 -1.75").unwrap();
    vehicle.set_property("road", "straight 500").unwrap();
    for tick in 0..200 {
        let at = kairos_sdk::Timestamp::from_millis(tick * 10);
        vehicle.push("steering", Payload::F64(0.01), at);
        vehicle.push("throttle", Payload::F64(0.1), at);
    }
    vehicle.run_periodic(200).unwrap().samples("world").to_vec()
}

/// `sensor` at 10 Hz for the two seconds, fed the vehicle's worlds; its samples on `output`.
fn sensed(mut sensor: Harness, worlds: &[Sample], output: &str) -> Vec<Sample> {
    sensor.set_property("rate", 10.0).unwrap();
    for world in worlds {
        sensor.push_sample("vehicle", world.clone());
    }
    sensor.run_periodic(20).unwrap().samples(output).to_vec()
}

fn world_at(worlds: &[Sample], timestamp: kairos_sdk::Timestamp) -> WorldView {
    let sample = worlds.iter().rfind(|w| w.timestamp <= timestamp).unwrap();
    WorldView::from_payload(&sample.payload).unwrap()
}

#[test]
fn the_gnss_receiver_is_where_the_simulated_vehicle_is() {
    let worlds = drive();
    let mut receiver = Harness::new(gnss::descriptor(), gnss::GnssSensor::default());
    receiver.set_property("noise_m", 0.0).unwrap();
    let fixes = sensed(receiver, &worlds, "fix");
    assert_eq!(fixes.len(), 20);
    let origin = GeoPoint::new(48.7167, 2.2333, 150.0);
    let frame = LocalFrame::new(origin);
    for fix in &fixes {
        let Payload::GnssFix(reading) = &fix.payload else {
            panic!("a fix")
        };
        let truth = frame.to_geodetic(world_at(&worlds, fix.timestamp).state.position);
        assert!(
            (reading.latitude_deg - truth.latitude_deg).abs() < 1e-9,
            "{reading:?}"
        );
        assert!(
            (reading.longitude_deg - truth.longitude_deg).abs() < 1e-9,
            "{reading:?}"
        );
    }
    // The vehicle moved east along its road: about 12 m/s for two seconds.
    let Payload::GnssFix(last) = &fixes[19].payload else {
        panic!("a fix")
    };
    let east = frame.to_enu(GeoPoint::new(
        last.latitude_deg,
        last.longitude_deg,
        last.altitude_m,
    ));
    assert!((20.0..25.0).contains(&east.x), "{east}");
}

#[test]
fn the_imu_feels_the_simulated_vehicle_turn() {
    let worlds = drive();
    let mut unit = Harness::new(imu::descriptor(), imu::ImuSensor::default());
    unit.set_property("gyro_noise", 0.0).unwrap();
    unit.set_property("accel_noise", 0.0).unwrap();
    let readings = sensed(unit, &worlds, "imu");
    let Payload::Imu(last) = &readings[19].payload else {
        panic!("an IMU reading")
    };
    let truth = world_at(&worlds, readings[19].timestamp).state;
    assert!(truth.yaw_rate > 0.01, "turning left: {}", truth.yaw_rate);
    assert!((last.angular_velocity.z - truth.yaw_rate).abs() < 1e-12);
    assert!((last.linear_acceleration.z - GRAVITY).abs() < 1e-9);
    // Centripetal: v × yaw rate, to the left.
    let expected = truth.speed() * truth.yaw_rate;
    assert!(
        (last.linear_acceleration.y - expected).abs() < 0.05 * expected.abs() + 0.02,
        "{last:?}"
    );
}

#[test]
fn the_lidar_sees_the_parked_car_in_the_lane() {
    let worlds = drive();
    let mut scanner = Harness::new(lidar::descriptor(), lidar::LidarSensor::default());
    for (name, value) in [
        ("channels", Value::I64(32)),
        ("columns", Value::I64(720)),
        ("range_noise_m", Value::F64(0.0)),
    ] {
        scanner.set_property(name, value).unwrap();
    }
    let clouds = sensed(scanner, &worlds, "points");
    let first = &clouds[0];
    let Payload::PointCloud(cloud) = &first.payload else {
        panic!("a cloud")
    };
    // At the start the car's rear is 40 − 2.25 m ahead, in the vehicle's own lane.
    let on_car: Vec<_> = cloud
        .points
        .iter()
        .filter(|p| p.z > -1.85 && p.y.abs() < 0.9 && p.x > 30.0 && p.x < 45.0)
        .collect();
    // One channel of 32 crosses the car's height at that range, five columns of 720 its width.
    assert!(on_car.len() >= 4, "{} points on the car", on_car.len());
    let nearest = on_car.iter().map(|p| p.x).fold(f32::MAX, f32::min);
    assert!((nearest - 37.75).abs() < 0.1, "the car's rear at {nearest} m");
}

#[test]
fn the_camera_shows_the_simulated_road_and_draws_nothing_before_the_first_step() {
    let worlds = drive();
    let mut camera = Harness::new(camera::descriptor(), camera::CameraSensor::default());
    camera.set_property("rate", 10.0).unwrap();
    // Nothing from the simulator yet: no frame.
    assert!(camera.run_periodic(1).unwrap().samples("image").is_empty());
    let later: Vec<Sample> = worlds.iter().skip(10).cloned().collect();
    for world in &later {
        camera.push_sample("vehicle", world.clone());
    }
    let frames = camera.run_periodic(19).unwrap().samples("image").to_vec();
    assert_eq!(frames.len(), 19);
    let mut figure_eight = Harness::new(camera::descriptor(), camera::CameraSensor::default());
    figure_eight.leave_unconnected("vehicle");
    figure_eight.set_property("rate", 10.0).unwrap();
    let unconnected = figure_eight.run_periodic(19).unwrap().samples("image").to_vec();
    let (Payload::Image(simulated), Payload::Image(fixed)) = (&frames[18].payload, &unconnected[18].payload)
    else {
        panic!("images")
    };
    assert_ne!(
        simulated.pixels, fixed.pixels,
        "the simulated road is not the figure-eight"
    );
    // A straight road seen from the right lane: its solid right edge line is right of the middle of the
    // image, a few metres ahead (a fifth of the height from the bottom).
    let row = (simulated.height as usize * 4 / 5) * simulated.stride as usize;
    let bright: Vec<usize> = (0..simulated.width as usize)
        .filter(|x| simulated.pixels[row + x * 3] > 200)
        .collect();
    let middle = simulated.width as usize / 2;
    assert!(bright.iter().any(|x| *x > middle), "{bright:?}");
}

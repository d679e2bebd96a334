//! Obstacles in the simulated lidar's scans: ground removal then clustering finds the car ahead and the
//! posts along the road, through the components.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use kairos_pack_lidar::processing::{Clusters, GroundRemoval, VoxelGrid};
use kairos_sdk::harness::Harness;
use kairos_sdk::{Payload, Sample};

/// The simulated lidar's scan 12 s into the drive, when the vehicle is at speed.
fn scan() -> Sample {
    let mut lidar = Harness::new(
        kairos_pack_sensors::lidar::descriptor(),
        kairos_pack_sensors::lidar::LidarSensor::default(),
    );
    lidar.leave_unconnected("vehicle");
    // One revolution a second: twelve seconds in thirteen scans.
    lidar.set_property("rate", 1.0).unwrap();
    let out = lidar.run_periodic(13).unwrap();
    out.samples("points").last().unwrap().clone()
}

fn one(harness: &mut Harness, input: &str, sample: &Sample, output: &str) -> Sample {
    harness.push_sample(input, sample.clone());
    harness.run().unwrap().samples(output)[0].clone()
}

#[test]
fn ground_removal_and_clustering_find_the_car_ahead_and_the_posts() {
    let scan = scan();
    let Payload::PointCloud(points) = &scan.payload else {
        panic!()
    };
    let mut voxels = Harness::new(VoxelGrid::info(), VoxelGrid);
    voxels.set_property("leaf", 0.1).unwrap();
    let down = one(&mut voxels, "in", &scan, "out");
    let Payload::PointCloud(down_points) = &down.payload else {
        panic!()
    };
    assert!(down_points.points.len() < points.points.len());
    let mut ground = Harness::new(GroundRemoval::info(), GroundRemoval);
    let obstacles = one(&mut ground, "in", &down, "obstacles");
    let Payload::PointCloud(above) = &obstacles.payload else {
        panic!()
    };
    assert!(
        above.points.len() < down_points.points.len() / 4,
        "most of a scan is ground"
    );
    let mut clusters = Harness::new(Clusters::info(), Clusters);
    let boxes = one(&mut clusters, "in", &obstacles, "boxes");
    assert_eq!(boxes.timestamp, scan.timestamp, "the scan's time is kept");
    let Payload::Matrix(boxes) = &boxes.payload else {
        panic!()
    };
    assert!(boxes.rows >= 3, "{boxes:?}");
    let rows: Vec<&[f64]> = boxes.values.chunks_exact(6).collect();
    // The car: ahead, about 4.5 m by 1.8 m seen from behind or at an angle, at most 1.5 m tall.
    let car = rows
        .iter()
        .find(|b| {
            let (centre_x, length, width) = (f64::midpoint(b[0], b[3]), b[3] - b[0], b[4] - b[1]);
            centre_x > 5.0 && length.max(width) > 1.0 && length.max(width) < 5.5 && b[5] - b[2] < 1.8
        })
        .unwrap_or_else(|| panic!("no car among {rows:?}"));
    // Posts: thin and tall.
    let posts = rows
        .iter()
        .filter(|b| b[3] - b[0] < 0.6 && b[4] - b[1] < 0.6 && b[5] - b[2] > 1.0)
        .count();
    assert!(posts >= 2, "{rows:?}");
    println!("car box {car:?}, {posts} posts, {} boxes", boxes.rows);
}

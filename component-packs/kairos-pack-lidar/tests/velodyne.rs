//! VLP-16 packets built from the manual's format, decoded to the points they describe; a capture replayed
//! through the component; garbage refused and counted.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::net::UdpSocket;

use kairos_pack_lidar::packets::{Decoder, Model, PACKET_BYTES, PacketError, encode_packet};
use kairos_pack_lidar::pcap::{capture_of, frame_of};
use kairos_pack_lidar::velodyne::{Velodyne, descriptor};
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{Payload, PointCloud};

/// A packet whose blocks start at `first` hundredths of a degree, `step` apart, every laser at 10 m
/// (5000 units), reflectivity = laser id × 10.
fn packet(first: u16, step: u16) -> Vec<u8> {
    let mut blocks = [(0_u16, [(0_u16, 0_u8); 32]); 12];
    for (index, block) in blocks.iter_mut().enumerate() {
        block.0 = (first + step * index as u16) % 36_000;
        for (measurement, value) in block.1.iter_mut().enumerate() {
            *value = (5000, (measurement % 16) as u8 * 10);
        }
    }
    encode_packet(Model::Vlp16, &blocks, 0)
}

fn clouds_of(packets: &[Vec<u8>]) -> (Vec<PointCloud>, Decoder) {
    let mut decoder = Decoder::new();
    let mut clouds = Vec::new();
    for payload in packets {
        decoder.packet(payload, |cloud| clouds.push(cloud)).unwrap();
    }
    (clouds, decoder)
}

#[test]
fn points_land_where_the_manual_puts_them() {
    // Blocks at 90° and 90.4°, ...: the first laser (−15°) of the first block, 10 m away, to the right.
    let (_, mut decoder) = clouds_of(&[packet(9000, 40)]);
    let cloud = decoder.finish().unwrap();
    assert_eq!(cloud.points.len(), 12 * 32);
    let first = cloud.points[0];
    let (elevation, azimuth) = ((-15.0_f32).to_radians(), 90.0_f32.to_radians());
    let expected = [
        10.0 * elevation.cos() * azimuth.cos(),
        -10.0 * elevation.cos() * azimuth.sin(),
        // The manual's vertical correction of laser 0: its beam starts 11.2 mm above the centre.
        10.0 * elevation.sin() + 0.0112,
    ];
    for (got, want) in first.to_array().iter().zip(expected) {
        assert!((got - want).abs() < 1e-4, "{first:?} vs {expected:?}");
    }
    // Every laser's height is its beam's plus its correction (mm, by laser id, from the manual).
    let corrections_mm = [
        11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1, 2.2, -9.7, 0.7, -11.2,
    ];
    for (laser, correction) in corrections_mm.iter().enumerate() {
        let elevation = -15.0_f32
            + if laser % 2 == 0 {
                laser as f32
            } else {
                15.0 + laser as f32
            };
        let beam = 10.0 * elevation.to_radians().sin();
        let z = cloud.points[laser].z;
        assert!(
            ((z - beam) * 1000.0 - correction).abs() < 0.05,
            "laser {laser}: z {z}, beam {beam}"
        );
    }
    // Laser 1 (+1°) of the second firing sequence: half a block later, between the two azimuths.
    let later = cloud.points[17];
    let azimuth = (-later.y).atan2(later.x).to_degrees();
    assert!(azimuth > 90.2 && azimuth < 90.4, "{azimuth}");
    assert!((cloud.intensity.unwrap()[1] - 10.0 / 255.0).abs() < 1e-6);
}

#[test]
fn a_revolution_ends_where_the_azimuth_wraps_and_no_return_gives_no_point() {
    // 75 packets of 12 blocks 0.4° apart: 360° (900 blocks), then a few more of the next revolution.
    let packets: Vec<Vec<u8>> = (0..80)
        .map(|i| packet((i * 12 * 40 % 36_000) as u16, 40))
        .collect();
    let (clouds, mut decoder) = clouds_of(&packets);
    assert_eq!(clouds.len(), 1);
    assert_eq!(clouds[0].points.len(), 900 * 32);
    assert_eq!(decoder.finish().unwrap().points.len(), 5 * 12 * 32);
    let mut silent = [(0_u16, [(0_u16, 0_u8); 32]); 12];
    for (index, block) in silent.iter_mut().enumerate() {
        block.0 = index as u16 * 40;
    }
    let (_, mut decoder) = clouds_of(&[encode_packet(Model::Vlp16, &silent, 0)]);
    assert!(decoder.finish().is_none(), "distance 0 is no return");
}

#[test]
fn garbage_packets_are_refused_whole() {
    let mut decoder = Decoder::new();
    assert_eq!(
        decoder.packet(&[0; 512], |_| {}),
        Err(PacketError::WrongSize(512))
    );
    let mut flagless = packet(0, 40);
    flagless[300] = 0;
    assert_eq!(decoder.packet(&flagless, |_| {}), Err(PacketError::BadFlag(3)));
    let mut beyond = packet(0, 40);
    beyond[2..4].copy_from_slice(&36_000_u16.to_le_bytes());
    assert!(matches!(
        decoder.packet(&beyond, |_| {}),
        Err(PacketError::BadAzimuth { block: 0, .. })
    ));
    assert!(decoder.finish().is_none(), "nothing of a refused packet is kept");
}

fn run(mut harness: Harness, cycles: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    for _ in 0..cycles {
        out.extend(harness.run().unwrap());
    }
    out.extend(harness.finish().unwrap());
    out
}

#[test]
fn a_capture_replays_at_its_timing_and_other_traffic_is_passed_over() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("drive.pcap");
    // Two revolutions at 10 Hz (75 packets each, 1.33 ms apart), with position packets (port 8308) between.
    let mut frames = Vec::new();
    for index in 0..150_i64 {
        let time = 1_700_000_000_000_000_000 + index * 1_333_333;
        let azimuth = (index * 12 * 40 % 36_000) as u16;
        frames.push((time, frame_of(2368, &packet(azimuth, 40))));
        if index % 50 == 0 {
            frames.push((time, frame_of(8308, &[0; 512])));
        }
    }
    std::fs::write(&path, capture_of(&frames)).unwrap();
    let mut harness = Harness::new(descriptor(), Velodyne::default());
    harness.set_property("source", "pcap").unwrap();
    harness.set_property("path", path.display().to_string()).unwrap();
    let started = harness.now();
    let out = run(harness, 160);
    let clouds = out.samples("points");
    assert_eq!(clouds.len(), 2, "a revolution, then the one the capture ends in");
    let Payload::PointCloud(first) = &clouds[0].payload else {
        panic!()
    };
    assert_eq!(first.points.len(), 900 * 32);
    // The first revolution completes with packet 75, captured 99.999 ms (in µs) after the first one.
    assert_eq!(clouds[0].timestamp.0 - started.0, 99_999_000);
}

#[test]
fn a_file_that_is_not_a_capture_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.pcap");
    std::fs::write(&path, "not a capture at all, not even close").unwrap();
    let mut harness = Harness::new(descriptor(), Velodyne::default());
    harness.set_property("source", "pcap").unwrap();
    harness.set_property("path", path.display().to_string()).unwrap();
    let error = harness.run().unwrap_err().to_string();
    assert!(
        error.contains("notes.pcap") && error.contains("not a pcap"),
        "{error}"
    );
}

#[test]
fn live_packets_over_udp_make_clouds_and_garbage_is_counted() {
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut harness = Harness::new(descriptor(), Velodyne::default());
    harness
        .set_property("address", format!("127.0.0.1:{port}"))
        .unwrap();
    harness.run().unwrap();
    let sensor = UdpSocket::bind("127.0.0.1:0").unwrap();
    sensor.send_to(&[1, 2, 3], ("127.0.0.1", port)).unwrap();
    for index in 0..80_u32 {
        sensor
            .send_to(
                &packet((index * 12 * 40 % 36_000) as u16, 40),
                ("127.0.0.1", port),
            )
            .unwrap();
    }
    let mut out = HarnessOutput::default();
    for _ in 0..200 {
        out.extend(harness.run().unwrap());
        if !out.samples("points").is_empty() {
            break;
        }
    }
    assert_eq!(out.samples("points").len(), 1);
    assert_eq!(PACKET_BYTES, packet(0, 40).len());
}

//! The fusion pack: from IMU and GNSS to a pose, and the coordinate frames in between.
//!
//! | type | what it does |
//! | --- | --- |
//! | `fusion.to_enu` | WGS84 fixes as east-north-up positions (exact, through ECEF) |
//! | `fusion.to_wgs84` | east-north-up positions back to WGS84 fixes |
//! | `fusion.frame_transform` | points, poses or vectors from one static frame to another (a frames file) |
//! | `fusion.gnss_imu_ekf` | GNSS + IMU extended Kalman filter: position, velocity, heading, uncertainty |
//! | `fusion.dead_reckoning` | odometry from speed and yaw rate |
//! | `fusion.interpolate` | a stream resampled at another stream's timestamps |
//!
//! [`geodesy`], [`frames`], [`ins`] and [`matrix`] hold the mathematics without any component around it.

pub mod frames;
pub mod geo_components;
pub mod geodesy;
pub mod ins;
pub mod matrix;
pub mod navigation;

use kairos_sdk::Registry;

/// Registers the pack "fusion".
pub fn register(registry: &mut Registry) {
    registry
        .pack("fusion", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<geo_components::ToEnu>(geo_components::ToEnu::info())
        .component::<geo_components::ToWgs84>(geo_components::ToWgs84::info())
        .component::<geo_components::FrameTransform>(geo_components::FrameTransform::info())
        .component::<navigation::GnssImuEkf>(navigation::GnssImuEkf::info())
        .component::<navigation::DeadReckoning>(navigation::DeadReckoning::info())
        .component::<navigation::Interpolate>(navigation::Interpolate::info());
}

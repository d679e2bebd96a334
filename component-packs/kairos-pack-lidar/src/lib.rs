//! The lidar pack.
//!
//! | type | what it does |
//! | --- | --- |
//! | `lidar.velodyne` | a Velodyne VLP-16: data packets over UDP or from a pcap capture, one point cloud per revolution |
//!
//! [`vlp16`] decodes packets as the sensor's manual specifies them; [`pcap`] reads UDP datagrams from a
//! capture.

pub mod pcap;
pub mod velodyne;
pub mod vlp16;

use kairos_sdk::Registry;

/// Registers the pack "lidar".
pub fn register(registry: &mut Registry) {
    registry
        .pack("lidar", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<velodyne::Velodyne>(velodyne::descriptor());
}

//! The lidar pack.
//!
//! | type | what it does |
//! | --- | --- |
//! | `lidar.velodyne` | a Velodyne VLP-16, VLP-32C or HDL-32E: data packets over UDP or from a pcap capture, one point cloud per revolution |
//! | `lidar.transform` | a cloud moved by the sensor's mounting and the vehicle's pose |
//! | `lidar.crop_box` | the points inside (or outside) a box |
//! | `lidar.voxel_grid` | one mean point per cube |
//! | `lidar.ground_removal` | the ground plane and what stands on it |
//! | `lidar.range_image` | the cloud as a grey range image |
//! | `lidar.clusters` | objects as boxes |
//!
//! [`packets`] decodes packets as the sensors' manuals specify them; [`pcap`] reads UDP datagrams from a
//! capture. [`cloud`] holds the point-cloud algorithms, [`processing`] their components.

pub mod cloud;
pub mod packets;
pub mod pcap;
pub mod processing;
pub mod velodyne;

use kairos_sdk::Registry;

/// Registers the pack "lidar".
pub fn register(registry: &mut Registry) {
    registry
        .pack("lidar", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<velodyne::Velodyne>(velodyne::descriptor())
        .component::<processing::Transform>(processing::Transform::info())
        .component::<processing::CropBox>(processing::CropBox::info())
        .component::<processing::VoxelGrid>(processing::VoxelGrid::info())
        .component::<processing::GroundRemoval>(processing::GroundRemoval::info())
        .component::<processing::RangeImage>(processing::RangeImage::info())
        .component::<processing::Clusters>(processing::Clusters::info());
}

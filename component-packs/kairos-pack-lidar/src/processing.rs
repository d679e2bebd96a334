//! Point-cloud components around [`crate::cloud`]: each reads a cloud, keeps its timestamp, and writes
//! the result.

use std::sync::Arc;

use glam::{DQuat, EulerRot, Vec3};
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Image, Matrix, Payload,
    PixelFormat, PointCloud, Pose, Sample, TypeFilter,
};

use crate::cloud::{self, ClusterSearch, GroundSearch};

fn clouds() -> TypeFilter {
    TypeFilter::only(DataType::PointCloud)
}

fn cloud_of<'a>(sample: &'a Sample, input: &str) -> Result<&'a Arc<PointCloud>, ComponentError> {
    match &sample.payload {
        Payload::PointCloud(cloud) => Ok(cloud),
        other => Err(ComponentError::failed(format_args!(
            "input {input} expects a point cloud, got {}",
            other.data_type()
        ))),
    }
}

fn metres(name: &str, default: f64, doc: &str) -> Property {
    Property::f64(name, default)
        .unit("m")
        .range(-1000.0, 1000.0)
        .live()
        .doc(doc)
}

fn float(ctx: &Context, name: &str) -> Result<f32, ComponentError> {
    Ok(ctx.f64_property(name)? as f32)
}

/// `lidar.crop_box`.
#[derive(Debug, Default)]
pub struct CropBox;

impl CropBox {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "lidar.crop_box",
            "lidar processing",
            "Keeps the points inside a box, or those outside it (to remove the vehicle itself)",
        )
        .label("Crop box")
        .input("in", clouds(), "A point cloud")
        .output("out", DataType::PointCloud, "The points kept, same timestamp")
        .property(metres("min_x", -50.0, "Box, lowest x"))
        .property(metres("max_x", 50.0, "Box, highest x"))
        .property(metres("min_y", -50.0, "Box, lowest y"))
        .property(metres("max_y", 50.0, "Box, highest y"))
        .property(metres("min_z", -5.0, "Box, lowest z"))
        .property(metres("max_z", 5.0, "Box, highest z"))
        .property(
            Property::choice("keep", &["inside", "outside"], "inside")
                .live()
                .doc("Which points are kept"),
        )
        .build()
    }
}

impl Component for CropBox {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let bounds = cloud::Aabb {
            min: Vec3::new(float(ctx, "min_x")?, float(ctx, "min_y")?, float(ctx, "min_z")?),
            max: Vec3::new(float(ctx, "max_x")?, float(ctx, "max_y")?, float(ctx, "max_z")?),
        };
        if bounds.min.cmpgt(bounds.max).any() {
            return Err(ComponentError::failed(format_args!(
                "the box is empty: each min must be at most its max (min {}, max {})",
                bounds.min, bounds.max
            )));
        }
        let inside = ctx.text_property("keep")? == "inside";
        let sample = ctx.read("in")?;
        let kept = cloud::filtered(cloud_of(&sample, "in")?, |_, p| {
            p.is_finite() && bounds.contains(p) == inside
        });
        ctx.write_processed("out", &sample, Payload::PointCloud(Arc::new(kept)))
    }
}

/// `lidar.voxel_grid`.
#[derive(Debug, Default)]
pub struct VoxelGrid;

impl VoxelGrid {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "lidar.voxel_grid",
            "lidar processing",
            "Downsamples a cloud: one point per cube, the mean of the points in it",
        )
        .label("Voxel-grid downsampling")
        .input("in", clouds(), "A point cloud")
        .output(
            "out",
            DataType::PointCloud,
            "One point per occupied cube, same timestamp",
        )
        .property(
            Property::f64("leaf", 0.2)
                .unit("m")
                .range(0.01, 100.0)
                .live()
                .doc("Side of the cubes"),
        )
        .build()
    }
}

impl Component for VoxelGrid {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let leaf = float(ctx, "leaf")?;
        let sample = ctx.read("in")?;
        let down = cloud::voxel_grid(cloud_of(&sample, "in")?, leaf);
        ctx.write_processed("out", &sample, Payload::PointCloud(Arc::new(down)))
    }
}

/// `lidar.ground_removal`.
#[derive(Debug, Default)]
pub struct GroundRemoval;

impl GroundRemoval {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "lidar.ground_removal",
            "lidar processing",
            "Finds the ground plane (RANSAC, then least squares) and separates what stands on it",
        )
        .label("Ground removal")
        .input("in", clouds(), "A point cloud, z up")
        .output(
            "obstacles",
            DataType::PointCloud,
            "The points above the ground, same timestamp",
        )
        .output("ground", DataType::PointCloud, "The ground's points")
        .output(
            "plane",
            DataType::Vector,
            "The plane a, b, c, d with a x + b y + c z + d = 0, (a, b, c) a unit normal pointing up",
        )
        .property(
            Property::f64("distance", 0.15)
                .unit("m")
                .range(0.01, 5.0)
                .live()
                .doc("Points closer to the plane are ground"),
        )
        .property(
            Property::f64("max_tilt", 15.0)
                .unit("°")
                .range(0.0, 89.0)
                .live()
                .doc("Steepest ground accepted"),
        )
        .property(
            Property::i64("iterations", 100)
                .int_range(1, 10_000)
                .live()
                .doc("Planes tried"),
        )
        .build()
    }
}

impl Component for GroundRemoval {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let search = GroundSearch {
            distance: ctx.f64_property("distance")?,
            max_tilt_deg: ctx.f64_property("max_tilt")?,
            iterations: usize::try_from(ctx.i64_property("iterations")?).unwrap_or(1),
        };
        let sample = ctx.read("in")?;
        let points = cloud_of(&sample, "in")?;
        let Some(plane) = cloud::ground_plane(points, &search) else {
            // No ground to be found (too few points, or none level enough): everything is an obstacle.
            ctx.write_processed("obstacles", &sample, sample.payload.clone())?;
            return ctx.write_processed(
                "ground",
                &sample,
                Payload::PointCloud(Arc::new(PointCloud::default())),
            );
        };
        let ground = cloud::filtered(points, |_, p| {
            p.is_finite() && plane.distance(p).abs() <= search.distance
        });
        let obstacles = cloud::filtered(points, |_, p| {
            p.is_finite() && plane.distance(p) > search.distance
        });
        ctx.write_processed("obstacles", &sample, Payload::PointCloud(Arc::new(obstacles)))?;
        ctx.write_processed("ground", &sample, Payload::PointCloud(Arc::new(ground)))?;
        let n = plane.normal;
        ctx.write_processed(
            "plane",
            &sample,
            Payload::Vector(Arc::from([n.x, n.y, n.z, plane.d].as_slice())),
        )
    }
}

/// `lidar.range_image`.
#[derive(Debug, Default)]
pub struct RangeImage;

impl RangeImage {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "lidar.range_image",
            "lidar processing",
            "A spinning lidar's cloud as a grey image: elevation down, azimuth across, near is bright",
        )
        .label("Range image")
        .input("in", clouds(), "A point cloud in the sensor frame")
        .output(
            "image",
            DataType::Image,
            "Grey image, straight ahead in the middle column; same timestamp",
        )
        .property(
            Property::i64("rows", 32)
                .int_range(1, 1024)
                .doc("Rows: usually the lidar's channels"),
        )
        .property(
            Property::i64("columns", 1024)
                .int_range(8, 16384)
                .doc("Columns per revolution"),
        )
        .property(
            Property::f64("fov_up", 15.0)
                .unit("°")
                .range(-90.0, 90.0)
                .doc("Elevation of the top row"),
        )
        .property(
            Property::f64("fov_down", -25.0)
                .unit("°")
                .range(-90.0, 90.0)
                .doc("Elevation of the bottom row"),
        )
        .property(
            Property::f64("max_range", 100.0)
                .unit("m")
                .range(0.1, 10_000.0)
                .live()
                .doc("Range shown black"),
        )
        .build()
    }
}

impl Component for RangeImage {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let rows = usize::try_from(ctx.i64_property("rows")?).unwrap_or(1);
        let columns = usize::try_from(ctx.i64_property("columns")?).unwrap_or(8);
        let (down, up) = (float(ctx, "fov_down")?, float(ctx, "fov_up")?);
        if down >= up {
            return Err(ComponentError::failed(format_args!(
                "fov_down ({down}°) must be below fov_up ({up}°)"
            )));
        }
        let max_range = float(ctx, "max_range")?;
        let sample = ctx.read("in")?;
        let pixels = cloud::range_image(cloud_of(&sample, "in")?, (rows, columns), (down, up), max_range);
        let image = Image::packed(columns as u32, rows as u32, PixelFormat::Gray8, pixels)
            .map_err(ComponentError::failed)?;
        ctx.write_processed("image", &sample, Payload::Image(image))
    }
}

/// `lidar.clusters`.
#[derive(Debug, Default)]
pub struct Clusters;

impl Clusters {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "lidar.clusters",
            "lidar processing",
            "Groups points closer than a distance into objects and gives each one's box",
        )
        .label("Obstacle clusters")
        .input(
            "in",
            clouds(),
            "A point cloud, usually the obstacles left by ground removal",
        )
        .output(
            "boxes",
            DataType::Matrix,
            "One row per object, largest first: min x, y, z, max x, y, z (m); same timestamp",
        )
        .property(
            Property::f64("tolerance", 0.5)
                .unit("m")
                .range(0.01, 10.0)
                .live()
                .doc("Points closer than this belong together"),
        )
        .property(
            Property::i64("min_points", 10)
                .int_range(1, 1_000_000)
                .live()
                .doc("Smaller groups are noise"),
        )
        .property(
            Property::i64("max_points", 20_000)
                .int_range(1, 10_000_000)
                .live()
                .doc("Larger groups are not objects"),
        )
        .build()
    }
}

impl Component for Clusters {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let search = ClusterSearch {
            tolerance: float(ctx, "tolerance")?,
            min_points: usize::try_from(ctx.i64_property("min_points")?).unwrap_or(1),
            max_points: usize::try_from(ctx.i64_property("max_points")?).unwrap_or(1),
        };
        let sample = ctx.read("in")?;
        let boxes = cloud::clusters(cloud_of(&sample, "in")?, &search);
        let values = boxes
            .iter()
            .flat_map(|b| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f64::from))
            .collect();
        let matrix = Matrix {
            rows: boxes.len(),
            cols: 6,
            values,
        };
        ctx.write_processed("boxes", &sample, Payload::Matrix(Arc::new(matrix)))
    }
}

/// `lidar.transform`.
#[derive(Debug, Default)]
pub struct Transform {
    pose: Option<Sample>,
}

impl Transform {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let angle = |name: &str, doc: &str| {
            Property::f64(name, 0.0)
                .unit("°")
                .range(-360.0, 360.0)
                .live()
                .doc(doc)
        };
        Descriptor::new(
            "lidar.transform",
            "lidar processing",
            "Moves a cloud by the sensor's mounting, then by a pose (e.g. the vehicle's, from fusion): sensor to world",
        )
        .label("Transform cloud")
        .input("in", clouds(), "A point cloud in the sensor frame")
        .input("pose", TypeFilter::only(DataType::Pose), "The vehicle's pose at the cloud's time (optional)")
        .output("out", DataType::PointCloud, "The moved cloud, same timestamp")
        .property(metres("x", 0.0, "Mounting: sensor position on the vehicle, forward"))
        .property(metres("y", 0.0, "Mounting: left"))
        .property(metres("z", 0.0, "Mounting: up"))
        .property(angle("roll", "Mounting: roll"))
        .property(angle("pitch", "Mounting: pitch"))
        .property(angle("yaw", "Mounting: yaw, counter-clockwise"))
        .build()
    }
}

impl Component for Transform {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        // The pose of the cloud's time: the first as recent as the cloud.
        if ctx.is_connected("pose") {
            while self.pose.as_ref().is_none_or(|p| p.timestamp < sample.timestamp) {
                self.pose = Some(ctx.read("pose")?);
            }
        }
        let mounting = DQuat::from_euler(
            EulerRot::ZYX,
            ctx.f64_property("yaw")?.to_radians(),
            ctx.f64_property("pitch")?.to_radians(),
            ctx.f64_property("roll")?.to_radians(),
        );
        let offset = glam::DVec3::new(
            ctx.f64_property("x")?,
            ctx.f64_property("y")?,
            ctx.f64_property("z")?,
        );
        let (rotation, translation) = match self.pose.as_ref().map(|s| &s.payload) {
            Some(Payload::Pose(Pose {
                position,
                orientation,
            })) => (*orientation * mounting, *orientation * offset + *position),
            _ => (mounting, offset),
        };
        let (rotation, translation) = (rotation.as_quat(), translation.as_vec3());
        let points = cloud_of(&sample, "in")?;
        let moved = PointCloud {
            points: points
                .points
                .iter()
                .map(|p| rotation * *p + translation)
                .collect(),
            intensity: points.intensity.clone(),
        };
        ctx.write_processed("out", &sample, Payload::PointCloud(Arc::new(moved)))
    }
}

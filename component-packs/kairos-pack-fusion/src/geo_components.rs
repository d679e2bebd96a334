//! Components between WGS84 and a local ENU frame, and between static coordinate frames.

use std::path::PathBuf;
use std::sync::Arc;

use glam::{DQuat, DVec3, Vec3};
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, FixStatus, GnssFix,
    Payload, PointCloud, Pose, TypeFilter,
};

use crate::frames::{Frames, Transform};
use crate::geodesy::{EnuFrame, Geodetic};

/// The reference point properties shared by the ENU components and the filter.
pub fn reference_properties(descriptor: Descriptor) -> Descriptor {
    descriptor
        .property(
            Property::choice("reference", &["first_fix", "fixed"], "first_fix")
                .doc("The ENU frame's origin: the first valid fix received, or the point given below"),
        )
        .property(
            Property::f64("latitude", 48.7167)
                .unit("deg N")
                .range(-90.0, 90.0)
                .doc("Origin latitude (fixed)"),
        )
        .property(
            Property::f64("longitude", 2.2333)
                .unit("deg E")
                .range(-180.0, 180.0)
                .doc("Origin longitude (fixed)"),
        )
        .property(
            Property::f64("altitude", 150.0)
                .unit("m")
                .range(-1000.0, 10_000.0)
                .doc("Origin height above the WGS84 ellipsoid (fixed)"),
        )
}

/// The ENU frame to use: the fixed one from the properties, or `None` until a first fix gives it.
pub fn fixed_reference(ctx: &Context) -> Result<Option<EnuFrame>, ComponentError> {
    if ctx.text_property("reference")? != "fixed" {
        return Ok(None);
    }
    Ok(Some(EnuFrame::new(Geodetic {
        latitude_deg: ctx.f64_property("latitude")?,
        longitude_deg: ctx.f64_property("longitude")?,
        altitude_m: ctx.f64_property("altitude")?,
    })))
}

/// A fix as a geodetic point, when it is a valid position.
pub fn geodetic_of(fix: &GnssFix) -> Option<Geodetic> {
    let point = Geodetic {
        latitude_deg: fix.latitude_deg,
        longitude_deg: fix.longitude_deg,
        altitude_m: fix.altitude_m,
    };
    (fix.status != FixStatus::NoFix && point.is_valid()).then_some(point)
}

/// `fusion.to_enu`.
#[derive(Debug, Default)]
pub struct ToEnu {
    frame: Option<EnuFrame>,
    skipped: u64,
}

impl ToEnu {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        reference_properties(
            Descriptor::new("fusion.to_enu", "coordinates", "WGS84 fixes as positions in a local east-north-up frame, exactly (through Earth-centred coordinates)")
                .label("WGS84 to local ENU")
                .input("fix", TypeFilter::only(DataType::GnssFix), "GNSS fixes")
                .output("enu", DataType::Vector, "East, north, up in metres; same timestamp")
                .output("pose", DataType::Pose, "The same position as a pose (orientation: none, the identity)"),
        )
        .build()
    }
}

impl Component for ToEnu {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.frame = fixed_reference(ctx)?;
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("fix")?;
        let Payload::GnssFix(fix) = &sample.payload else {
            return Err(ComponentError::failed(format_args!(
                "input fix expects a GNSS fix, got {}",
                sample.payload.data_type()
            )));
        };
        let Some(point) = geodetic_of(fix) else {
            // No position in it (no fix, or not a number): nothing to convert.
            self.skipped += 1;
            ctx.set_status(serde_json::json!({ "skipped": self.skipped }));
            return Ok(());
        };
        let frame = *self.frame.get_or_insert_with(|| EnuFrame::new(point));
        let enu = frame.to_enu(&point);
        ctx.write_processed(
            "enu",
            &sample,
            Payload::Vector(Arc::from([enu.x, enu.y, enu.z].as_slice())),
        )?;
        ctx.write_processed(
            "pose",
            &sample,
            Payload::Pose(Pose {
                position: enu,
                orientation: DQuat::IDENTITY,
            }),
        )
    }
}

/// `fusion.to_wgs84`.
#[derive(Debug, Default)]
pub struct ToWgs84;

impl ToWgs84 {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "fusion.to_wgs84",
            "coordinates",
            "Positions in a local east-north-up frame as WGS84 fixes",
        )
        .label("Local ENU to WGS84")
        .input(
            "in",
            TypeFilter::OneOf(vec![DataType::Pose, DataType::Vector]),
            "A pose, or a vector east, north, up (m)",
        )
        .output(
            "fix",
            DataType::GnssFix,
            "The WGS84 position (accuracies 0: unknown); same timestamp",
        )
        .property(
            Property::f64("latitude", 48.7167)
                .unit("deg N")
                .range(-90.0, 90.0)
                .doc("Origin latitude of the ENU frame"),
        )
        .property(
            Property::f64("longitude", 2.2333)
                .unit("deg E")
                .range(-180.0, 180.0)
                .doc("Origin longitude"),
        )
        .property(
            Property::f64("altitude", 150.0)
                .unit("m")
                .range(-1000.0, 10_000.0)
                .doc("Origin height above the WGS84 ellipsoid"),
        )
        .build()
    }
}

impl Component for ToWgs84 {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let enu = match &sample.payload {
            Payload::Pose(pose) => pose.position,
            Payload::Vector(v) if v.len() == 3 => DVec3::new(v[0], v[1], v[2]),
            other => {
                return Err(ComponentError::failed(format_args!(
                    "input in expects a pose or a vector of 3 (east, north, up), got {}",
                    describe(other)
                )));
            }
        };
        let frame = EnuFrame::new(Geodetic {
            latitude_deg: ctx.f64_property("latitude")?,
            longitude_deg: ctx.f64_property("longitude")?,
            altitude_m: ctx.f64_property("altitude")?,
        });
        let point = frame.to_geodetic(enu);
        let fix = GnssFix {
            latitude_deg: point.latitude_deg,
            longitude_deg: point.longitude_deg,
            altitude_m: point.altitude_m,
            horizontal_accuracy_m: 0.0,
            vertical_accuracy_m: 0.0,
            status: FixStatus::Fix,
        };
        ctx.write_processed("fix", &sample, Payload::GnssFix(fix))
    }
}

/// A payload in words, for errors.
pub fn describe(payload: &Payload) -> String {
    match payload {
        Payload::Vector(v) => format!("a vector of {}", v.len()),
        other => other.data_type().to_string(),
    }
}

/// `fusion.frame_transform`.
#[derive(Debug, Default)]
pub struct FrameTransform {
    transform: Option<Transform>,
}

impl FrameTransform {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "fusion.frame_transform",
            "coordinates",
            "Carries points, poses or vectors from one static frame to another (sensor to vehicle), as a frames file says",
        )
        .label("Change of frame")
        .input(
            "in",
            TypeFilter::OneOf(vec![DataType::PointCloud, DataType::Pose, DataType::Vector]),
            "A point cloud, a pose or a point (vector of 3) in the frame `from`",
        )
        .output_following("out", "in", "The same in the frame `to`; same timestamp")
        .property(Property::path("frames_file", "frames.toml").doc("The frames file (TOML: [frame.NAME] parent, translation, rotation)"))
        .property(Property::text("from", "lidar").doc("The frame the input is in"))
        .property(Property::text("to", "vehicle").doc("The frame to express it in"))
        .build()
    }
}

impl Component for FrameTransform {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let path = PathBuf::from(ctx.text_property("frames_file")?);
        let frames = Frames::load(&path).map_err(ComponentError::failed)?;
        let transform = frames
            .between(&ctx.text_property("from")?, &ctx.text_property("to")?)
            .map_err(ComponentError::failed)?;
        self.transform = Some(transform);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let t = self.transform.unwrap_or(Transform::IDENTITY);
        let out = match &sample.payload {
            Payload::PointCloud(cloud) => Payload::PointCloud(Arc::new(transform_cloud(cloud, &t))),
            Payload::Pose(pose) => Payload::Pose(Pose {
                position: t.point(pose.position),
                orientation: t.rotation * pose.orientation,
            }),
            Payload::Vector(v) if v.len() == 3 => {
                let p = t.point(DVec3::new(v[0], v[1], v[2]));
                Payload::Vector(Arc::from([p.x, p.y, p.z].as_slice()))
            }
            other => {
                return Err(ComponentError::failed(format_args!(
                    "input in expects a point cloud, a pose or a vector of 3, got {}",
                    describe(other)
                )));
            }
        };
        ctx.write_processed("out", &sample, out)
    }
}

/// `cloud` with every point carried by `t` (single precision, as clouds are).
pub fn transform_cloud(cloud: &PointCloud, t: &Transform) -> PointCloud {
    let rotation = t.rotation.as_quat();
    let translation = t.translation.as_vec3();
    PointCloud {
        points: cloud
            .points
            .iter()
            .map(|p| rotation * *p + translation)
            .collect::<Vec<Vec3>>(),
        intensity: cloud.intensity.clone(),
    }
}

//! `sensors.lidar`: a simulated spinning lidar on the simulated vehicle.
//!
//! The world it scans is simple and deterministic: flat ground under the vehicle, posts along both sides of
//! the figure-eight every few metres, and a car driving ahead on the same path (the one the camera shows).
//! Connected to a simulator, it scans the simulator's world instead: posts along both sides of its road
//! and its obstacles.
//! Each scan casts `channels` × `columns` rays from the sensor, 1.9 m above the vehicle, and returns the
//! nearest hit of each within range, in the sensor frame (x forward, y left, z up), with an intensity that
//! depends on what was hit and range noise.

use std::f64::consts::TAU;

use glam::{DQuat, DVec3, Vec3};
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::rng::NoiseRng;
use kairos_sdk::{
    Component, ComponentInfo, ComponentResult, Context, DataType, ExecutionMode, Payload, PointCloud, Value,
};

use crate::trajectory::Trajectory;
use crate::world::WorldView;
use crate::{Seen, TimeBase, apply_rate, rate_changed, rate_property, seen, with_vehicle_input};

/// The component's type name.
pub const TYPE_NAME: &str = "sensors.lidar";

/// Separates the lidar's noise stream from other sensors given the same seed.
const NOISE_SALT: u64 = 0x11DA_2D00;
/// The sensor's height above the vehicle's reference point, metres.
const MOUNT_HEIGHT_M: f64 = 1.9;
/// Posts stand this far apart along the path, and this far to each side of it, metres.
const POST_SPACING_M: f64 = 8.0;
const POST_OFFSET_M: f64 = 6.0;
const POST_RADIUS_M: f64 = 0.15;
const POST_HEIGHT_M: f64 = 3.0;
/// How far ahead the car drives, in seconds of the vehicle's own path.
const CAR_AHEAD_S: f64 = 1.8;
/// The car's half extents: length, width, height, metres.
const CAR_HALF: DVec3 = DVec3::new(2.25, 0.9, 0.75);
/// Intensities of what a ray can hit.
const GROUND_INTENSITY: f32 = 0.15;
const POST_INTENSITY: f32 = 0.85;
const CAR_INTENSITY: f32 = 0.55;

/// The descriptor of `sensors.lidar`.
pub fn descriptor() -> ComponentInfo {
    with_vehicle_input(Descriptor::new(
        TYPE_NAME,
        "sensors",
        "Simulated spinning lidar on the simulated vehicle: the ground, posts along the road and the car \
         ahead (with a simulator, its obstacles), as a point cloud in the sensor frame with intensities",
    ))
    .label("Simulated lidar")
    .mode(ExecutionMode::Periodic)
    .output(
        "points",
        DataType::PointCloud,
        "One revolution: points in metres in the sensor frame (x forward, y left, z up), intensity 0 to 1",
    )
    .property(rate_property(10.0, 50.0, "revolutions"))
    .property(
        Property::i64("channels", 32)
            .range(1.0, 256.0)
            .doc("Laser channels (rows), spread over the vertical field of view"),
    )
    .property(
        Property::i64("columns", 1024)
            .range(16.0, 8192.0)
            .doc("Rays per channel per revolution (horizontal resolution)"),
    )
    .property(
        Property::f64("fov_up_deg", 15.0)
            .unit("deg")
            .range(-90.0, 90.0)
            .doc("Elevation of the highest channel, degrees"),
    )
    .property(
        Property::f64("fov_down_deg", -25.0)
            .unit("deg")
            .range(-90.0, 90.0)
            .doc("Elevation of the lowest channel, degrees"),
    )
    .property(
        Property::f64("max_range_m", 80.0)
            .unit("m")
            .range(1.0, 1000.0)
            .live()
            .doc("Farther hits are not returned, metres"),
    )
    .property(
        Property::f64("range_noise_m", 0.02)
            .unit("m")
            .range(0.0, 5.0)
            .live()
            .doc("Standard deviation of the noise on each range, metres"),
    )
    .property(
        Property::i64("seed", 3).doc("Seed of the noise generator: the same seed gives the same output"),
    )
    .build()
}

/// A post: a vertical cylinder standing on the ground.
#[derive(Debug, Clone, Copy)]
struct Post {
    east: f64,
    north: f64,
}

/// Posts every [`POST_SPACING_M`] along the path, on both sides.
fn posts(trajectory: &Trajectory) -> Vec<Post> {
    let steps = 20_000;
    let point = |theta: f64| {
        DVec3::new(
            trajectory.half_length_m * theta.sin(),
            trajectory.half_width_m * (2.0 * theta).sin(),
            0.0,
        )
    };
    let mut posts = Vec::new();
    let mut travelled = 0.0;
    let mut previous = point(0.0);
    for step in 1..=steps {
        let here = point(TAU * f64::from(step) / f64::from(steps));
        let along = here - previous;
        travelled += along.length();
        if travelled >= POST_SPACING_M {
            travelled -= POST_SPACING_M;
            let side = DVec3::new(-along.y, along.x, 0.0).normalize_or_zero() * POST_OFFSET_M;
            for offset in [side, -side] {
                posts.push(Post {
                    east: here.x + offset.x,
                    north: here.y + offset.y,
                });
            }
        }
        previous = here;
    }
    posts
}

/// Distance along `direction` (a unit vector) from `origin` to a vertical cylinder, if the ray hits it.
fn hit_post(origin: DVec3, direction: DVec3, post: Post, ground: f64) -> Option<f64> {
    // |origin + t·direction − axis|² = r² in the horizontal plane: quadratic·t² + linear·t + constant = 0.
    let (ox, oy) = (origin.x - post.east, origin.y - post.north);
    let quadratic = direction.x * direction.x + direction.y * direction.y;
    if quadratic < 1e-12 {
        return None;
    }
    let linear = 2.0 * (ox * direction.x + oy * direction.y);
    let constant = ox * ox + oy * oy - POST_RADIUS_M * POST_RADIUS_M;
    let discriminant = linear * linear - 4.0 * quadratic * constant;
    if discriminant < 0.0 {
        return None;
    }
    let t = (-linear - discriminant.sqrt()) / (2.0 * quadratic);
    let z = origin.z + t * direction.z;
    (t > 0.0 && z >= ground && z <= ground + POST_HEIGHT_M).then_some(t)
}

/// Posts every [`POST_SPACING_M`] along a simulator's road, on both sides, in the world frame.
fn posts_along(view: &WorldView) -> Vec<Post> {
    let state = &view.state;
    let to_world = |x: f64, y: f64| {
        let (sin, cos) = state.yaw.sin_cos();
        (
            state.position.x + cos * x - sin * y,
            state.position.y + sin * x + cos * y,
        )
    };
    // As far beyond the road's edge as the figure-eight's posts stand beyond its 3.5 m lanes.
    let offset = view.lane_width_m + POST_OFFSET_M - 3.5;
    let mut posts = Vec::new();
    for pair in view.road.windows(2) {
        let [before, after] = pair else { continue };
        let mark = (after.station_m / POST_SPACING_M).floor() * POST_SPACING_M;
        if mark <= before.station_m || after.station_m <= before.station_m {
            continue;
        }
        let share = (mark - before.station_m) / (after.station_m - before.station_m);
        let (dx, dy) = (after.x - before.x, after.y - before.y);
        let (along_x, along_y) = (before.x + dx * share, before.y + dy * share);
        let length = dx.hypot(dy).max(f64::EPSILON);
        let (normal_x, normal_y) = (-dy / length, dx / length);
        for side in [offset, -offset] {
            let (east, north) = to_world(along_x + normal_x * side, along_y + normal_y * side);
            posts.push(Post { east, north });
        }
    }
    posts
}

/// A box a ray may hit: centre, heading and half extents, in the world frame.
#[derive(Debug, Clone, Copy)]
struct Target {
    centre: DVec3,
    yaw: f64,
    half: DVec3,
}

/// A simulator's obstacles as boxes in the world frame.
fn targets_in(view: &WorldView) -> Vec<Target> {
    let state = &view.state;
    let (sin, cos) = state.yaw.sin_cos();
    view.obstacles
        .iter()
        .map(|o| Target {
            centre: DVec3::new(
                state.position.x + cos * o.x - sin * o.y,
                state.position.y + sin * o.x + cos * o.y,
                state.position.z + 0.5 * o.height,
            ),
            yaw: state.yaw + o.yaw,
            half: 0.5 * DVec3::new(o.length, o.width, o.height),
        })
        .collect()
}

/// Distance to an oriented box, by the slab method in the box's frame.
fn hit_box(origin: DVec3, direction: DVec3, target: &Target) -> Option<f64> {
    let to_box = DQuat::from_rotation_z(-target.yaw);
    let o = to_box * (origin - target.centre);
    let d = to_box * direction;
    let (mut near, mut far) = (f64::NEG_INFINITY, f64::INFINITY);
    for axis in 0..3 {
        let (o, d, half) = (o[axis], d[axis], target.half[axis]);
        if d.abs() < 1e-12 {
            if o.abs() > half {
                return None;
            }
            continue;
        }
        let (t1, t2) = ((-half - o) / d, (half - o) / d);
        near = near.max(t1.min(t2));
        far = far.min(t1.max(t2));
    }
    (near <= far && near > 0.0).then_some(near)
}

/// The `sensors.lidar` component. See [`descriptor`].
#[derive(Debug)]
pub struct LidarSensor {
    trajectory: Trajectory,
    posts: Vec<Post>,
    time: TimeBase,
    rng: NoiseRng,
    /// Ray directions in the sensor frame, channel by channel.
    rays: Vec<DVec3>,
    max_range: f64,
    range_noise: f64,
    /// A simulator's newest world, when the `vehicle` input is connected.
    world: Option<WorldView>,
}

impl Default for LidarSensor {
    fn default() -> Self {
        let trajectory = Trajectory::default();
        LidarSensor {
            posts: posts(&trajectory),
            trajectory,
            time: TimeBase::default(),
            rng: NoiseRng::new(3, NOISE_SALT),
            rays: Vec::new(),
            max_range: 80.0,
            range_noise: 0.0,
            world: None,
        }
    }
}

impl LidarSensor {
    /// One revolution, of the figure-eight or of a simulator's world.
    fn scan(&mut self, seen: &Seen) -> PointCloud {
        let state = *seen.state();
        let origin = state.position + state.orientation * DVec3::new(0.0, 0.0, MOUNT_HEIGHT_M);
        let ground = state.position.z;
        let (posts, targets) = match seen {
            Seen::Trajectory(_) => {
                let ahead = self.trajectory.state(state.time_s + CAR_AHEAD_S);
                let car = Target {
                    centre: ahead.position + DVec3::new(0.0, 0.0, CAR_HALF.z),
                    yaw: ahead.yaw,
                    half: CAR_HALF,
                };
                (None, vec![car])
            }
            Seen::World(view) => (Some(posts_along(view)), targets_in(view)),
        };
        let near: Vec<Post> = posts
            .as_ref()
            .unwrap_or(&self.posts)
            .iter()
            .copied()
            .filter(|p| {
                let (de, dn) = (p.east - origin.x, p.north - origin.y);
                de * de + dn * dn <= (self.max_range + 1.0).powi(2)
            })
            .collect();
        let mut points: Vec<Vec3> = Vec::with_capacity(self.rays.len());
        let mut intensity = Vec::with_capacity(self.rays.len());
        for ray in &self.rays {
            let direction = state.orientation * *ray;
            let mut best: Option<(f64, f32)> = None;
            let mut consider = |t: Option<f64>, what: f32| {
                if let Some(t) = t
                    && t <= self.max_range
                    && best.is_none_or(|(b, _)| t < b)
                {
                    best = Some((t, what));
                }
            };
            if direction.z < -1e-9 {
                consider(Some((ground - origin.z) / direction.z), GROUND_INTENSITY);
            }
            for post in &near {
                consider(hit_post(origin, direction, *post, ground), POST_INTENSITY);
            }
            for target in &targets {
                consider(hit_box(origin, direction, target), CAR_INTENSITY);
            }
            if let Some((range, what)) = best {
                let range = (range + self.rng.normal(self.range_noise)).max(0.0);
                points.push((*ray * range).as_vec3());
                #[allow(clippy::cast_possible_truncation, reason = "an intensity, 0 to 1")]
                let fade = (1.0 - range / self.max_range).clamp(0.0, 1.0) as f32;
                intensity.push(what * (0.6 + 0.4 * fade));
            }
        }
        PointCloud {
            points,
            intensity: Some(intensity),
        }
    }
}

impl Component for LidarSensor {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.time = TimeBase::default();
        self.rng = NoiseRng::new(ctx.i64_property("seed")?, NOISE_SALT);
        self.max_range = ctx.f64_property("max_range_m")?;
        self.range_noise = ctx.f64_property("range_noise_m")?;
        let channels = ctx.i64_property("channels")?;
        let columns = ctx.i64_property("columns")?;
        let (up, down) = (
            ctx.f64_property("fov_up_deg")?.to_radians(),
            ctx.f64_property("fov_down_deg")?.to_radians(),
        );
        self.rays.clear();
        for channel in 0..channels {
            let elevation = if channels == 1 {
                up
            } else {
                down + (up - down) * channel as f64 / (channels - 1) as f64
            };
            for column in 0..columns {
                let azimuth = TAU * column as f64 / columns as f64;
                self.rays.push(DVec3::new(
                    elevation.cos() * azimuth.cos(),
                    elevation.cos() * azimuth.sin(),
                    elevation.sin(),
                ));
            }
        }
        apply_rate(ctx)?;
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let now = ctx.now();
        let Some(seen) = seen(ctx, &self.trajectory, &mut self.time, &mut self.world)? else {
            return Ok(());
        };
        let cloud = self.scan(&seen);
        ctx.write_at("points", Payload::PointCloud(std::sync::Arc::new(cloud)), now)
    }

    fn property_changed(&mut self, name: &str, value: &Value, ctx: &mut Context) -> ComponentResult {
        rate_changed(name, value, ctx);
        match name {
            "max_range_m" => self.max_range = ctx.f64_property(name)?,
            "range_noise_m" => self.range_noise = ctx.f64_property(name)?,
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {

    use kairos_sdk::Value;
    use kairos_sdk::harness::Harness;

    use super::{LidarSensor, descriptor};

    #[test]
    fn a_scan_sees_the_ground_the_posts_and_the_car_ahead() {
        let mut harness = Harness::new(descriptor(), LidarSensor::default());
        harness.leave_unconnected("vehicle");
        for (name, value) in [
            ("channels", Value::I64(16)),
            ("columns", Value::I64(360)),
            ("range_noise_m", Value::F64(0.0)),
        ] {
            harness.set_property(name, value).expect("property");
        }
        // Ten seconds at 10 Hz: the vehicle is past its start and cruising, the car ahead of it.
        let out = harness.run_periodic(100).expect("the lidar runs");
        let clouds = out.samples("points");
        assert_eq!(clouds.len(), 100);
        let Some(kairos_sdk::Payload::PointCloud(cloud)) = clouds.last().map(|s| &s.payload) else {
            panic!("not a point cloud");
        };
        let intensity = cloud.intensity.as_ref().expect("intensities");
        assert_eq!(intensity.len(), cloud.points.len());
        let count = |keep: &dyn Fn(&glam::Vec3, f32) -> bool| {
            cloud
                .points
                .iter()
                .zip(intensity)
                .filter(|(p, i)| keep(p, **i))
                .count()
        };
        // Intensities tell what was hit: ground 0.09 to 0.15, the car 0.33 to 0.55, posts above that.
        let ground = count(&|p, i| i < 0.2 && p.z < -1.0);
        let posts = count(&|_, i| i > 0.56);
        let car = count(&|p, i| (0.3..0.56).contains(&i) && p.x > 2.0 && p.x < 40.0 && p.y.abs() < 4.0);
        assert!(ground > 500, "{ground} ground points");
        assert!(posts > 10, "{posts} post points");
        assert!(car > 3, "{car} points on the car ahead");
        // Nothing beyond the range.
        assert!(cloud.points.iter().all(|p| p.length() <= 80.5));
    }
}

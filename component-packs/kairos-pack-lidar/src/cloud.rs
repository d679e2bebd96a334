//! Point-cloud processing as pure functions: crop, voxel-grid downsampling, ground-plane removal, a
//! range image, and Euclidean clustering into boxes.

use std::collections::HashMap;

use glam::{DMat3, DVec3, Vec3};
use kairos_sdk::PointCloud;

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The lowest corner.
    pub min: Vec3,
    /// The highest corner.
    pub max: Vec3,
}

impl Aabb {
    /// Whether `p` lies inside (edges included).
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }
}

/// The points of `cloud` for which `keep` is true, with their intensities.
pub fn filtered(cloud: &PointCloud, mut keep: impl FnMut(usize, Vec3) -> bool) -> PointCloud {
    let mut points = Vec::with_capacity(cloud.points.len());
    let mut intensity = cloud
        .intensity
        .as_ref()
        .map(|_| Vec::with_capacity(cloud.points.len()));
    for (i, p) in cloud.points.iter().enumerate() {
        if keep(i, *p) {
            points.push(*p);
            if let (Some(out), Some(all)) = (intensity.as_mut(), cloud.intensity.as_ref()) {
                out.push(all.get(i).copied().unwrap_or(0.0));
            }
        }
    }
    PointCloud { points, intensity }
}

/// One point per occupied cube of side `leaf` metres: the mean of the points in it (and of their
/// intensities). Non-finite points are dropped.
pub fn voxel_grid(cloud: &PointCloud, leaf: f32) -> PointCloud {
    // Each point's cube as one sortable key: 21 bits per axis (±1 048 576 cubes around the origin).
    const OFFSET: i64 = 1 << 20;
    let inverse = 1.0 / leaf.max(1e-4);
    let mut keyed: Vec<(u64, u32)> = cloud
        .points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.is_finite())
        .map(|(i, p)| {
            let cell = (*p * inverse).floor();
            let axis = |v: f32| ((v as i64).clamp(-OFFSET, OFFSET - 1) + OFFSET) as u64;
            (
                (axis(cell.x) << 42) | (axis(cell.y) << 21) | axis(cell.z),
                i as u32,
            )
        })
        .collect();
    keyed.sort_unstable_by_key(|(key, _)| *key);
    let mut points = Vec::new();
    let mut intensity = cloud.intensity.as_ref().map(|_| Vec::new());
    for run in keyed.chunk_by(|a, b| a.0 == b.0) {
        let n = run.len() as f32;
        let sum: Vec3 = run.iter().map(|(_, i)| cloud.points[*i as usize]).sum();
        points.push(sum / n);
        if let (Some(out), Some(all)) = (intensity.as_mut(), cloud.intensity.as_ref()) {
            let total: f32 = run
                .iter()
                .map(|(_, i)| all.get(*i as usize).copied().unwrap_or(0.0))
                .sum();
            out.push(total / n);
        }
    }
    PointCloud { points, intensity }
}

/// A plane `n · p + d = 0` with `n` of unit length pointing up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: DVec3,
    /// Offset.
    pub d: f64,
}

impl Plane {
    /// Signed distance of `p` above the plane.
    pub fn distance(&self, p: Vec3) -> f64 {
        self.normal.dot(p.as_dvec3()) + self.d
    }
}

/// What [`ground_plane`] looks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundSearch {
    /// Points closer to the plane than this are ground, metres.
    pub distance: f64,
    /// Steepest ground accepted, degrees from horizontal.
    pub max_tilt_deg: f64,
    /// Random samples of three points tried.
    pub iterations: usize,
}

/// The ground: the plane, tilted at most `max_tilt_deg`, that the most points lie near (RANSAC with a
/// fixed seed, so a cloud always gives the same plane), refined by least squares on those points.
pub fn ground_plane(cloud: &PointCloud, search: &GroundSearch) -> Option<Plane> {
    let points: Vec<Vec3> = cloud.points.iter().copied().filter(|p| p.is_finite()).collect();
    if points.len() < 3 {
        return None;
    }
    let mut state = 0x9E37_79B9_7F4A_7C15_u64;
    let mut next = |n: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as usize
    };
    let min_up = search.max_tilt_deg.to_radians().cos();
    // Count inliers on a subsample: a few thousand points tell planes apart as well as all of them.
    let stride = (points.len() / 4000).max(1);
    let mut best: Option<(usize, Plane)> = None;
    for _ in 0..search.iterations.max(1) {
        let (a, b, c) = (
            points[next(points.len())],
            points[next(points.len())],
            points[next(points.len())],
        );
        let normal = (b - a).as_dvec3().cross((c - a).as_dvec3());
        if normal.length() < 1e-9 {
            continue;
        }
        let mut normal = normal.normalize();
        if normal.z < 0.0 {
            normal = -normal;
        }
        if normal.z < min_up {
            continue;
        }
        let plane = Plane {
            normal,
            d: -normal.dot(a.as_dvec3()),
        };
        let inliers = points
            .iter()
            .step_by(stride)
            .filter(|p| plane.distance(**p).abs() < search.distance)
            .count();
        if best.is_none_or(|(count, _)| inliers > count) {
            best = Some((inliers, plane));
        }
    }
    let (_, rough) = best?;
    // Least squares z = a x + b y + c over the inliers.
    let (mut normal_matrix, mut moments) = (DMat3::ZERO, DVec3::ZERO);
    for p in points
        .iter()
        .filter(|p| rough.distance(**p).abs() < search.distance)
    {
        let p = p.as_dvec3();
        let row = DVec3::new(p.x, p.y, 1.0);
        normal_matrix += DMat3::from_cols(row * row.x, row * row.y, row * row.z);
        moments += row * p.z;
    }
    if normal_matrix.determinant().abs() < 1e-9 {
        return Some(rough);
    }
    let [slope_x, slope_y, height] = (normal_matrix.inverse() * moments).to_array();
    let normal = DVec3::new(-slope_x, -slope_y, 1.0);
    let length = normal.length();
    Some(Plane {
        normal: normal / length,
        d: -height / length,
    })
}

/// A grey range image of a spinning lidar's cloud: one row per `rows` band of elevation between
/// `fov_down_deg` and `fov_up_deg`, one column per `columns` slice of azimuth (column 0 straight behind,
/// the middle column straight ahead); near is bright, `max_range` and beyond (or nothing) is black.
pub fn range_image(
    cloud: &PointCloud,
    (rows, columns): (usize, usize),
    (fov_down_deg, fov_up_deg): (f32, f32),
    max_range: f32,
) -> Vec<u8> {
    let mut image = vec![0_u8; rows * columns];
    let (down, up) = (fov_down_deg.to_radians(), fov_up_deg.to_radians());
    let span = (up - down).max(1e-6);
    for p in &cloud.points {
        let range = p.length();
        if !range.is_finite() || range <= 0.0 || range >= max_range {
            continue;
        }
        let elevation = (p.z / range).asin();
        let azimuth = p.y.atan2(p.x);
        let row = ((up - elevation) / span * rows as f32).floor();
        let column = ((azimuth + std::f32::consts::PI) / std::f32::consts::TAU * columns as f32).floor();
        if row < 0.0 || row >= rows as f32 || column < 0.0 {
            continue;
        }
        // Straight behind is both −π and π: the same column.
        let at = row as usize * columns + (column as usize) % columns;
        let brightness = (255.0 * (1.0 - range / max_range)).clamp(1.0, 255.0) as u8;
        // The nearest point of a cell wins, as a depth image shows the first surface.
        image[at] = image[at].max(brightness);
    }
    image
}

/// What [`clusters`] keeps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClusterSearch {
    /// Points closer than this join a cluster, metres.
    pub tolerance: f32,
    /// Smaller clusters are noise.
    pub min_points: usize,
    /// Larger clusters are not objects (walls, the remaining ground).
    pub max_points: usize,
}

/// Euclidean clusters of `cloud`: points chained by gaps shorter than `tolerance`, as boxes, largest
/// first. Neighbours are found through a grid of cells of side `tolerance`.
pub fn clusters(cloud: &PointCloud, search: &ClusterSearch) -> Vec<Aabb> {
    let tolerance = search.tolerance.max(1e-3);
    let cell_of = |p: Vec3| {
        let c = (p / tolerance).floor();
        (c.x as i32, c.y as i32, c.z as i32)
    };
    let mut grid: HashMap<(i32, i32, i32), Vec<u32>> = HashMap::new();
    for (i, p) in cloud.points.iter().enumerate() {
        if p.is_finite() {
            grid.entry(cell_of(*p)).or_default().push(i as u32);
        }
    }
    let squared = tolerance * tolerance;
    let mut visited = vec![false; cloud.points.len()];
    let mut boxes: Vec<(usize, Aabb)> = Vec::new();
    let mut queue = Vec::new();
    for start in 0..cloud.points.len() {
        if visited[start] || !cloud.points[start].is_finite() {
            continue;
        }
        visited[start] = true;
        queue.clear();
        queue.push(start as u32);
        let mut bounds = Aabb {
            min: cloud.points[start],
            max: cloud.points[start],
        };
        let mut count = 0;
        while let Some(i) = queue.pop() {
            let p = cloud.points[i as usize];
            count += 1;
            bounds.min = bounds.min.min(p);
            bounds.max = bounds.max.max(p);
            let (cx, cy, cz) = cell_of(p);
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let Some(members) = grid.get(&(cx + dx, cy + dy, cz + dz)) else {
                            continue;
                        };
                        for &j in members {
                            if !visited[j as usize] && cloud.points[j as usize].distance_squared(p) <= squared
                            {
                                visited[j as usize] = true;
                                queue.push(j);
                            }
                        }
                    }
                }
            }
        }
        if (search.min_points..=search.max_points).contains(&count) {
            boxes.push((count, bounds));
        }
    }
    boxes.sort_by_key(|(count, _)| std::cmp::Reverse(*count));
    boxes.into_iter().map(|(_, b)| b).collect()
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use kairos_sdk::PointCloud;

    use super::{
        Aabb, ClusterSearch, GroundSearch, clusters, filtered, ground_plane, range_image, voxel_grid,
    };

    /// Flat ground at z = −1.8 (a 20 m square, 0.2 m apart) and two boxes of points standing on it.
    fn scene() -> PointCloud {
        let mut points = Vec::new();
        for i in 0..100 {
            for j in 0..100 {
                points.push(Vec3::new(i as f32 * 0.2 - 10.0, j as f32 * 0.2 - 10.0, -1.8));
            }
        }
        for (cx, cy) in [(5.0, 2.0), (-4.0, -3.0)] {
            for i in 0..10 {
                for k in 0..10 {
                    points.push(Vec3::new(cx + i as f32 * 0.1, cy, -1.7 + k as f32 * 0.15));
                }
            }
        }
        points.push(Vec3::NAN);
        PointCloud {
            points,
            intensity: None,
        }
    }

    #[test]
    fn the_ground_is_found_and_what_stands_on_it_clusters_into_two_boxes() {
        let cloud = scene();
        let plane = ground_plane(
            &cloud,
            &GroundSearch {
                distance: 0.05,
                max_tilt_deg: 15.0,
                iterations: 100,
            },
        )
        .unwrap();
        assert!(
            (plane.normal.z - 1.0).abs() < 1e-6 && (plane.d - 1.8).abs() < 1e-6,
            "{plane:?}"
        );
        let obstacles = filtered(&cloud, |_, p| p.is_finite() && plane.distance(p) > 0.12);
        assert_eq!(
            obstacles.points.len(),
            2 * 10 * 9,
            "the lowest row of each box is within 0.12 m of the ground"
        );
        let boxes = clusters(
            &obstacles,
            &ClusterSearch {
                tolerance: 0.5,
                min_points: 10,
                max_points: 10_000,
            },
        );
        assert_eq!(boxes.len(), 2, "{boxes:?}");
        assert!(
            boxes.iter().any(|b| b.contains(Vec3::new(5.4, 2.0, -1.0))),
            "{boxes:?}"
        );
        let tight = Aabb {
            min: Vec3::new(-4.0, -3.0, -1.55),
            max: Vec3::new(-3.1, -3.0, -0.35),
        };
        assert!(
            boxes
                .iter()
                .any(|b| (b.min - tight.min).length() < 1e-4 && (b.max - tight.max).length() < 1e-4),
            "{boxes:?}"
        );
    }

    #[test]
    fn a_voxel_grid_keeps_one_mean_point_per_cube() {
        let cloud = PointCloud {
            points: vec![
                Vec3::new(0.1, 0.1, 0.1),
                Vec3::new(0.3, 0.3, 0.3),
                Vec3::new(1.5, 0.1, 0.1),
                Vec3::NAN,
            ],
            intensity: Some(vec![1.0, 0.0, 0.5, 0.5]),
        };
        let down = voxel_grid(&cloud, 1.0);
        assert_eq!(down.points, [Vec3::splat(0.2), Vec3::new(1.5, 0.1, 0.1)]);
        assert_eq!(down.intensity, Some(vec![0.5, 0.5]));
        // The ground's 400 cubes, and one more above it for each box.
        assert_eq!(voxel_grid(&scene(), 1.0).points.len(), 20 * 20 + 2);
    }

    #[test]
    fn the_range_image_puts_near_points_ahead_in_the_middle_and_bright() {
        let cloud = PointCloud {
            points: vec![Vec3::new(5.0, 0.0, 0.0), Vec3::new(-50.0, 0.0, 0.0)],
            intensity: None,
        };
        let image = range_image(&cloud, (16, 360), (-15.0, 15.0), 100.0);
        let lit: Vec<usize> = (0..image.len()).filter(|i| image[*i] > 0).collect();
        assert_eq!(lit.len(), 2, "{lit:?}");
        assert_eq!(lit[0] % 360, 0, "behind: the first column");
        assert_eq!(lit[1] % 360, 180, "ahead: the middle column");
        assert!(image[lit[1]] > image[lit[0]], "near is brighter");
    }
}

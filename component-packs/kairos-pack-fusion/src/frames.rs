//! Static coordinate frames from a file: where each sensor sits on the vehicle, and so how to carry a
//! point from one frame to another.
//!
//! ```toml
//! # Frames are named; each but the root has a parent and a pose in it.
//! [frame.lidar]
//! parent = "vehicle"
//! translation = [1.20, 0.0, 1.85]   # metres, in the parent's axes
//! rotation = [0.0, 0.0, 90.0]       # roll, pitch, yaw in degrees (applied yaw, then pitch, then roll)
//! ```
//!
//! A frame named as a parent without a section of its own is a root (`vehicle` above). Errors name the
//! file, line and column: an unknown key, a value of the wrong kind, a parent that does not exist as a
//! frame or root, a cycle, numbers that are not finite.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DQuat, DVec3, EulerRot};
use serde::Deserialize;
use toml::Spanned;

/// Why a frames file was refused: `file:line:column: what`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct FramesError(pub String);

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileFormat {
    #[serde(default)]
    frame: BTreeMap<String, Spanned<FrameEntry>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FrameEntry {
    parent: Spanned<String>,
    #[serde(default)]
    translation: Option<Spanned<[f64; 3]>>,
    #[serde(default)]
    rotation: Option<Spanned<[f64; 3]>>,
}

/// A rigid transform: `rotation` then `translation` (child coordinates into the parent's).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    /// Rotation from the child's axes to the parent's.
    pub rotation: DQuat,
    /// The child's origin in the parent's axes, metres.
    pub translation: DVec3,
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform = Transform {
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
    };

    /// Applies the transform to a point.
    pub fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// `self` after `inner`: first `inner`, then `self`.
    #[must_use]
    pub fn after(&self, inner: &Transform) -> Transform {
        Transform {
            rotation: self.rotation * inner.rotation,
            translation: self.rotation * inner.translation + self.translation,
        }
    }

    /// The inverse transform.
    #[must_use]
    pub fn inverse(&self) -> Transform {
        let rotation = self.rotation.inverse();
        Transform {
            rotation,
            translation: -(rotation * self.translation),
        }
    }
}

/// The frames of a file: each with its parent and its pose in it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frames {
    parents: BTreeMap<String, (String, Transform)>,
}

impl Frames {
    /// Reads and checks the frames file at `path`.
    pub fn load(path: &Path) -> Result<Frames, FramesError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| FramesError(format!("cannot read the frames file {}: {e}", path.display())))?;
        Frames::parse(&text, &path.display().to_string())
    }

    /// Parses and checks `text`; errors are located as `shown:line:column`.
    pub fn parse(text: &str, shown: &str) -> Result<Frames, FramesError> {
        let at = |offset: usize, what: String| {
            let (line, column) = kairos_sdk::text::line_column(text, offset);
            FramesError(format!("{shown}:{line}:{column}: {what}"))
        };
        let file: FileFormat = toml::from_str(text).map_err(|e| {
            let offset = e.span().map_or(0, |s| s.start);
            at(offset, e.message().to_owned())
        })?;
        let mut parents = BTreeMap::new();
        for (name, entry) in &file.frame {
            let entry = entry.get_ref();
            let finite = |values: &Option<Spanned<[f64; 3]>>, what: &str| -> Result<[f64; 3], FramesError> {
                match values {
                    None => Ok([0.0; 3]),
                    Some(v) if v.get_ref().iter().all(|x| x.is_finite()) => Ok(*v.get_ref()),
                    Some(v) => Err(at(
                        v.span().start,
                        format!("frame '{name}': the {what} has a number that is not finite"),
                    )),
                }
            };
            let translation = finite(&entry.translation, "translation")?;
            let [roll, pitch, yaw] = finite(&entry.rotation, "rotation")?;
            let rotation = DQuat::from_euler(
                EulerRot::ZYX,
                yaw.to_radians(),
                pitch.to_radians(),
                roll.to_radians(),
            );
            let parent = entry.parent.get_ref().clone();
            if parent == *name {
                return Err(at(
                    entry.parent.span().start,
                    format!("frame '{name}' cannot be its own parent"),
                ));
            }
            parents.insert(
                name.clone(),
                (
                    parent,
                    Transform {
                        rotation,
                        translation: DVec3::from_array(translation),
                    },
                ),
            );
        }
        // Every chain must end at a root: a cycle never does.
        for (name, entry) in &file.frame {
            let mut seen = vec![name.as_str()];
            let mut current = name.as_str();
            while let Some((parent, _)) = parents.get(current) {
                if seen.contains(&parent.as_str()) {
                    seen.push(parent);
                    return Err(at(
                        entry.get_ref().parent.span().start,
                        format!("the frames form a cycle: {}", seen.join(" -> ")),
                    ));
                }
                seen.push(parent);
                current = parent;
            }
        }
        Ok(Frames { parents })
    }

    /// Every frame named in the file, roots included.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.parents.keys().cloned().collect();
        names.extend(self.parents.values().map(|(p, _)| p.clone()));
        names.sort();
        names.dedup();
        names
    }

    /// The transform from `frame` to its root, and the root's name; `None` for an unknown frame.
    fn to_root(&self, frame: &str) -> Option<(Transform, String)> {
        if !self.parents.contains_key(frame) && !self.parents.values().any(|(p, _)| p == frame) {
            return None;
        }
        let mut transform = Transform::IDENTITY;
        let mut current = frame.to_owned();
        while let Some((parent, step)) = self.parents.get(&current) {
            transform = step.after(&transform);
            current = parent.clone();
        }
        Some((transform, current))
    }

    /// The transform carrying coordinates in `from` into `to`.
    pub fn between(&self, from: &str, to: &str) -> Result<Transform, FramesError> {
        let known = || self.names().join(", ");
        let (from_root, root_a) = self.to_root(from).ok_or_else(|| {
            FramesError(format!(
                "no frame '{from}' in the frames file (it has {})",
                known()
            ))
        })?;
        let (to_root, root_b) = self
            .to_root(to)
            .ok_or_else(|| FramesError(format!("no frame '{to}' in the frames file (it has {})", known())))?;
        if root_a != root_b {
            return Err(FramesError(format!(
                "'{from}' and '{to}' are not connected: one hangs from '{root_a}', the other from '{root_b}'"
            )));
        }
        Ok(to_root.inverse().after(&from_root))
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::Frames;

    const RIG: &str = "\
[frame.lidar]
parent = \"vehicle\"
translation = [1.0, 0.0, 2.0]
rotation = [0.0, 0.0, 90.0]

[frame.camera]
parent = \"vehicle\"
translation = [2.0, 0.5, 1.0]
";

    #[test]
    fn points_move_between_sensor_frames_through_the_vehicle() {
        let frames = Frames::parse(RIG, "rig.toml").unwrap();
        // One metre ahead of the lidar, which is turned 90° left: one metre to the vehicle's left.
        let to_vehicle = frames.between("lidar", "vehicle").unwrap();
        let p = to_vehicle.point(DVec3::X);
        assert!((p - DVec3::new(1.0, 1.0, 2.0)).length() < 1e-12, "{p}");
        let to_camera = frames.between("lidar", "camera").unwrap();
        let q = to_camera.point(DVec3::X);
        assert!((q - DVec3::new(-1.0, 0.5, 1.0)).length() < 1e-12, "{q}");
        let back = frames.between("camera", "lidar").unwrap().point(q);
        assert!((back - DVec3::X).length() < 1e-12);
    }

    #[test]
    fn errors_name_the_line_and_column() {
        let cases = [
            (
                "[frame.a]\nparent = \"b\"\ntranslaton = [1, 2, 3]\n",
                "rig.toml:3:1",
                "translaton",
            ),
            (
                "[frame.a]\nparent = \"b\"\ntranslation = [1, 2]\n",
                "rig.toml:3:15",
                "",
            ),
            (
                "[frame.a]\nparent = \"b\"\n[frame.b]\nparent = \"a\"\n",
                "rig.toml:",
                "cycle",
            ),
            ("[frame.a]\nparent = \"a\"\n", "rig.toml:2:10", "own parent"),
            (
                "[frame.a]\nparent = \"b\"\nrotation = [0, nan, 0]\n",
                "rig.toml:3:12",
                "not finite",
            ),
        ];
        for (text, place, words) in cases {
            let error = Frames::parse(text, "rig.toml").unwrap_err().0;
            assert!(
                error.starts_with(place) && error.contains(words),
                "{text:?}: {error}"
            );
        }
        let frames = Frames::parse(RIG, "rig.toml").unwrap();
        let error = frames.between("radar", "vehicle").unwrap_err().0;
        assert!(
            error.contains("no frame 'radar'") && error.contains("camera, lidar, vehicle"),
            "{error}"
        );
    }
}

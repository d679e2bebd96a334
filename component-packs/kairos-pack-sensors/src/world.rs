//! What a simulator tells the simulated sensors: the `sim_world` sample type.
//!
//! A simulator (the `sim` pack's vehicle) writes one [`WorldView`] per step: the vehicle's state, the
//! geographic origin of its world, and the part of the world around the vehicle that sensors see (the
//! road's centre line and the obstacles), already in the vehicle's frame. A sensor whose `vehicle` input
//! is connected renders from it instead of the fixed trajectory, so what the sensors see follows what
//! the diagram decides.
//!
//! Frames: the state is in the world's local east-north-up frame (see [`crate::trajectory`]); road and
//! obstacles are in the vehicle frame, x forward, y left, on the ground under the vehicle's reference
//! point. The road is flat.
//!
//! Encoding (little-endian): the magic `KSW1`, the state as 24 `f64`s, the origin (3 `f64`), the
//! station, lane width (2 `f64`), a `u32` count and that many road points (3 `f64` each: x, y, station),
//! a `u32` count and that many obstacles (6 `f64` each: x, y, yaw, length, width, height).

use std::sync::Arc;

use glam::{DQuat, DVec3};
use kairos_sdk::{CustomPayload, DataType, Payload};

use crate::geo::GeoPoint;
use crate::trajectory::VehicleState;

/// The registered name of the sample type.
pub const TYPE_NAME: &str = "sim_world";

const MAGIC: &[u8; 4] = b"KSW1";

/// The `sim_world` data type, for port declarations.
pub fn data_type() -> DataType {
    DataType::Custom(TYPE_NAME.to_owned())
}

/// A point of the road's centre line, in the vehicle frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadPoint {
    /// Metres ahead of the vehicle.
    pub x: f64,
    /// Metres left of the vehicle.
    pub y: f64,
    /// Metres along the road from its start.
    pub station_m: f64,
}

/// A box standing on the road (a parked car, a cone), in the vehicle frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Obstacle {
    /// Centre, metres ahead of the vehicle.
    pub x: f64,
    /// Centre, metres left of the vehicle.
    pub y: f64,
    /// Heading relative to the vehicle's, radians counter-clockwise.
    pub yaw: f64,
    /// Extent along its heading, metres.
    pub length: f64,
    /// Extent across, metres.
    pub width: f64,
    /// Height, metres.
    pub height: f64,
}

/// One step of a simulation, as the sensors see it.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldView {
    /// The vehicle.
    pub state: VehicleState,
    /// The geographic position of the world's origin.
    pub origin: GeoPoint,
    /// Metres the vehicle is along the road.
    pub station_m: f64,
    /// Width of one lane, metres; the road has two, one on each side of its centre line.
    pub lane_width_m: f64,
    /// The road's centre line around the vehicle, in order along the road.
    pub road: Vec<RoadPoint>,
    /// The obstacles near the vehicle.
    pub obstacles: Vec<Obstacle>,
}

fn push(bytes: &mut Vec<u8>, values: &[f64]) {
    for value in values {
        bytes.extend_from_slice(&value.to_le_bytes());
    }
}

/// Why bytes or a sample are not a `sim_world` view.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WorldError {
    /// Another payload type on the input.
    #[error("expected a {TYPE_NAME} sample, got {0}")]
    NotAWorld(DataType),
    /// Bytes without the magic.
    #[error("not a sim_world sample (it does not start with KSW1)")]
    NoMagic,
    /// Cut before a field.
    #[error("a sim_world sample ends before its {0}")]
    EndsBefore(&'static str),
    /// Cut before a list's count.
    #[error("a sim_world sample ends before its number of {0}")]
    EndsBeforeCount(&'static str),
    /// A count larger than the bytes that follow: refused, not allocated.
    #[error("a sim_world sample says it holds {count} {what}, but has bytes for fewer")]
    CountTooLarge {
        /// The count the bytes say.
        count: usize,
        /// What is counted.
        what: &'static str,
    },
}

/// Reads the encoding field by field, saying what is missing.
struct Fields<'a> {
    bytes: &'a [u8],
}

impl Fields<'_> {
    fn f64(&mut self, what: &'static str) -> Result<f64, WorldError> {
        let (head, rest) = self
            .bytes
            .split_first_chunk::<8>()
            .ok_or(WorldError::EndsBefore(what))?;
        self.bytes = rest;
        Ok(f64::from_le_bytes(*head))
    }

    fn vec3(&mut self, what: &'static str) -> Result<DVec3, WorldError> {
        Ok(DVec3::new(self.f64(what)?, self.f64(what)?, self.f64(what)?))
    }

    fn count(&mut self, what: &'static str, each: usize) -> Result<usize, WorldError> {
        let (head, rest) = self
            .bytes
            .split_first_chunk::<4>()
            .ok_or(WorldError::EndsBeforeCount(what))?;
        self.bytes = rest;
        let count = usize::try_from(u32::from_le_bytes(*head)).unwrap_or(usize::MAX);
        if count.saturating_mul(each * 8) > self.bytes.len() {
            return Err(WorldError::CountTooLarge { count, what });
        }
        Ok(count)
    }
}

impl WorldView {
    /// The view as bytes (see the module's documentation).
    pub fn encode(&self) -> Vec<u8> {
        let s = &self.state;
        let mut bytes = Vec::with_capacity(256 + 24 * self.road.len() + 48 * self.obstacles.len());
        bytes.extend_from_slice(MAGIC);
        push(
            &mut bytes,
            &[
                s.time_s,
                s.position.x,
                s.position.y,
                s.position.z,
                s.velocity.x,
                s.velocity.y,
                s.velocity.z,
                s.acceleration.x,
                s.acceleration.y,
                s.acceleration.z,
                s.yaw,
                s.yaw_rate,
                s.pitch,
                s.pitch_rate,
                s.orientation.x,
                s.orientation.y,
                s.orientation.z,
                s.orientation.w,
                s.angular_velocity_body.x,
                s.angular_velocity_body.y,
                s.angular_velocity_body.z,
                s.specific_force_body.x,
                s.specific_force_body.y,
                s.specific_force_body.z,
            ],
        );
        let o = &self.origin;
        push(
            &mut bytes,
            &[
                o.latitude_deg,
                o.longitude_deg,
                o.altitude_m,
                self.station_m,
                self.lane_width_m,
            ],
        );
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX).to_le_bytes();
        bytes.extend_from_slice(&count(self.road.len()));
        for point in &self.road {
            push(&mut bytes, &[point.x, point.y, point.station_m]);
        }
        bytes.extend_from_slice(&count(self.obstacles.len()));
        for b in &self.obstacles {
            push(&mut bytes, &[b.x, b.y, b.yaw, b.length, b.width, b.height]);
        }
        bytes
    }

    /// A view from its bytes.
    ///
    /// # Errors
    ///
    /// Bytes that are not a `sim_world` sample: what is wrong with them.
    pub fn decode(bytes: &[u8]) -> Result<WorldView, WorldError> {
        let Some(rest) = bytes.strip_prefix(MAGIC) else {
            return Err(WorldError::NoMagic);
        };
        let mut f = Fields { bytes: rest };
        let time_s = f.f64("time")?;
        let position = f.vec3("position")?;
        let velocity = f.vec3("velocity")?;
        let acceleration = f.vec3("acceleration")?;
        let (yaw, yaw_rate, pitch, pitch_rate) = (
            f.f64("yaw")?,
            f.f64("yaw rate")?,
            f.f64("pitch")?,
            f.f64("pitch rate")?,
        );
        let orientation = DQuat::from_xyzw(
            f.f64("orientation")?,
            f.f64("orientation")?,
            f.f64("orientation")?,
            f.f64("orientation")?,
        );
        let angular_velocity_body = f.vec3("angular velocity")?;
        let specific_force_body = f.vec3("specific force")?;
        let origin = GeoPoint::new(f.f64("origin")?, f.f64("origin")?, f.f64("origin")?);
        let station_m = f.f64("station")?;
        let lane_width_m = f.f64("lane width")?;
        let points = f.count("road points", 3)?;
        let mut road = Vec::with_capacity(points);
        for _ in 0..points {
            road.push(RoadPoint {
                x: f.f64("road")?,
                y: f.f64("road")?,
                station_m: f.f64("road")?,
            });
        }
        let boxes = f.count("obstacles", 6)?;
        let mut obstacles = Vec::with_capacity(boxes);
        for _ in 0..boxes {
            obstacles.push(Obstacle {
                x: f.f64("obstacle")?,
                y: f.f64("obstacle")?,
                yaw: f.f64("obstacle")?,
                length: f.f64("obstacle")?,
                width: f.f64("obstacle")?,
                height: f.f64("obstacle")?,
            });
        }
        Ok(WorldView {
            state: VehicleState {
                time_s,
                position,
                velocity,
                acceleration,
                yaw,
                yaw_rate,
                pitch,
                pitch_rate,
                orientation,
                angular_velocity_body,
                specific_force_body,
            },
            origin,
            station_m,
            lane_width_m,
            road,
            obstacles,
        })
    }

    /// The view as a sample's payload.
    pub fn payload(&self) -> Payload {
        Payload::Custom(CustomPayload {
            type_name: Arc::from(TYPE_NAME),
            data: Arc::from(self.encode()),
        })
    }

    /// The view a payload carries.
    ///
    /// # Errors
    ///
    /// Another type, or bytes that do not decode.
    pub fn from_payload(payload: &Payload) -> Result<WorldView, WorldError> {
        match payload {
            Payload::Custom(custom) if &*custom.type_name == TYPE_NAME => WorldView::decode(&custom.data),
            other => Err(WorldError::NotAWorld(other.data_type())),
        }
    }

    /// Metres left of the vehicle of the road's centre line `ahead` metres ahead, and its station there,
    /// interpolated along the centre line's first stretch going forward; `None` beyond what the view
    /// holds (or where the road turns back).
    pub fn centre_line_at(&self, ahead: f64) -> Option<(f64, f64)> {
        let start = self.road.iter().position(|p| p.x >= 0.0)?.saturating_sub(1);
        let points = self.road.get(start..)?;
        for pair in points.windows(2) {
            let [a, b] = pair else { continue };
            if b.x <= a.x {
                return None;
            }
            if (a.x..=b.x).contains(&ahead) {
                let t = (ahead - a.x) / (b.x - a.x);
                return Some((
                    a.y + (b.y - a.y) * t,
                    a.station_m + (b.station_m - a.station_m) * t,
                ));
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::Trajectory;

    fn view() -> WorldView {
        WorldView {
            state: Trajectory::default().state(20.0),
            origin: GeoPoint::new(48.7, 2.1, 150.0),
            station_m: 123.5,
            lane_width_m: 3.5,
            road: (-5..40)
                .map(|i| RoadPoint {
                    x: f64::from(i) * 2.0,
                    y: 1.75 + 0.001 * f64::from(i * i),
                    station_m: 123.5 + f64::from(i) * 2.0,
                })
                .collect(),
            obstacles: vec![Obstacle {
                x: 30.0,
                y: 3.5,
                yaw: 0.1,
                length: 4.5,
                width: 1.8,
                height: 1.5,
            }],
        }
    }

    #[test]
    fn a_view_survives_its_encoding() {
        let view = view();
        let decoded = WorldView::from_payload(&view.payload()).expect("decodes");
        assert_eq!(decoded, view);
    }

    #[test]
    fn broken_bytes_are_errors_that_say_what_is_missing() {
        let bytes = view().encode();
        for cut in [0, 3, 4, 50, 230, bytes.len() - 1] {
            let error = WorldView::decode(bytes.get(..cut).expect("cut")).expect_err("cut short");
            assert!(error.to_string().contains("sim_world"), "{error}");
        }
        // A count larger than the bytes that follow is refused, not allocated.
        let mut lying = bytes.clone();
        let at = 4 + 29 * 8;
        lying.splice(at..at + 4, u32::MAX.to_le_bytes());
        assert!(
            WorldView::decode(&lying)
                .expect_err("lies")
                .to_string()
                .contains("holds")
        );
        assert!(WorldView::from_payload(&Payload::F64(1.0)).is_err());
    }

    #[test]
    fn the_centre_line_is_interpolated_ahead() {
        let view = view();
        let (y, station) = view.centre_line_at(3.0).expect("ahead");
        let (y2, y4) = (1.75 + 0.001, 1.75 + 0.004);
        assert!((y - 0.5 * (y2 + y4)).abs() < 1e-12);
        assert!((station - 126.5).abs() < 1e-12);
        assert!(view.centre_line_at(500.0).is_none());
    }
}

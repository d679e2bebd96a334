//! WGS84 geodetic coordinates, Earth-centred Earth-fixed (ECEF) and a local east-north-up (ENU) frame,
//! exactly (through ECEF, no small-area approximation): good anywhere on Earth and at any distance from
//! the reference point.

use glam::{DMat3, DVec3};

/// WGS84 semi-major axis, metres.
const A: f64 = 6_378_137.0;
/// WGS84 flattening.
const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared.
const E2: f64 = F * (2.0 - F);

/// A WGS84 position: latitude and longitude in degrees, height above the ellipsoid in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geodetic {
    /// Degrees north.
    pub latitude_deg: f64,
    /// Degrees east.
    pub longitude_deg: f64,
    /// Metres above the ellipsoid.
    pub altitude_m: f64,
}

impl Geodetic {
    /// Whether every field is a number in its range.
    pub fn is_valid(&self) -> bool {
        self.latitude_deg.is_finite()
            && self.longitude_deg.is_finite()
            && self.altitude_m.is_finite()
            && self.latitude_deg.abs() <= 90.0
            && self.longitude_deg.abs() <= 180.0
    }

    /// Earth-centred, Earth-fixed coordinates, metres.
    pub fn to_ecef(&self) -> DVec3 {
        let (lat, lon) = (self.latitude_deg.to_radians(), self.longitude_deg.to_radians());
        let normal = A / (1.0 - E2 * lat.sin().powi(2)).sqrt();
        let h = self.altitude_m;
        DVec3::new(
            (normal + h) * lat.cos() * lon.cos(),
            (normal + h) * lat.cos() * lon.sin(),
            (normal * (1.0 - E2) + h) * lat.sin(),
        )
    }

    /// The geodetic position of ECEF coordinates (Bowring's method refined until it moves less than a
    /// micrometre: two or three steps).
    pub fn from_ecef(ecef: DVec3) -> Geodetic {
        let p = ecef.x.hypot(ecef.y);
        let lon = ecef.y.atan2(ecef.x);
        let mut lat = ecef.z.atan2(p * (1.0 - E2));
        let mut h = 0.0;
        for _ in 0..8 {
            let root = (1.0 - E2 * lat.sin().powi(2)).sqrt();
            let normal = A / root;
            // Exact at every latitude (p / cos φ − N loses digits near the poles).
            h = p * lat.cos() + ecef.z * lat.sin() - A * root;
            let next = ecef.z.atan2(p * (1.0 - E2 * normal / (normal + h)));
            let done = (next - lat).abs() < 1e-13;
            lat = next;
            if done {
                break;
            }
        }
        Geodetic {
            latitude_deg: lat.to_degrees(),
            longitude_deg: lon.to_degrees(),
            altitude_m: h,
        }
    }
}

/// A local east-north-up frame whose origin is a WGS84 point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnuFrame {
    origin: Geodetic,
    origin_ecef: DVec3,
    /// Rows: east, north and up as ECEF directions.
    ecef_to_enu: DMat3,
}

impl EnuFrame {
    /// The frame at `origin`.
    pub fn new(origin: Geodetic) -> Self {
        let (lat, lon) = (
            origin.latitude_deg.to_radians(),
            origin.longitude_deg.to_radians(),
        );
        let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
        let north = DVec3::new(-lat.sin() * lon.cos(), -lat.sin() * lon.sin(), lat.cos());
        let up = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        EnuFrame {
            origin,
            origin_ecef: origin.to_ecef(),
            ecef_to_enu: DMat3::from_cols(east, north, up).transpose(),
        }
    }

    /// The origin.
    pub fn origin(&self) -> Geodetic {
        self.origin
    }

    /// A WGS84 point in this frame: east, north, up in metres.
    pub fn to_enu(&self, point: &Geodetic) -> DVec3 {
        self.ecef_to_enu * (point.to_ecef() - self.origin_ecef)
    }

    /// The WGS84 point at `enu` in this frame.
    pub fn to_geodetic(&self, enu: DVec3) -> Geodetic {
        Geodetic::from_ecef(self.origin_ecef + self.ecef_to_enu.transpose() * enu)
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::{EnuFrame, Geodetic};

    #[test]
    fn enu_round_trips_to_the_micrometre_near_and_far() {
        let origin = Geodetic {
            latitude_deg: 48.7167,
            longitude_deg: 2.2333,
            altitude_m: 150.0,
        };
        let frame = EnuFrame::new(origin);
        for enu in [
            DVec3::ZERO,
            DVec3::new(100.0, -35.0, 6.0),
            DVec3::new(50_000.0, 80_000.0, -120.0),
        ] {
            let back = frame.to_enu(&frame.to_geodetic(enu));
            assert!((back - enu).length() < 1e-6, "{enu} came back as {back}");
        }
        // One degree of latitude north is about 111.2 km at this latitude, straight north.
        let north = Geodetic {
            latitude_deg: 49.7167,
            ..origin
        };
        let enu = frame.to_enu(&north);
        assert!((enu.y - 111_200.0).abs() < 300.0 && enu.x.abs() < 1e-6, "{enu}");
        // The ellipsoid drops away from the tangent plane: the point lies below "up".
        assert!(enu.z < -900.0, "{enu}");
        // Near the poles too.
        let polar = EnuFrame::new(Geodetic {
            latitude_deg: 89.9999,
            longitude_deg: 0.0,
            altitude_m: 0.0,
        });
        let back = polar.to_enu(&polar.to_geodetic(DVec3::new(10.0, 10.0, 10.0)));
        assert!((back - DVec3::new(10.0, 10.0, 10.0)).length() < 1e-6, "{back}");
    }
}

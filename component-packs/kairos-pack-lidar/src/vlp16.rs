//! The Velodyne VLP-16's data packets to points, from the format its user manual specifies.
//!
//! A packet's payload is 1206 bytes: 12 blocks of 100 bytes, then a 4-byte timestamp (µs past the hour)
//! and 2 factory bytes (return mode, product). A block is the flag `FF EE`, the azimuth (u16, hundredths of
//! a degree, little-endian) and 32 measurements — two firing sequences of the 16 lasers — each a distance
//! (u16, 2 mm units; 0: no return) and a reflectivity byte. Lasers fire 2.304 µs apart and a sequence
//! lasts 55.296 µs, so each measurement's azimuth is interpolated between its block's and the next's.
//!
//! Points are in the sensor frame Kairos uses everywhere: x forward (azimuth 0), y left, z up, metres.
//! Each laser's beam starts at its own height, the manual's per-laser vertical correction (±11.2 mm),
//! added to z.
//! The VLP-16's azimuth grows clockwise seen from above.

use glam::Vec3;
use kairos_sdk::PointCloud;

/// The payload of a data packet.
pub const PACKET_BYTES: usize = 1206;
const BLOCKS: usize = 12;
const BLOCK_BYTES: usize = 100;
const LASERS: usize = 16;
/// Vertical angle of each laser, degrees, by laser id (the manual's table).
const ELEVATION_DEG: [f32; LASERS] = [
    -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
];
/// Vertical offset of each laser's origin from the sensor's, metres, by laser id (the manual's
/// "vertical correction", mm): each beam starts that far above (or below) the optical centre.
const VERTICAL_CORRECTION_M: [f32; LASERS] = [
    0.0112, -0.0007, 0.0097, -0.0022, 0.0081, -0.0037, 0.0066, -0.0051, 0.0051, -0.0066, 0.0037, -0.0081,
    0.0022, -0.0097, 0.0007, -0.0112,
];
/// Metres per distance unit.
const DISTANCE_UNIT_M: f32 = 0.002;
/// Timing within a block, µs: between two lasers, and the two sequences' span.
const LASER_US: f32 = 2.304;
const SEQUENCE_US: f32 = 55.296;

/// Why a packet was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    /// Not the size of a data packet.
    #[error("{0} bytes, not the {PACKET_BYTES} of a VLP-16 data packet")]
    WrongSize(usize),
    /// A block without its flag.
    #[error("block {0} does not start with FF EE")]
    BadFlag(usize),
    /// An azimuth beyond 359.99°.
    #[error("block {block} has azimuth {hundredths} (beyond 35999)")]
    BadAzimuth {
        /// The block.
        block: usize,
        /// The value read.
        hundredths: u16,
    },
}

/// Gathers the points of a revolution, packet by packet; a revolution ends where the azimuth wraps.
#[derive(Debug, Default)]
pub struct Decoder {
    points: Vec<Vec3>,
    intensity: Vec<f32>,
    last_azimuth: Option<f32>,
}

/// One block's azimuth in degrees, checked.
fn azimuth_of(block: &[u8], index: usize) -> Result<f32, PacketError> {
    let hundredths = u16::from_le_bytes([block[2], block[3]]);
    if hundredths > 35_999 {
        return Err(PacketError::BadAzimuth {
            block: index,
            hundredths,
        });
    }
    Ok(f32::from(hundredths) / 100.0)
}

impl Decoder {
    /// A decoder at the start of a revolution.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes one packet's payload; `on_revolution` receives each revolution it completes.
    ///
    /// # Errors
    ///
    /// A payload that is not a data packet; nothing of it is kept.
    pub fn packet(
        &mut self,
        payload: &[u8],
        mut on_revolution: impl FnMut(PointCloud),
    ) -> Result<(), PacketError> {
        if payload.len() != PACKET_BYTES {
            return Err(PacketError::WrongSize(payload.len()));
        }
        let blocks: Vec<&[u8]> = payload.chunks_exact(BLOCK_BYTES).take(BLOCKS).collect();
        let mut azimuths = [0.0_f32; BLOCKS];
        for (index, block) in blocks.iter().enumerate() {
            if block[0] != 0xFF || block[1] != 0xEE {
                return Err(PacketError::BadFlag(index));
            }
            azimuths[index] = azimuth_of(block, index)?;
        }
        for (index, block) in blocks.iter().enumerate() {
            let azimuth = azimuths[index];
            // How far the head turns over this block: to the next block's azimuth, or as the last one did.
            let gap = if index + 1 < BLOCKS {
                (azimuths[index + 1] - azimuth).rem_euclid(360.0)
            } else if index > 0 {
                (azimuth - azimuths[index - 1]).rem_euclid(360.0)
            } else {
                0.0
            };
            if self.last_azimuth.is_some_and(|last| azimuth < last) {
                self.finish_revolution(&mut on_revolution);
            }
            self.last_azimuth = Some(azimuth);
            for (measurement, bytes) in block[4..].chunks_exact(3).enumerate() {
                let distance = f32::from(u16::from_le_bytes([bytes[0], bytes[1]])) * DISTANCE_UNIT_M;
                if distance == 0.0 {
                    continue;
                }
                let (sequence, laser) = (measurement / LASERS, measurement % LASERS);
                let elapsed = sequence as f32 * SEQUENCE_US + laser as f32 * LASER_US;
                let alpha = (azimuth + gap * elapsed / (2.0 * SEQUENCE_US)).to_radians();
                let omega = ELEVATION_DEG[laser].to_radians();
                let horizontal = distance * omega.cos();
                self.points.push(Vec3::new(
                    horizontal * alpha.cos(),
                    -horizontal * alpha.sin(),
                    distance * omega.sin() + VERTICAL_CORRECTION_M[laser],
                ));
                self.intensity.push(f32::from(bytes[2]) / 255.0);
            }
        }
        Ok(())
    }

    fn finish_revolution(&mut self, on_revolution: &mut impl FnMut(PointCloud)) {
        if self.points.is_empty() {
            return;
        }
        on_revolution(PointCloud {
            points: std::mem::take(&mut self.points),
            intensity: Some(std::mem::take(&mut self.intensity)),
        });
    }

    /// Ends the stream: the revolution begun, if any points were gathered.
    pub fn finish(&mut self) -> Option<PointCloud> {
        let mut last = None;
        self.finish_revolution(&mut |cloud| last = Some(cloud));
        self.last_azimuth = None;
        last
    }
}

/// A data packet's payload with the given blocks: azimuth (hundredths of a degree) and 32 (distance units,
/// reflectivity) each; for tests, simulators and tools that write captures.
pub fn encode_packet(blocks: &[(u16, [(u16, u8); 32]); BLOCKS], timestamp_us: u32) -> Vec<u8> {
    let mut payload = Vec::with_capacity(PACKET_BYTES);
    for (azimuth, measurements) in blocks {
        payload.extend_from_slice(&[0xFF, 0xEE]);
        payload.extend_from_slice(&azimuth.to_le_bytes());
        for (distance, reflectivity) in measurements {
            payload.extend_from_slice(&distance.to_le_bytes());
            payload.push(*reflectivity);
        }
    }
    payload.extend_from_slice(&timestamp_us.to_le_bytes());
    // Strongest return, VLP-16.
    payload.extend_from_slice(&[0x37, 0x22]);
    payload
}

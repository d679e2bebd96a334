//! Velodyne data packets to points, from the format the sensors' manuals specify: the VLP-16, the
//! VLP-32C and the HDL-32E.
//!
//! A packet's payload is 1206 bytes: 12 blocks of 100 bytes, then a 4-byte timestamp (µs past the hour)
//! and 2 factory bytes (return mode, product id: 0x22 VLP-16, 0x28 VLP-32C, 0x21 HDL-32E). A block is the
//! flag `FF EE`, the azimuth (u16, hundredths of a degree, little-endian) and 32 measurements, each a
//! distance (u16; 2 mm units, 4 mm on the VLP-32C; 0: no return) and a reflectivity byte.
//!
//! - **VLP-16**: a block holds two firing sequences of the 16 lasers, fired 2.304 µs apart in a sequence
//!   of 55.296 µs.
//! - **VLP-32C**: a block holds one sequence of the 32 lasers, fired two at a time every 2.304 µs, in
//!   55.296 µs; each laser also looks a little aside of the block's azimuth (±1.4° or ±4.2°).
//! - **HDL-32E**: a block holds one sequence of the 32 lasers, fired 1.152 µs apart, in 46.08 µs.
//!
//! Each measurement's azimuth is interpolated between its block's and the next's by its firing time.
//! Points are in the sensor frame Kairos uses everywhere: x forward (azimuth 0), y left, z up, metres;
//! the azimuth grows clockwise seen from above. Each laser's beam starts at its own height (its vertical
//! offset), added to z: for the VLP-16 the manual's "vertical correction" table (±11.2 mm); the VLP-32C's
//! and HDL-32E's manuals give none, so theirs are Velodyne's own calibration values as the
//! `VeloView` calibration files carry them (the VLP-32C's up to 19.8 mm, the HDL-32E's up to 17.2 mm).
//! `tests/cli.rs` compares every model with velodyne-decoder on packets it generates.

use glam::Vec3;
use kairos_sdk::PointCloud;

/// The payload of a data packet.
pub const PACKET_BYTES: usize = 1206;
const BLOCKS: usize = 12;
const BLOCK_BYTES: usize = 100;
const MEASUREMENTS: usize = 32;

/// A Velodyne sensor whose packets this module decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Model {
    /// VLP-16 (Puck): 16 lasers, ±15°.
    Vlp16,
    /// VLP-32C (Ultra Puck): 32 lasers, −25° to +15°.
    Vlp32c,
    /// HDL-32E: 32 lasers, −30.67° to +10.67°.
    Hdl32e,
}

/// What differs between models: their lasers and their timing.
struct Spec {
    product_id: u8,
    /// Elevation of each laser, degrees, by laser id (the manual's table).
    elevation_deg: &'static [f32],
    /// How far aside of the block's azimuth each laser looks, degrees, clockwise (VLP-32C only).
    azimuth_offset_deg: &'static [f32],
    /// Height of each laser's origin above the sensor's, millimetres.
    vertical_offset_mm: &'static [f32],
    distance_unit_m: f32,
    /// When measurement `m` of a block fires after the block's first, µs, and by which laser.
    firing: fn(usize) -> (usize, f32),
    /// The span of a block's firings, µs: the azimuth moves from one block's to the next's in it.
    block_us: f32,
}

const VLP16: Spec = Spec {
    product_id: 0x22,
    elevation_deg: &[
        -15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0,
    ],
    azimuth_offset_deg: &[0.0; 16],
    vertical_offset_mm: &[
        11.2, -0.7, 9.7, -2.2, 8.1, -3.7, 6.6, -5.1, 5.1, -6.6, 3.7, -8.1, 2.2, -9.7, 0.7, -11.2,
    ],
    distance_unit_m: 0.002,
    firing: |m| (m % 16, (m / 16) as f32 * 55.296 + (m % 16) as f32 * 2.304),
    block_us: 2.0 * 55.296,
};

const VLP32C: Spec = Spec {
    product_id: 0x28,
    elevation_deg: &[
        -25.0, -1.0, -1.667, -15.639, -11.31, 0.0, -0.667, -8.843, -7.254, 0.333, -0.333, -6.148, -5.333,
        1.333, 0.667, -4.0, -4.667, 1.667, 1.0, -3.667, -3.333, 3.333, 2.333, -2.667, -3.0, 7.0, 4.667,
        -2.333, -2.0, 15.0, 10.333, -1.333,
    ],
    azimuth_offset_deg: &[
        1.4, -4.2, 1.4, -1.4, 1.4, -1.4, 4.2, -1.4, 1.4, -4.2, 1.4, -1.4, 4.2, -1.4, 4.2, -1.4, 1.4, -4.2,
        1.4, -4.2, 4.2, -1.4, 1.4, -1.4, 1.4, -1.4, 1.4, -4.2, 4.2, -1.4, 1.4, -1.4,
    ],
    vertical_offset_mm: &[
        19.77, 0.74, 1.23, 11.87, 8.48, 0.0, 0.49, 6.6, 5.4, -0.25, 0.25, 4.57, 3.96, -0.99, -0.49, 2.96,
        3.46, -1.23, -0.74, 2.72, 2.47, -2.47, -1.73, 1.98, 2.22, -5.21, -3.46, 1.73, 1.48, -11.36, -7.73,
        0.99,
    ],
    distance_unit_m: 0.004,
    firing: |m| (m, (m / 2) as f32 * 2.304),
    block_us: 55.296,
};

const HDL32E: Spec = Spec {
    product_id: 0x21,
    elevation_deg: &[
        -30.67, -9.33, -29.33, -8.0, -28.0, -6.67, -26.67, -5.33, -25.33, -4.0, -24.0, -2.67, -22.67, -1.33,
        -21.33, 0.0, -20.0, 1.33, -18.67, 2.67, -17.33, 4.0, -16.0, 5.33, -14.67, 6.67, -13.33, 8.0, -12.0,
        9.33, -10.67, 10.67,
    ],
    azimuth_offset_deg: &[0.0; 32],
    vertical_offset_mm: &[
        17.17, 4.76, 16.27, 4.07, 15.4, 3.38, 14.54, 2.7, 13.71, 2.02, 12.89, 1.35, 12.09, 0.67, 11.31, 0.0,
        10.54, -0.67, 9.78, -1.35, 9.04, -2.02, 8.3, -2.7, 7.58, -3.38, 6.86, -4.07, 6.15, -4.76, 5.45,
        -5.45,
    ],
    distance_unit_m: 0.002,
    firing: |m| (m, m as f32 * 1.152),
    block_us: 46.08,
};

impl Model {
    /// Every model, in the order the component offers them.
    pub const ALL: [Model; 3] = [Model::Vlp16, Model::Vlp32c, Model::Hdl32e];

    /// Its name as Velodyne writes it (`VLP-16`).
    pub fn name(self) -> &'static str {
        match self {
            Model::Vlp16 => "VLP-16",
            Model::Vlp32c => "VLP-32C",
            Model::Hdl32e => "HDL-32E",
        }
    }

    /// The model named `name` (as [`Model::name`] writes it).
    pub fn named(name: &str) -> Option<Model> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The model whose packets carry `product_id` in their last byte.
    pub fn of_product(product_id: u8) -> Option<Model> {
        Self::ALL.into_iter().find(|m| m.spec().product_id == product_id)
    }

    /// The product id its packets carry.
    pub fn product_id(self) -> u8 {
        self.spec().product_id
    }

    fn spec(self) -> &'static Spec {
        match self {
            Model::Vlp16 => &VLP16,
            Model::Vlp32c => &VLP32C,
            Model::Hdl32e => &HDL32E,
        }
    }
}

/// Why a packet was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    /// Not the size of a data packet.
    #[error("{0} bytes, not the {PACKET_BYTES} of a Velodyne data packet")]
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
    /// A product id of no model decoded here, while the model is to be read from the packets.
    #[error(
        "product id 0x{0:02X} is not a VLP-16 (0x22), VLP-32C (0x28) or HDL-32E (0x21): set the property model"
    )]
    UnknownModel(u8),
}

/// One laser of the model being decoded, its trigonometry worked out once.
#[derive(Debug, Clone, Copy)]
struct Laser {
    cos_elevation: f32,
    sin_elevation: f32,
    vertical_offset_m: f32,
    azimuth_offset_deg: f32,
}

/// Gathers the points of a revolution, packet by packet; a revolution ends where the azimuth wraps.
#[derive(Debug, Default)]
pub struct Decoder {
    /// The model set by the user; `None` reads it from each packet's product id.
    fixed: Option<Model>,
    /// The model whose lasers are worked out in `lasers`.
    current: Option<Model>,
    lasers: Vec<Laser>,
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
    /// A decoder at the start of a revolution, reading the model from each packet's product id.
    pub fn new() -> Self {
        Self::default()
    }

    /// A decoder for `model`'s packets, whatever their product id says.
    pub fn for_model(model: Model) -> Self {
        Decoder {
            fixed: Some(model),
            ..Self::default()
        }
    }

    /// The model of the packets decoded last, if any.
    pub fn model(&self) -> Option<Model> {
        self.current
    }

    fn use_model(&mut self, model: Model) {
        if self.current == Some(model) {
            return;
        }
        let spec = model.spec();
        self.lasers = spec
            .elevation_deg
            .iter()
            .zip(spec.vertical_offset_mm)
            .zip(spec.azimuth_offset_deg)
            .map(|((elevation, offset), aside)| Laser {
                cos_elevation: elevation.to_radians().cos(),
                sin_elevation: elevation.to_radians().sin(),
                vertical_offset_m: offset / 1000.0,
                azimuth_offset_deg: *aside,
            })
            .collect();
        self.current = Some(model);
    }

    /// Decodes one packet's payload; `on_revolution` receives each revolution it completes.
    ///
    /// # Errors
    ///
    /// A payload that is not a data packet of a known model; nothing of it is kept.
    pub fn packet(
        &mut self,
        payload: &[u8],
        mut on_revolution: impl FnMut(PointCloud),
    ) -> Result<(), PacketError> {
        if payload.len() != PACKET_BYTES {
            return Err(PacketError::WrongSize(payload.len()));
        }
        let model = if let Some(model) = self.fixed {
            model
        } else {
            let product = payload[PACKET_BYTES - 1];
            Model::of_product(product).ok_or(PacketError::UnknownModel(product))?
        };
        let blocks: Vec<&[u8]> = payload.chunks_exact(BLOCK_BYTES).take(BLOCKS).collect();
        let mut azimuths = [0.0_f32; BLOCKS];
        for (index, block) in blocks.iter().enumerate() {
            if block[0] != 0xFF || block[1] != 0xEE {
                return Err(PacketError::BadFlag(index));
            }
            azimuths[index] = azimuth_of(block, index)?;
        }
        self.use_model(model);
        let spec = model.spec();
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
            for (measurement, bytes) in block[4..].chunks_exact(3).take(MEASUREMENTS).enumerate() {
                let units = u16::from_le_bytes([bytes[0], bytes[1]]);
                if units == 0 {
                    continue;
                }
                let distance = f32::from(units) * spec.distance_unit_m;
                let (laser, elapsed_us) = (spec.firing)(measurement);
                let Some(laser) = self.lasers.get(laser) else {
                    continue;
                };
                let alpha =
                    (azimuth + gap * elapsed_us / spec.block_us + laser.azimuth_offset_deg).to_radians();
                let horizontal = distance * laser.cos_elevation;
                let (sin_alpha, cos_alpha) = alpha.sin_cos();
                self.points.push(Vec3::new(
                    horizontal * cos_alpha,
                    -horizontal * sin_alpha,
                    distance * laser.sin_elevation + laser.vertical_offset_m,
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

/// A data packet's payload of `model` with the given blocks: azimuth (hundredths of a degree) and 32
/// (distance units, reflectivity) each; for tests, simulators and tools that write captures.
pub fn encode_packet(model: Model, blocks: &[(u16, [(u16, u8); 32]); BLOCKS], timestamp_us: u32) -> Vec<u8> {
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
    // Strongest return, then the model.
    payload.extend_from_slice(&[0x37, model.product_id()]);
    payload
}

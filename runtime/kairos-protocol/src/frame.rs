//! Binary sample frames: one sample of a subscribed output per WebSocket binary message.
//!
//! Layout: the 4 bytes `KSF1`, the header's length (u32, little-endian), the header (JSON, a
//! [`SampleHeader`]), then the payload's bytes. Small payloads (numbers, text, IMU, GNSS, poses, CAN frames)
//! travel in the header's `value`, with no bytes after it; images carry their pixels (rows of `stride`
//! bytes), point clouds their points (x, y, z and, with `intensity`, a fourth f32, little-endian), raw and
//! pack-defined data their bytes.

use serde::{Deserialize, Serialize};

/// The first bytes of every frame.
pub const MAGIC: &[u8; 4] = b"KSF1";

/// An image's layout in a frame.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ImageLayout {
    /// Width in pixels (after any downscaling).
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `gray8`, `gray16`, `rgb8`, `rgba8`, `bgr8` or `bgra8`.
    pub format: String,
    /// Bytes per row.
    pub stride: u32,
    /// The width the runtime produced, when the image was downscaled to fit the subscription.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub original_width: Option<u32>,
    /// Set instead of pixel bytes after the header, in frames published through shared memory for a
    /// subscription with `shared_pixels`: where the pixels lie in the runtime's memory.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shared: Option<crate::shared_pixels::PixelsReference>,
}

/// What describes the payload in a frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleHeader {
    /// The output (`camera.image`).
    pub output: String,
    /// The payload's data type (`image`, `f64`, ...).
    pub data_type: String,
    /// The sample's timestamp, ns since the UNIX epoch.
    pub timestamp_ns: i64,
    /// Its time of issue.
    pub time_of_issue_ns: i64,
    /// Its sequence number on the output.
    pub sequence: u64,
    /// Samples of this output the client did not get since the previous frame (rate limit, slow client).
    pub skipped: u64,
    /// Small payloads, as JSON.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<serde_json::Value>,
    /// For images: how to read the bytes after the header.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image: Option<ImageLayout>,
    /// For point clouds: whether each point has a fourth value, its intensity.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub intensity: bool,
}

/// Why bytes are not a frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Too short or not starting with [`MAGIC`].
    #[error("not a sample frame (it must start with KSF1 and a header length)")]
    NotAFrame,
    /// The header length points past the end.
    #[error("the header length {0} runs past the end of the frame")]
    Truncated(usize),
    /// The header is not the JSON of a [`SampleHeader`].
    #[error("the frame header is not valid: {0}")]
    BadHeader(String),
}

/// Encodes a frame.
pub fn encode(header: &SampleHeader, payload: &[u8]) -> Vec<u8> {
    let json = serde_json::to_vec(header).unwrap_or_default();
    let mut frame = Vec::with_capacity(8 + json.len() + payload.len());
    frame.extend_from_slice(MAGIC);
    frame.extend_from_slice(&u32::try_from(json.len()).unwrap_or(u32::MAX).to_le_bytes());
    frame.extend_from_slice(&json);
    frame.extend_from_slice(payload);
    frame
}

/// Decodes a frame into its header and payload bytes.
pub fn decode(frame: &[u8]) -> Result<(SampleHeader, &[u8]), FrameError> {
    if frame.get(..4) != Some(MAGIC.as_slice()) {
        return Err(FrameError::NotAFrame);
    }
    let length_bytes: [u8; 4] = frame
        .get(4..8)
        .and_then(|b| b.try_into().ok())
        .ok_or(FrameError::NotAFrame)?;
    let length = u32::from_le_bytes(length_bytes) as usize;
    let json = frame.get(8..8 + length).ok_or(FrameError::Truncated(length))?;
    let header = serde_json::from_slice(json).map_err(|e| FrameError::BadHeader(e.to_string()))?;
    Ok((header, frame.get(8 + length..).unwrap_or_default()))
}

#[cfg(test)]
mod tests {
    use super::{FrameError, ImageLayout, SampleHeader, decode, encode};

    #[test]
    fn a_frame_decodes_to_what_was_encoded() {
        let header = SampleHeader {
            output: "camera.image".to_owned(),
            data_type: "image".to_owned(),
            timestamp_ns: 5,
            time_of_issue_ns: 7,
            sequence: 3,
            skipped: 1,
            value: None,
            image: Some(ImageLayout {
                width: 2,
                height: 1,
                format: "rgb8".to_owned(),
                stride: 6,
                original_width: Some(4),
                shared: Some(crate::shared_pixels::PixelsReference {
                    pid: 4711,
                    fd: 23,
                    id: 5,
                    generation: 8,
                    len: 6,
                }),
            }),
            intensity: false,
        };
        let pixels = [1_u8, 2, 3, 4, 5, 6];
        let frame = encode(&header, &pixels);
        let (decoded, payload) = decode(&frame).unwrap();
        assert_eq!(decoded, header);
        assert_eq!(payload, pixels);
    }

    #[test]
    fn broken_frames_are_errors() {
        assert_eq!(decode(b"KSF").unwrap_err(), FrameError::NotAFrame);
        assert_eq!(decode(b"XXXX\0\0\0\0").unwrap_err(), FrameError::NotAFrame);
        assert_eq!(
            decode(b"KSF1\xff\0\0\0{}").unwrap_err(),
            FrameError::Truncated(255)
        );
        assert!(matches!(
            decode(b"KSF1\x02\0\0\0{}").unwrap_err(),
            FrameError::BadHeader(_)
        ));
    }
}

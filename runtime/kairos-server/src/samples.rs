//! Samples into binary frames for subscribed clients (see `kairos_protocol::frame`).

use std::borrow::Cow;
use std::sync::Arc;

use kairos_protocol::frame::{self, ImageLayout};
use kairos_sample_frame as sample_frame;
use kairos_sdk_core::host::{Reader, ReaderConfig};
use kairos_sdk_core::{Image, Payload, ReaderPolicy, RunSignal, Sample};

use super::runtime::Runtime;

/// The newest samples of one output for one client, whatever transport carries them: a LastOrNext reader
/// on the output's buffer (it never slows the writer; what the client does not take is skipped, not
/// queued), attached again whenever a new diagram is deployed.
pub struct LatestSamples {
    runtime: Arc<Runtime>,
    output: String,
    /// Who reads, for the link's name in statistics (`client 127.0.0.1:5000`).
    client: String,
    reader: Option<(Reader, u64)>,
    skipped_before: u64,
}

impl LatestSamples {
    /// Follows `output` (`component.port`) of whatever `runtime` has deployed.
    pub fn new(runtime: Arc<Runtime>, output: String, client: String) -> Self {
        LatestSamples {
            runtime,
            output,
            client,
            reader: None,
            skipped_before: 0,
        }
    }

    /// The newest sample not taken yet, with how many samples were passed over since the previous one.
    pub fn next(&mut self) -> Option<(Sample, u64)> {
        let generation = self.runtime.generation();
        if self.reader.as_ref().is_none_or(|(_, g)| *g != generation) {
            self.reader = self.output.rsplit_once('.').and_then(|(component, port)| {
                let (buffer, generation) = self.runtime.output(component, port)?;
                let config = ReaderConfig::new(
                    ReaderPolicy::LastOrNext,
                    format!("{} -> {}", self.output, self.client),
                );
                Some((buffer.attach(config, Arc::new(RunSignal::new())), generation))
            });
            self.skipped_before = 0;
        }
        let (reader, _) = self.reader.as_mut()?;
        let sample = reader.try_read()?;
        let skipped_now = reader.counters().skipped;
        let skipped = skipped_now.saturating_sub(self.skipped_before);
        self.skipped_before = skipped_now;
        Some((sample, skipped))
    }
}

/// The image's pixels, packed, keeping one pixel in `factor` along both axes.
fn downscale(image: &Image, factor: u32) -> (u32, u32, Vec<u8>) {
    let pixel = image.format.bytes_per_pixel() as usize;
    let source = &image.pixels[..];
    let width = image.width.div_ceil(factor);
    let height = image.height.div_ceil(factor);
    let mut pixels = Vec::with_capacity(width as usize * height as usize * pixel);
    for y in (0..image.height).step_by(factor as usize) {
        let row = y as usize * image.stride as usize;
        for x in (0..image.width).step_by(factor as usize) {
            let at = row + x as usize * pixel;
            pixels.extend_from_slice(source.get(at..at + pixel).unwrap_or(&[0; 8][..pixel]));
        }
    }
    (width, height, pixels)
}

/// Encodes `sample` of `output` as a frame; images wider than `max_image_width` are downscaled.
pub fn encode(output: &str, sample: &Sample, skipped: u64, max_image_width: Option<u32>) -> Vec<u8> {
    let (head, body) = encode_parts(output, sample, skipped, max_image_width, PixelsIn::Frame);
    let mut frame = Vec::with_capacity(head.len() + body.len());
    frame.extend_from_slice(&head);
    frame.extend_from_slice(&body);
    frame
}

/// How a frame carries an image's pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelsIn {
    /// After the header, always.
    Frame,
    /// As a reference in the header when they lie in shared memory (and are not downscaled), for a client
    /// on this machine that maps the runtime's buffers; after the header otherwise.
    SharedMemory,
}

/// A frame in two parts: its start (magic, header length, header) and its payload bytes, borrowed from the
/// sample where they can be (an image's pixels), so a transport copies them once, where they go; with
/// [`PixelsIn::SharedMemory`], pixels already in shared memory are not copied at all.
pub fn encode_parts<'s>(
    output: &str,
    sample: &'s Sample,
    skipped: u64,
    max_image_width: Option<u32>,
    pixels_in: PixelsIn,
) -> (Vec<u8>, Cow<'s, [u8]>) {
    let mut header = sample_frame::header_of(output, sample, skipped);
    let body: Cow<'s, [u8]> = match &sample.payload {
        Payload::Image(image) => {
            let factor = max_image_width
                .filter(|max| *max > 0 && image.width > *max)
                .map_or(1, |max| image.width.div_ceil(max));
            let shared = (factor == 1 && pixels_in == PixelsIn::SharedMemory)
                .then(|| image.pixels.shared_reference())
                .flatten();
            let (width, height, pixels) = if factor > 1 {
                let (width, height, pixels) = downscale(image, factor);
                (width, height, Cow::Owned(pixels))
            } else if shared.is_some() {
                (image.width, image.height, Cow::Borrowed(&[][..]))
            } else {
                (image.width, image.height, Cow::Borrowed(&image.pixels[..]))
            };
            header.image = Some(ImageLayout {
                width,
                height,
                format: sample_frame::format_name(image.format).to_owned(),
                stride: if factor > 1 {
                    width * image.format.bytes_per_pixel()
                } else {
                    image.stride
                },
                original_width: (factor > 1).then_some(image.width),
                shared,
            });
            pixels
        }
        Payload::PointCloud(cloud) => Cow::Owned(sample_frame::point_bytes(cloud)),
        Payload::Bytes(bytes) => Cow::Borrowed(&bytes[..]),
        Payload::Custom(custom) => Cow::Borrowed(&custom.data[..]),
        _ => Cow::Borrowed(&[]),
    };
    (frame::encode(&header, &[]), body)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use kairos_protocol::frame;
    use kairos_sdk_core::{Image, Payload, PixelFormat, Sample, Timestamp};

    use super::{PixelsIn, encode, encode_parts};

    #[test]
    fn wide_images_are_downscaled_by_a_whole_factor() {
        let pixels: Vec<u8> = (0..8 * 4 * 3).map(|i| i as u8).collect();
        let image = Image::packed(8, 4, PixelFormat::Rgb8, Arc::<[u8]>::from(pixels)).unwrap();
        let sample = Sample::new(Payload::Image(image), Timestamp(9));
        let bytes = encode("camera.image", &sample, 0, Some(4));
        let (header, body) = frame::decode(&bytes).unwrap();
        let layout = header.image.unwrap();
        assert_eq!((layout.width, layout.height, layout.stride), (4, 2, 12));
        assert_eq!(layout.original_width, Some(8));
        assert_eq!(body.len(), 4 * 2 * 3);
        // Row 0, pixel 2 of the downscaled image is pixel 4 of row 0 of the original.
        assert_eq!(&body[6..9], &[12, 13, 14]);
    }

    #[test]
    fn shared_pixels_travel_as_a_reference_only_when_asked_and_not_downscaled() {
        let len = 640 * 480 * 3;
        let mut pixels = kairos_sdk_core::PixelsMut::new(len);
        pixels.fill(4);
        let image = Image::packed(640, 480, PixelFormat::Rgb8, pixels.freeze()).unwrap();
        let Some(reference) = image.pixels.shared_reference() else {
            return; // no shared memory on this system
        };
        let sample = Sample::new(Payload::Image(image), Timestamp(9));
        let (head, body) = encode_parts("camera.image", &sample, 0, None, PixelsIn::SharedMemory);
        let (header, _) = frame::decode(&head).unwrap();
        assert_eq!(header.image.unwrap().shared, Some(reference));
        assert!(body.is_empty());
        let (head, body) = encode_parts("camera.image", &sample, 0, None, PixelsIn::Frame);
        assert!(frame::decode(&head).unwrap().0.image.unwrap().shared.is_none());
        assert_eq!(body.len(), len);
        let (head, body) = encode_parts("camera.image", &sample, 0, Some(320), PixelsIn::SharedMemory);
        assert!(frame::decode(&head).unwrap().0.image.unwrap().shared.is_none());
        assert_eq!(body.len(), len / 4);
    }

    #[test]
    fn scalars_travel_in_the_header() {
        let bytes = encode("sine.out", &Sample::new(Payload::F64(0.5), Timestamp(1)), 3, None);
        let (header, body) = frame::decode(&bytes).unwrap();
        assert_eq!(header.value, Some(serde_json::json!(0.5)));
        assert_eq!((header.skipped, header.data_type.as_str()), (3, "f64"));
        assert!(body.is_empty());
    }
}

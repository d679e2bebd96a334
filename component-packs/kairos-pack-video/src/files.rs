//! Images from and to files: `video.image_sequence` plays a folder of PNG/JPEG files as a camera would,
//! `video.image_writer` writes one file per sample.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Image, Payload,
    PixelFormat, PixelsMut, ReaderPolicy, Timestamp, TypeFilter, Value,
};

/// The file names the sequence plays, by extension (lower case).
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The descriptor of `video.image_sequence`.
pub fn sequence_descriptor() -> ComponentInfo {
    Descriptor::new(
        "video.image_sequence",
        "video",
        "Plays a folder of PNG/JPEG images in name order, as a camera would: at a fixed rate, at the times \
         of a CSV beside them, or at the times in their names; once or in a loop",
    )
    .label("Image sequence (folder)")
    .output(
        "image",
        DataType::Image,
        "Each image (RGB, RGBA or grey as in the file)",
    )
    .property(Property::path("folder", "images").doc("The folder of images (.png, .jpg, .jpeg)"))
    .property(Property::choice("timing", &["rate", "csv", "names"], "rate").doc(
        "rate: a fixed rate; csv: a file of `name,seconds` lines; names: the number in each file \
             name, in name_unit",
    ))
    .property(
        Property::f64("rate", 10.0)
            .unit("Hz")
            .range(0.001, 1000.0)
            .live()
            .doc("Images per second, with timing = rate"),
    )
    .property(
        Property::path("csv", "")
            .doc("With timing = csv: lines `file name,time in seconds` (a header line is skipped)"),
    )
    .property(
        Property::choice("name_unit", &["ns", "us", "ms", "s"], "ns")
            .doc("With timing = names: the unit of the number in the file names"),
    )
    .property(Property::bool("loop", false).doc("Start again after the last image"))
    .property(
        Property::f64("speed", 1.0)
            .range(0.01, 100.0)
            .live()
            .doc("Replay speed with timing = csv or names (2: twice as fast)"),
    )
    .build()
}

/// One image of the sequence and its time from the first, in seconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// The file.
    pub path: PathBuf,
    /// Seconds after the first frame (for `rate` timing, filled in from the rate when played).
    pub offset_s: Option<f64>,
}

/// Why a folder of images cannot be replayed as a sequence; each names the file and, where it can, the fix.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// The folder is missing or not readable.
    #[error("cannot read the folder {}: {source}", .folder.display())]
    Folder { folder: PathBuf, source: std::io::Error },
    /// Nothing in it to replay.
    #[error("the folder {} holds no image (.png, .jpg, .jpeg)", .0.display())]
    NoImage(PathBuf),
    /// `timing: csv` names no file.
    #[error("timing is csv but no csv file is given: set the property csv")]
    NoCsv,
    /// The CSV file is missing or not readable.
    #[error("cannot read {}: {source}", .csv.display())]
    Csv { csv: PathBuf, source: std::io::Error },
    /// A line of the CSV that is not `name,seconds`.
    #[error("{}:{line}: expected `file name,time in seconds`, found {found:?}", .csv.display())]
    CsvLine {
        csv: PathBuf,
        line: usize,
        found: String,
    },
    /// An image the CSV gives no time for.
    #[error("{} gives no time for {name}", .csv.display())]
    NoTime { csv: PathBuf, name: String },
    /// `timing: names` and a file name without digits.
    #[error("{} has no number in its name to take its time from", .0.display())]
    NoNumber(PathBuf),
}

/// Why an image file is not an image sample.
#[derive(Debug, thiserror::Error)]
pub enum ImageFileError {
    /// Not readable, or not an image the decoder knows.
    #[error("cannot read the image {}: {source}", .path.display())]
    Decode {
        path: PathBuf,
        source: image::ImageError,
    },
    /// Decoded, but its size does not fit its pixels.
    #[error("{}: {source}", .path.display())]
    Size {
        path: PathBuf,
        source: kairos_sdk::payload::ImageSizeError,
    },
}

/// The images of `folder`, in name order, with their times for `timing`.
///
/// # Errors
///
/// The folder or the CSV cannot be read, holds no image, or a time cannot be found; the message says
/// which file and line.
pub fn frames(folder: &Path, timing: &str, csv: &Path, name_unit: &str) -> Result<Vec<Frame>, SequenceError> {
    let entries = std::fs::read_dir(folder).map_err(|source| SequenceError::Folder {
        folder: folder.to_owned(),
        source,
    })?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| {
            path.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(SequenceError::NoImage(folder.to_owned()));
    }
    let times: Vec<Option<f64>> = match timing {
        "csv" => {
            let table = csv_times(csv)?;
            paths
                .iter()
                .map(|path| {
                    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
                    table
                        .get(name)
                        .copied()
                        .map(Some)
                        .ok_or_else(|| SequenceError::NoTime {
                            csv: csv.to_owned(),
                            name: name.to_owned(),
                        })
                })
                .collect::<Result<_, _>>()?
        }
        "names" => {
            let scale = match name_unit {
                "s" => 1.0,
                "ms" => 1e-3,
                "us" => 1e-6,
                _ => 1e-9,
            };
            paths
                .iter()
                .map(|path| {
                    let stem = path.file_stem().and_then(|n| n.to_str()).unwrap_or_default();
                    let digits: String = stem
                        .chars()
                        .skip_while(|c| !c.is_ascii_digit())
                        .take_while(char::is_ascii_digit)
                        .collect();
                    digits
                        .parse::<u64>()
                        .map(|n| Some(n as f64 * scale))
                        .map_err(|_| SequenceError::NoNumber(path.clone()))
                })
                .collect::<Result<_, _>>()?
        }
        _ => vec![None; paths.len()],
    };
    let first = times.iter().flatten().copied().fold(f64::INFINITY, f64::min);
    Ok(paths
        .into_iter()
        .zip(times)
        .map(|(path, time)| Frame {
            path,
            offset_s: time.map(|t| t - first),
        })
        .collect())
}

/// `name,seconds` lines of a CSV; a first line that does not parse is a header.
fn csv_times(csv: &Path) -> Result<BTreeMap<String, f64>, SequenceError> {
    if csv.as_os_str().is_empty() {
        return Err(SequenceError::NoCsv);
    }
    let text = std::fs::read_to_string(csv).map_err(|source| SequenceError::Csv {
        csv: csv.to_owned(),
        source,
    })?;
    let mut table = BTreeMap::new();
    for (index, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let parsed = line
            .split_once(',')
            .and_then(|(name, time)| Some((name.trim().to_owned(), time.trim().parse::<f64>().ok()?)));
        match parsed {
            Some((name, time)) if time.is_finite() => {
                table.insert(name, time);
            }
            _ if index == 0 => {}
            _ => {
                return Err(SequenceError::CsvLine {
                    csv: csv.to_owned(),
                    line: index + 1,
                    found: line.to_owned(),
                });
            }
        }
    }
    Ok(table)
}

/// An image file as an image sample: grey (8 or 16 bits), RGB or RGBA as in the file (16-bit colour is
/// cut to 8 bits).
///
/// # Errors
///
/// The file cannot be read or decoded.
pub fn load(path: &Path) -> Result<Image, ImageFileError> {
    let decoded = image::open(path).map_err(|source| ImageFileError::Decode {
        path: path.to_owned(),
        source,
    })?;
    let (width, height) = (decoded.width(), decoded.height());
    let (format, bytes) = match decoded {
        image::DynamicImage::ImageLuma8(grey) => (PixelFormat::Gray8, grey.into_raw()),
        image::DynamicImage::ImageRgb8(rgb) => (PixelFormat::Rgb8, rgb.into_raw()),
        image::DynamicImage::ImageRgba8(rgba) => (PixelFormat::Rgba8, rgba.into_raw()),
        // A depth camera's millimetres: kept whole, little-endian as Kairos' images hold them.
        image::DynamicImage::ImageLuma16(grey) => (
            PixelFormat::Gray16,
            grey.into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        ),
        // Alpha kept where the file has it; everything else (16 bits, float) to 8-bit RGB.
        other if other.color().has_alpha() => (PixelFormat::Rgba8, other.into_rgba8().into_raw()),
        other => (PixelFormat::Rgb8, other.into_rgb8().into_raw()),
    };
    let mut pixels = PixelsMut::new(bytes.len());
    pixels.copy_from_slice(&bytes);
    Image::packed(width, height, format, pixels.freeze()).map_err(|source| ImageFileError::Size {
        path: path.to_owned(),
        source,
    })
}

/// `video.image_sequence`. See [`sequence_descriptor`].
#[derive(Debug, Default)]
pub struct ImageSequence {
    frames: Vec<Frame>,
    next: usize,
    /// The clock time the current pass started at.
    started: Option<Timestamp>,
    /// Where the last image was due, for `rate` timing.
    last_due: Option<Timestamp>,
    looping: bool,
    timing: String,
    /// The next frame, decoded ahead of its time.
    ready: Option<(usize, Image)>,
}

impl Component for ImageSequence {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.timing = ctx.text_property("timing")?;
        self.frames = frames(
            Path::new(&ctx.text_property("folder")?),
            &self.timing,
            Path::new(&ctx.text_property("csv")?),
            &ctx.text_property("name_unit")?,
        )
        .map_err(ComponentError::failed)?;
        self.looping = ctx.bool_property("loop")?;
        tracing::info!("{} images to play", self.frames.len());
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.next >= self.frames.len() {
            if !self.looping {
                return Err(ComponentError::EndOfStream);
            }
            self.next = 0;
            // The next pass starts one mean interval after the last image, as the next image would.
            let intervals = self.frames.len().saturating_sub(1).max(1) as f64;
            let span = self.frames.last().and_then(|f| f.offset_s).unwrap_or(0.0);
            let speed = ctx.f64_property("speed")?;
            #[allow(clippy::cast_possible_truncation, reason = "nanoseconds of a replay")]
            let gap = (span / intervals / speed * 1e9).round() as i64;
            self.started = self.last_due.map(|last| Timestamp(last.0 + gap));
        }
        let Some(frame) = self.frames.get(self.next) else {
            return Err(ComponentError::EndOfStream);
        };
        // Decoded before its time comes, so that it goes out on time.
        if self.ready.as_ref().is_none_or(|(index, _)| *index != self.next) {
            self.ready = Some((self.next, load(&frame.path).map_err(ComponentError::failed)?));
        }
        let now = ctx.now();
        let started = *self.started.get_or_insert(now);
        let due = if let Some(offset) = frame.offset_s {
            let speed = ctx.f64_property("speed")?;
            #[allow(clippy::cast_possible_truncation, reason = "nanoseconds of a replay")]
            Timestamp(started.0 + (offset / speed * 1e9).round() as i64)
        } else {
            let period = 1e9 / ctx.f64_property("rate")?;
            #[allow(clippy::cast_possible_truncation, reason = "nanoseconds of a period")]
            self.last_due
                .map_or(now, |last| Timestamp(last.0 + period.round() as i64))
        };
        // A control request interrupts the wait: the frame is played on the next call.
        ctx.wait_until(due)?;
        let Some((_, image)) = self.ready.take() else {
            return Ok(());
        };
        self.next += 1;
        self.last_due = Some(due);
        ctx.write_at("image", Payload::Image(image), due)
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `video.image_writer`.
pub fn writer_descriptor() -> ComponentInfo {
    Descriptor::new(
        "video.image_writer",
        "video",
        "Writes each image it receives to a PNG or JPEG file named by its timestamp (ns) and sequence \
         number, so that an image sequence with timing = names plays them back at their times",
    )
    .label("Image writer (files)")
    .input_with_policy(
        "image",
        TypeFilter::OneOf(vec![DataType::Image]),
        ReaderPolicy::NeverSkipping,
        "The images to write",
    )
    .property(Property::path("folder", "frames").doc("Where to write (created if missing)"))
    .property(Property::choice("format", &["png", "jpeg"], "png").doc("The file format"))
    .property(
        Property::i64("quality", 90)
            .int_range(1, 100)
            .live()
            .doc("JPEG quality"),
    )
    .build()
}

/// `video.image_writer`. See [`writer_descriptor`].
#[derive(Debug, Default)]
pub struct ImageWriter {
    folder: PathBuf,
    written: u64,
}

/// Why an image sample cannot be written as a file: its pixels are fewer than its size says.
#[derive(Debug, thiserror::Error)]
#[error("the image's pixels are shorter than its size")]
struct PixelsShort;

/// `image` as the `image` crate's buffer, 8 bits per channel, without row padding.
fn to_dynamic(image: &Image) -> Result<image::DynamicImage, PixelsShort> {
    let bpp = image.format.bytes_per_pixel() as usize;
    let (w, h) = (image.width as usize, image.height as usize);
    let mut packed = Vec::with_capacity(w * h * bpp);
    for row in 0..h {
        let start = row * image.stride as usize;
        packed.extend_from_slice(image.pixels.get(start..start + w * bpp).unwrap_or_default());
    }
    Ok(match image.format {
        PixelFormat::Gray8 => image::GrayImage::from_raw(image.width, image.height, packed)
            .ok_or(PixelsShort)?
            .into(),
        PixelFormat::Rgb8 => image::RgbImage::from_raw(image.width, image.height, packed)
            .ok_or(PixelsShort)?
            .into(),
        PixelFormat::Rgba8 => image::RgbaImage::from_raw(image.width, image.height, packed)
            .ok_or(PixelsShort)?
            .into(),
        PixelFormat::Bgr8 => {
            let rgb: Vec<u8> = packed.chunks_exact(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
            image::RgbImage::from_raw(image.width, image.height, rgb)
                .ok_or(PixelsShort)?
                .into()
        }
        PixelFormat::Bgra8 => {
            let rgba: Vec<u8> = packed
                .chunks_exact(4)
                .flat_map(|p| [p[2], p[1], p[0], p[3]])
                .collect();
            image::RgbaImage::from_raw(image.width, image.height, rgba)
                .ok_or(PixelsShort)?
                .into()
        }
        PixelFormat::Gray16 => {
            let grey: Vec<u16> = packed
                .chunks_exact(2)
                .map(|p| u16::from_le_bytes([p[0], p[1]]))
                .collect();
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(image.width, image.height, grey)
                .ok_or(PixelsShort)?
                .into()
        }
    })
}

impl Component for ImageWriter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.folder = PathBuf::from(ctx.text_property("folder")?);
        std::fs::create_dir_all(&self.folder).map_err(|e| {
            ComponentError::failed(format_args!(
                "cannot create the folder {}: {e}",
                self.folder.display()
            ))
        })?;
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("image")?;
        let Payload::Image(image) = &sample.payload else {
            return Err(ComponentError::failed(format_args!(
                "expected an image, got {}",
                sample.payload.data_type()
            )));
        };
        let jpeg = ctx.text_property("format")? == "jpeg";
        // Timestamp first: names sort in time order, and an image sequence with timing = names (ns)
        // plays the files back at the times they were taken.
        let name = format!(
            "{:019}_{:08}.{}",
            sample.timestamp.0,
            sample.sequence,
            if jpeg { "jpg" } else { "png" }
        );
        let path = self.folder.join(name);
        let dynamic = to_dynamic(image).map_err(ComponentError::failed)?;
        let written = if jpeg {
            let quality = u8::try_from(ctx.i64_property("quality")?).unwrap_or(90);
            let dynamic = match dynamic {
                // JPEG has no alpha and no 16-bit grey.
                image::DynamicImage::ImageRgba8(_) => image::DynamicImage::ImageRgb8(dynamic.to_rgb8()),
                image::DynamicImage::ImageLuma16(_) => image::DynamicImage::ImageLuma8(dynamic.to_luma8()),
                other => other,
            };
            // The file's own error as the image crate's, which says it in the same words.
            std::fs::File::create(&path)
                .map_err(image::ImageError::IoError)
                .and_then(|file| {
                    image::codecs::jpeg::JpegEncoder::new_with_quality(std::io::BufWriter::new(file), quality)
                        .encode_image(&dynamic)
                })
        } else {
            dynamic.save_with_format(&path, image::ImageFormat::Png)
        };
        written.map_err(|e| ComponentError::failed(format_args!("cannot write {}: {e}", path.display())))?;
        self.written += 1;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(
            serde_json::json!({"kind": "image_writer", "written": self.written, "folder": self.folder.display().to_string()}),
        )
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

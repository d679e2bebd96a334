//! Sinks: print to the console, write CSV files.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, PackRegistrar, Payload, Sample,
    Synchronizer, TypeFilter,
};

/// The log target of what `core.console` prints.
pub const CONSOLE_TARGET: &str = "kairos::console";

/// `core.console`: prints samples on standard output.
#[derive(Debug, Default)]
pub struct Console {
    seen: u64,
}

impl Console {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "core.console",
            "sinks",
            "Prints samples on standard output: timestamp, sequence, latency, value",
        )
        .label("Console")
        .input("in", TypeFilter::Any, "Any stream")
        .property(
            Property::i64("every", 1)
                .int_range(1, 1_000_000)
                .live()
                .doc("Print one sample in this many"),
        )
        .property(
            Property::text("prefix", "")
                .live()
                .doc("Printed first on each line; the component id when empty"),
        )
        .build()
    }
}

impl Component for Console {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let every = u64::try_from(ctx.i64_property("every")?).unwrap_or(1).max(1);
        let print = self.seen.is_multiple_of(every);
        self.seen += 1;
        if !print {
            return Ok(());
        }
        let prefix = ctx.text_property("prefix")?;
        let prefix = if prefix.is_empty() {
            ctx.id().to_owned()
        } else {
            prefix
        };
        let line = format!(
            "{prefix}: t={} seq={} latency={:.1}µs {}\n",
            sample.timestamp,
            sample.sequence,
            sample.latency_nanos() as f64 / 1000.0,
            sample.payload
        );
        // A closed pipe (`kairos run ... | head`) is not the component's failure: stop printing quietly.
        let _ = std::io::stdout().lock().write_all(line.as_bytes());
        // The same line for a client of `kairos serve` (the studio's Console), as a log record of this
        // component; the runtime keeps records of this target off its standard error.
        tracing::info!(target: CONSOLE_TARGET, "{}", line.trim_end());
        Ok(())
    }
}

/// Column names and values for one payload.
pub fn payload_fields(payload: &Payload) -> Vec<(String, String)> {
    fn named<const N: usize>(names: [&str; N], values: [String; N]) -> Vec<(String, String)> {
        names.iter().map(|n| (*n).to_owned()).zip(values).collect()
    }
    match payload {
        Payload::F64(v) => named(["value"], [v.to_string()]),
        Payload::I64(v) => named(["value"], [v.to_string()]),
        Payload::Bool(v) => named(["value"], [v.to_string()]),
        Payload::Vector(v) => v
            .iter()
            .enumerate()
            .map(|(i, x)| (format!("v{i}"), x.to_string()))
            .collect(),
        Payload::Matrix(m) => {
            let mut fields = named(["rows", "cols"], [m.rows.to_string(), m.cols.to_string()]);
            fields.extend(
                m.values
                    .iter()
                    .enumerate()
                    .map(|(i, x)| (format!("m{i}"), x.to_string())),
            );
            fields
        }
        Payload::Text(t) => named(["text"], [csv_quote(t)]),
        Payload::Bytes(b) => named(["size_bytes"], [b.len().to_string()]),
        Payload::Image(i) => named(
            ["width", "height", "format", "size_bytes"],
            [
                i.width.to_string(),
                i.height.to_string(),
                format!("{:?}", i.format),
                i.pixels.len().to_string(),
            ],
        ),
        Payload::PointCloud(c) => named(["points"], [c.points.len().to_string()]),
        Payload::Imu(i) => named(
            ["gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"],
            [
                i.angular_velocity.x.to_string(),
                i.angular_velocity.y.to_string(),
                i.angular_velocity.z.to_string(),
                i.linear_acceleration.x.to_string(),
                i.linear_acceleration.y.to_string(),
                i.linear_acceleration.z.to_string(),
            ],
        ),
        Payload::GnssFix(g) => named(
            [
                "latitude_deg",
                "longitude_deg",
                "altitude_m",
                "horizontal_accuracy_m",
                "status",
            ],
            [
                g.latitude_deg.to_string(),
                g.longitude_deg.to_string(),
                g.altitude_m.to_string(),
                g.horizontal_accuracy_m.to_string(),
                format!("{:?}", g.status),
            ],
        ),
        Payload::CanFrame(f) => named(
            ["id", "extended", "len", "data_hex"],
            [
                f.id.to_string(),
                f.extended.to_string(),
                f.data().len().to_string(),
                f.data().iter().fold(String::new(), |mut hex, b| {
                    use std::fmt::Write as _;
                    let _ = write!(hex, "{b:02x}");
                    hex
                }),
            ],
        ),
        Payload::Pose(p) => named(
            ["x", "y", "z", "qx", "qy", "qz", "qw"],
            [
                p.position.x.to_string(),
                p.position.y.to_string(),
                p.position.z.to_string(),
                p.orientation.x.to_string(),
                p.orientation.y.to_string(),
                p.orientation.z.to_string(),
                p.orientation.w.to_string(),
            ],
        ),
        Payload::Custom(c) => named(
            ["type", "size_bytes"],
            [c.type_name.to_string(), c.data.len().to_string()],
        ),
        // A payload type newer than this pack: its type at least.
        other => named(["type"], [other.data_type().to_string()]),
    }
}

fn csv_quote(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_owned()
    }
}

const CSV_INPUTS: [&str; 4] = ["in1", "in2", "in3", "in4"];
const FLUSH_PERIOD: Duration = Duration::from_millis(500);

/// `core.csv_writer`: writes samples to a CSV file.
#[derive(Debug, Default)]
pub struct CsvWriter {
    writer: Option<BufWriter<File>>,
    path: PathBuf,
    header_written: bool,
    connected: Vec<usize>,
    synchronizer: Option<Synchronizer>,
    last_flush: Option<Instant>,
}

impl CsvWriter {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let mut descriptor = Descriptor::new(
            "core.csv_writer",
            "sinks",
            "Writes samples to a CSV file: one row per sample, or one row per timestamp-matched set",
        )
        .label("CSV file writer");
        for input in CSV_INPUTS {
            descriptor = descriptor.input(input, TypeFilter::Any, "A stream to write");
        }
        descriptor
            .property(Property::path("path", "kairos.csv").doc(
                "The file written. A file of that name is never replaced unless `overwrite` is set: the \
                     run writes the first free NAME-1.csv, NAME-2.csv, … beside it, and says so",
            ))
            .property(
                Property::bool("overwrite", false)
                    .doc("Replace a file already at `path` instead of writing beside it under a new name"),
            )
            .property(Property::bool("synchronize", false).doc(
                "false: one row per sample with its input's name; true: one row per set matched by timestamp",
            ))
            .property(
                Property::f64("tolerance_ms", 5.0)
                    .unit("ms")
                    .range(0.0, 60_000.0)
                    .doc("synchronize: largest timestamp gap in a set"),
            )
            .build()
    }

    fn write_row(&mut self, row: &[String]) -> ComponentResult {
        let Some(writer) = self.writer.as_mut() else {
            return Err(ComponentError::failed("the CSV file is not open"));
        };
        writeln!(writer, "{}", row.join(","))
            .map_err(|e| ComponentError::failed(format_args!("writing {}: {e}", self.path.display())))?;
        let now = Instant::now();
        if self
            .last_flush
            .is_none_or(|t| now.duration_since(t) >= FLUSH_PERIOD)
        {
            self.last_flush = Some(now);
            writer
                .flush()
                .map_err(|e| ComponentError::failed(format_args!("writing {}: {e}", self.path.display())))?;
        }
        Ok(())
    }

    fn sample_columns(prefix: &str, sample: &Sample) -> (Vec<String>, Vec<String>) {
        let mut names = vec![
            format!("{prefix}timestamp_ns"),
            format!("{prefix}time_of_issue_ns"),
            format!("{prefix}sequence"),
        ];
        let mut values = vec![
            sample.timestamp.as_nanos().to_string(),
            sample.time_of_issue.as_nanos().to_string(),
            sample.sequence.to_string(),
        ];
        for (name, value) in payload_fields(&sample.payload) {
            names.push(format!("{prefix}{name}"));
            values.push(value);
        }
        (names, values)
    }
}

impl Component for CsvWriter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.path = PathBuf::from(ctx.text_property("path")?);
        let (file, path) = kairos_sdk::files::create_for(ctx, &self.path).map_err(|e| {
            ComponentError::failed(format_args!("cannot create {}: {e}", self.path.display()))
        })?;
        self.path = path;
        ctx.set_status(serde_json::json!({"path": self.path.display().to_string()}));
        self.writer = Some(BufWriter::new(file));
        self.connected = (0..CSV_INPUTS.len()).filter(|i| ctx.is_connected(*i)).collect();
        if ctx.bool_property("synchronize")? {
            let tolerance = Duration::from_secs_f64(ctx.f64_property("tolerance_ms")? / 1000.0);
            self.synchronizer = Some(Synchronizer::new(self.connected.clone(), tolerance));
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.connected.is_empty() {
            return Err(ComponentError::Stopped);
        }
        let (names, values) = if let Some(synchronizer) = &mut self.synchronizer {
            let matched = synchronizer.read(ctx)?;
            let mut names = Vec::new();
            let mut values = Vec::new();
            for (index, sample) in self.connected.iter().zip(&matched) {
                let input = CSV_INPUTS.get(*index).copied().unwrap_or("in");
                let (n, v) = Self::sample_columns(&format!("{input}."), sample);
                names.extend(n);
                values.extend(v);
            }
            (names, values)
        } else {
            let inputs: Vec<usize> = self.connected.clone();
            let (position, sample) = ctx.read_any(&inputs)?;
            let input = inputs
                .get(position)
                .and_then(|i| CSV_INPUTS.get(*i))
                .copied()
                .unwrap_or("in");
            let (mut names, mut values) = Self::sample_columns("", &sample);
            names.insert(0, "input".to_owned());
            values.insert(0, input.to_owned());
            (names, values)
        };
        if !self.header_written {
            self.header_written = true;
            self.write_row(&names)?;
        }
        self.write_row(&values)
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        if let Some(mut writer) = self.writer.take() {
            writer
                .flush()
                .map_err(|e| ComponentError::failed(format_args!("writing {}: {e}", self.path.display())))?;
        }
        Ok(())
    }
}

/// Registers the sinks.
pub fn register(pack: &mut PackRegistrar<'_>) {
    pack.component::<Console>(Console::info())
        .component::<CsvWriter>(CsvWriter::info());
}

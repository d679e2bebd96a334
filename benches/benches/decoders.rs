//! Benchmark 14 — sensor decoders through their components against bare loops over the same library
//! calls and arithmetic: NMEA (`gnss.nmea`), candump + DBC (`can.candump_reader` into
//! `can.dbc_decoder`), Velodyne VLP-16 from a pcap capture (`lidar.velodyne`). Each component runs on
//! one thread, called as the engine calls it (`core` on a context whose outputs write into buffers),
//! replaying as fast as possible; the baseline does the same decoding without the component. Also: the
//! multiple of real time on one core, against a typical sensor's rate.

#![allow(
    clippy::unwrap_used,
    reason = "a failure here is a broken benchmark, not something to carry on from"
)]

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::hint::black_box;
use std::io::{BufRead as _, BufReader};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use kairos_benches::{
    Goal, LatencySeries, Percentiles, Ratios, Table, component_context as context, header, nanos,
    print_latency, size,
};
use kairos_pack_can::components::readable;
use kairos_sdk_core::host::ReaderConfig;
use kairos_sdk_core::{Component, Payload, ReaderPolicy, RunSignal, Value};

/// Nanoseconds per item of `items` calls of `op`.
fn per_item(items: usize, mut op: impl FnMut()) -> f64 {
    let start = Instant::now();
    for _ in 0..items {
        op();
    }
    nanos(start.elapsed()) / items as f64
}

fn one(value: f64) -> Percentiles {
    Percentiles::of(&mut [value])
}

fn nmea(dir: &Path, items: usize) -> (f64, f64) {
    let path = dir.join("drive.nmea");
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/data/drive.nmea"),
        &path,
    )
    .unwrap();
    let info = kairos_pack_gnss::receiver::descriptor();
    let (mut ctx, _buffers) = context(
        &info,
        &[
            ("source", Value::Text("file".into())),
            ("path", Value::Text(path.display().to_string())),
            ("replay", Value::Text("fast".into())),
            ("loop", Value::Bool(true)),
        ],
        Vec::new(),
    );
    let mut component = kairos_pack_gnss::receiver::NmeaReceiver::default();
    component.birth(&mut ctx).unwrap();
    let ours = per_item(items, || component.core(&mut ctx).unwrap());
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<Vec<u8>> = text.lines().map(|l| l.as_bytes().to_vec()).collect();
    let mut decoder = kairos_pack_gnss::sentence::Decoder::new();
    let mut index = 0;
    let baseline = per_item(items, || {
        let line = std::str::from_utf8(&lines[index % lines.len()]).unwrap();
        index += 1;
        let reading = decoder.decode(line).unwrap();
        // What the component builds from a reading: the text, the fix, the numbers.
        black_box(Payload::Text(Arc::from(line)));
        if let Some(fix) = reading.fix {
            let accuracy = fix.hdop.map_or(f64::NAN, |h| h * 3.0);
            black_box((
                fix.latitude_deg,
                fix.longitude_deg,
                fix.altitude_ellipsoid_m(),
                accuracy,
                fix.satellites,
            ));
        }
        black_box((reading.utc_s, reading.motion));
    });
    (ours, baseline)
}

fn can(dir: &Path, items: usize) -> (f64, f64) {
    let log = dir.join("drive.log");
    let dbc = dir.join("vehicle.dbc");
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/data/drive.log"),
        &log,
    )
    .unwrap();
    std::fs::copy(
        concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/data/vehicle.dbc"),
        &dbc,
    )
    .unwrap();
    let reader_info = kairos_pack_can::components::reader_descriptor();
    let (mut reader_ctx, reader_buffers) = context(
        &reader_info,
        &[
            ("path", Value::Text(log.display().to_string())),
            ("replay", Value::Text("fast".into())),
            ("loop", Value::Bool(true)),
        ],
        Vec::new(),
    );
    let decoder_properties = BTreeMap::from([("dbc".to_owned(), Value::Text(dbc.display().to_string()))]);
    let decoder_info = kairos_pack_can::components::describe_decoder(&decoder_properties).unwrap();
    let frames_to_decoder = reader_buffers[0].attach(
        ReaderConfig::new(ReaderPolicy::Fifo, "log.frame -> decoder.frame"),
        Arc::new(RunSignal::new()),
    );
    let (mut decoder_ctx, _buffers) = context(
        &decoder_info,
        &[("dbc", Value::Text(dbc.display().to_string()))],
        vec![Some(frames_to_decoder)],
    );
    let mut reader = kairos_pack_can::components::CandumpReader::default();
    let mut decoding = kairos_pack_can::components::DbcDecoder::default();
    reader.birth(&mut reader_ctx).unwrap();
    decoding.birth(&mut decoder_ctx).unwrap();
    let ours = per_item(items, || {
        reader.core(&mut reader_ctx).unwrap();
        decoding.core(&mut decoder_ctx).unwrap();
    });
    // The same work without the components: lines read from the file, parsed, decoded, written as text.
    let open = || BufReader::new(std::fs::File::open(&log).unwrap()).lines();
    let mut lines = open();
    let database = kairos_pack_can::dbc::Database::open(&dbc).unwrap();
    let baseline = per_item(items, || {
        // Frames only, as the reader passes them on (the log's one error frame is skipped).
        let frame = loop {
            let Some(line) = lines.next() else {
                lines = open();
                continue;
            };
            if let Ok(kairos_pack_can::candump::Logged::Frame { frame, .. }) =
                kairos_pack_can::candump::parse(&line.unwrap())
            {
                break frame;
            }
        };
        let decoded = database.decode(&frame).unwrap_or_default();
        let mut line = String::new();
        for (index, signal) in decoded.iter().enumerate() {
            line.push_str(if index == 0 { signal.message } else { "; " });
            if index == 0 {
                line.push_str(": ");
            }
            let _ = write!(line, "{} = {}", signal.signal, readable(signal.value));
            if !signal.unit.is_empty() {
                line.push(' ');
                line.push_str(signal.unit);
            }
        }
        black_box(Payload::Text(Arc::from(line)));
        black_box(decoded.iter().map(|d| d.value).sum::<f64>());
    });
    (ours, baseline)
}

fn velodyne(dir: &Path, items: usize) -> (f64, f64) {
    use kairos_pack_lidar::packets::{Decoder, Model, encode_packet};
    use kairos_pack_lidar::pcap::{Capture, capture_of, frame_of};
    let path = dir.join("spin.pcap");
    let frames: Vec<(i64, Vec<u8>)> = (0..754_i64)
        .map(|index| {
            let mut blocks = [(0_u16, [(0_u16, 0_u8); 32]); 12];
            for (block_index, block) in blocks.iter_mut().enumerate() {
                block.0 = ((index * 12 + block_index as i64) * 40 % 36_000) as u16;
                for (m, value) in block.1.iter_mut().enumerate() {
                    *value = (2500 + (m as u16) * 10, m as u8);
                }
            }
            (
                index * 1_326_000,
                frame_of(2368, &encode_packet(Model::Vlp16, &blocks, 0)),
            )
        })
        .collect();
    std::fs::write(&path, capture_of(&frames)).unwrap();
    let info = kairos_pack_lidar::velodyne::descriptor();
    let (mut ctx, _buffers) = context(
        &info,
        &[
            ("source", Value::Text("pcap".into())),
            ("path", Value::Text(path.display().to_string())),
            ("replay", Value::Text("fast".into())),
            ("loop", Value::Bool(true)),
        ],
        Vec::new(),
    );
    let mut component = kairos_pack_lidar::velodyne::Velodyne::default();
    component.birth(&mut ctx).unwrap();
    let ours = per_item(items, || component.core(&mut ctx).unwrap());
    let mut capture = Capture::open(&path).unwrap();
    let mut decoder = Decoder::new();
    let baseline = per_item(items, || {
        let datagram = if let Some(datagram) = capture.next_datagram() {
            datagram
        } else {
            capture = Capture::open(&path).unwrap();
            capture.next_datagram().unwrap()
        };
        decoder
            .packet(&datagram.payload, |cloud| {
                black_box(Payload::PointCloud(Arc::new(cloud)));
            })
            .unwrap();
    });
    (ours, baseline)
}

fn main() {
    let items = size(20_000, 200_000);
    header(
        "14. Sensor decoders: through the component vs a bare loop",
        "one thread, replay as fast as possible, outputs into buffers nobody reads",
        &format!(
            "{items} sentences or frames per run, {} packets for the lidar",
            items / 10
        ),
    );
    let dir = tempfile::tempdir().unwrap();
    let mut series: Vec<(LatencySeries, LatencySeries, f64, &str)> = vec![
        (
            LatencySeries::new("ours: gnss.nmea, per sentence"),
            LatencySeries::new("baseline: decode loop, per sentence"),
            60.0,
            "NMEA (60 sentences/s: 10 Hz, 6 sentences a fix)",
        ),
        (
            LatencySeries::new("ours: candump_reader → dbc_decoder, per frame"),
            LatencySeries::new("baseline: parse + decode loop, per frame"),
            2000.0,
            "candump + DBC (2000 frames/s: a busy 500 kbit/s bus)",
        ),
        (
            LatencySeries::new("ours: lidar.velodyne, per packet"),
            LatencySeries::new("baseline: pcap + decode loop, per packet"),
            754.0,
            "VLP-16 (754 packets/s at 600 rpm)",
        ),
    ];
    for _ in 0..kairos_benches::repetitions() {
        let results = [
            nmea(dir.path(), items),
            can(dir.path(), items),
            velodyne(dir.path(), items / 10),
        ];
        for ((ours, baseline, _, _), (o, b)) in series.iter_mut().zip(results) {
            ours.reps.push(one(o));
            baseline.reps.push(one(b));
        }
    }
    let all: Vec<&LatencySeries> = series.iter().flat_map(|(o, b, _, _)| [b, o]).collect();
    print_latency(&all);
    let mut ratios = Ratios::new();
    for (ours, baseline, _, name) in &series {
        ratios.add(
            format!(
                "{}: component / bare loop",
                name.split(' ').next().unwrap_or(name)
            ),
            kairos_benches::ratio_spread(ours, baseline, |p| p.mean),
            Some(Goal::AtMost(1.2)),
        );
    }
    ratios.print();
    let mut table = Table::new(&[
        "decoder",
        "per item (median)",
        "multiple of real time on one core",
        "goal",
    ]);
    for (ours, _, real_rate, name) in &series {
        let per_item = ours.spread(|p| p.mean).median;
        let multiple = 1e9 / per_item / real_rate;
        table.row(vec![
            (*name).to_owned(),
            kairos_benches::time(per_item),
            format!("{multiple:.0}×"),
            format!("≥ 50×: {}", if multiple >= 50.0 { "met" } else { "MISSED" }),
        ]);
    }
    table.print();
}

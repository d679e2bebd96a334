//! Any bytes as a ROS 2 message in CDR of each type Kairos writes, and any text as a message definition:
//! located errors are fine, panics and runaway allocations are not. Run with `cargo +nightly fuzz run
//! ros2_cdr` in `fuzz/`.
#![no_main]

use kairos_pack_recording::ros2::write::definition_of;
use kairos_pack_recording::ros2::{Definitions, data_type_of, to_payload};
use libfuzzer_sys::fuzz_target;

const TYPES: &[&str] = &[
    "sensor_msgs/msg/Imu",
    "sensor_msgs/msg/NavSatFix",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/PointCloud2",
    "geometry_msgs/msg/PoseStamped",
    "std_msgs/msg/Float64MultiArray",
    "std_msgs/msg/UInt8MultiArray",
    "std_msgs/msg/String",
    "can_msgs/msg/Frame",
];

fuzz_target!(|data: &[u8]| {
    let Some((&choice, message)) = data.split_first() else { return };
    // One of the known definitions, or the input's text (up to a NUL) as a definition of its own.
    let definitions = match TYPES.get(usize::from(choice)) {
        Some(type_name) => Definitions::parse(type_name, &definition_of(type_name)),
        None => {
            let (text, _) = message.split_at(message.iter().position(|b| *b == 0).unwrap_or(message.len()));
            Definitions::parse("fuzz/msg/Message", &String::from_utf8_lossy(text))
        }
    };
    let Ok(definitions) = definitions else { return };
    if let Ok(value) = definitions.decode(message) {
        let _ = to_payload(&definitions, &value, &data_type_of(definitions.type_name()));
        let _ = value.to_json();
    }
});

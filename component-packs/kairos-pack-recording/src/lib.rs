//! The recording pack: `recording.recorder` writes time-stamped samples to MCAP files that open in
//! Foxglove, Lichtblick and any MCAP reader; `recording.player` replays them (and MCAP files from other
//! writers) as if the sensors were live; [`inspect`] reads them back for `kairos inspect`.
//!
//! Every message keeps both times: MCAP's publish time is the sample's timestamp (when the data
//! originated) and its log time the sample's time of issue (when it was last written). Images, point
//! clouds, GNSS fixes and poses use the Foxglove well-known schemas (protobuf); every other type a JSON
//! schema of ours (`kairos.F64`, `kairos.Imu`, ...), so each channel decodes from the file alone.
//! rosbag2 recordings (MCAP, ROS 2 messages in CDR) replay too, decoded through the message definitions
//! they carry ([`ros2`]).

pub mod decode;
pub mod encode;
pub mod inspect;
pub mod merge;
pub mod player;
pub mod pretrigger;
pub mod recorder;
pub mod recover;
pub mod ros2;
pub mod safe_read;
pub mod timeline;

pub use inspect::{InspectError, Progress, Report, inspect, inspect_bytes, inspect_with_progress};
use kairos_sdk::Registry;
pub use recover::{Recovered, recover};

/// Registers the pack "recording".
pub fn register(registry: &mut Registry) {
    registry
        .pack("recording", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<recorder::Recorder>(recorder::Recorder::info())
        .component_described::<player::Player>(player::Player::info(), player::Player::describe);
}

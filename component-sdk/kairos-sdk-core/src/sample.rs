//! A sample: a payload with its two times and its sequence number.

use crate::payload::Payload;
use crate::time::Timestamp;

/// One piece of data on an output.
///
/// Cloning is cheap: heavy payloads are shared, never copied.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// The data.
    pub payload: Payload,
    /// When the data originated: set by the most upstream producer, carried unchanged downstream.
    pub timestamp: Timestamp,
    /// When the sample was last written to an output.
    pub time_of_issue: Timestamp,
    /// The position of the sample in its output's stream, from 0.
    pub sequence: u64,
}

impl Sample {
    /// A sample whose timestamp and time of issue are both `time`.
    pub fn new(payload: Payload, time: Timestamp) -> Self {
        Sample {
            payload,
            timestamp: time,
            time_of_issue: time,
            sequence: 0,
        }
    }

    /// Time of issue minus timestamp, in nanoseconds.
    #[inline]
    pub fn latency_nanos(&self) -> i64 {
        self.time_of_issue.nanos_since(self.timestamp)
    }
}

//! Any bytes as a Kairos sample frame (what a socket component in `kairos` encoding receives): decoded or
//! refused with a reason, never a panic; a frame that decodes encodes back to one that decodes the same.
#![no_main]

use kairos_sample_frame::{decode, encode_whole};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(received) = decode(data) {
        let again = decode(&encode_whole(&received.output, &received.sample)).expect("re-encoded frame decodes");
        assert_eq!(again.sample.payload.data_type(), received.sample.payload.data_type());
        assert_eq!(again.sample.timestamp, received.sample.timestamp);
    }
});

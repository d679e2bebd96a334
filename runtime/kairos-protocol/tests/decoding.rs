//! Decoding whatever a client sends never panics: arbitrary text, valid requests with bytes changed, and
//! arbitrary binary frames (property tests standing in for the fuzz targets in `fuzz/`).

use kairos_protocol::{RequestKind, decode_request, frame};
use proptest::prelude::*;

fn valid_requests() -> Vec<String> {
    RequestKind::ALL
        .iter()
        .enumerate()
        .map(|(id, kind)| {
            format!(
                r#"{{"id": {id}, "type": "{}", "protocol": 1, "client": "c", "token": "t", "diagram": "D", "component": "a", "property": "p", "value": 1.5, "action": "x", "interval_ms": 100, "outputs": ["a.b"], "max_rate_hz": 5, "seconds": 1, "factor": 2, "level": "warn", "name": "n", "version": "0.1.0", "platform": "linux-x86_64", "size": 1, "offset": 0, "data": "AA==", "publish": true, "ticket": 1, "router": "tcp/localhost:7447"}}"#,
                kind.name()
            )
        })
        .collect()
}

#[test]
fn every_request_type_decodes_from_a_complete_message() {
    for text in valid_requests() {
        assert!(decode_request(&text).is_ok(), "{text}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text_never_panics(text in ".{0,400}") {
        let _ = decode_request(&text);
    }

    #[test]
    fn changed_requests_never_panic(which in 0_usize..25, edits in prop::collection::vec((any::<usize>(), any::<char>()), 1..8)) {
        let requests = valid_requests();
        let mut chars: Vec<char> = requests[which % requests.len()].chars().collect();
        for (at, c) in edits {
            let len = chars.len();
            chars[at % len] = c;
        }
        let text: String = chars.into_iter().collect();
        let _ = decode_request(&text);
    }

    #[test]
    fn arbitrary_frames_never_panic(mut bytes in prop::collection::vec(any::<u8>(), 0..256), magic in any::<bool>()) {
        if magic && bytes.len() >= 4 {
            bytes[..4].copy_from_slice(frame::MAGIC);
        }
        let _ = frame::decode(&bytes);
    }
}

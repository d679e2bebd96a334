//! A dora-rs node for benchmark 18 (`run.py`). One binary, three roles (its argument): `source` (stamps
//! the wall time at each tick of a 1 ms timer), `relay` (passes the value on), `sink`
//! (each sample's latency, the first 1000 left out as warm-up, summarised into $OUT).
use dora_node_api::{DoraNode, Event, dora_core::config::DataId};
use std::time::{SystemTime, UNIX_EPOCH};

fn now() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).unwrap().as_nanos() as u64
}

fn main() {
    let role = std::env::args().nth(1).unwrap();
    let (mut node, mut events) = DoraNode::init_from_env().unwrap();
    let out = DataId::from("out".to_owned());
    let total: usize = std::env::var("SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6000);
    let mut latencies = Vec::new();
    let mut sent = 0;
    while let Some(event) = events.recv() {
        if let Event::Input { data, metadata, .. } = event {
            match role.as_str() {
                "source" => {
                    node.send_output(out.clone(), metadata.parameters, now()).unwrap();
                    sent += 1;
                    if sent == total {
                        break;
                    }
                }
                "relay" => {
                    let value: u64 = (&data).try_into().unwrap();
                    node.send_output(out.clone(), metadata.parameters, value).unwrap();
                }
                _ => {
                    let value: u64 = (&data).try_into().unwrap();
                    latencies.push(now() - value);
                    if latencies.len() == total {
                        break;
                    }
                }
            }
        }
    }
    if role == "sink" {
        let mut kept: Vec<u64> = latencies.into_iter().skip(1000).collect();
        kept.sort_unstable();
        let n = kept.len().max(1);
        let us = |ns: u64| ns as f64 / 1e3;
        let line = format!(
            "{{\"samples\": {}, \"p50_us\": {:.1}, \"p99_us\": {:.1}, \"mean_us\": {:.1}}}\n",
            kept.len(),
            us(kept.get(n / 2).copied().unwrap_or(0)),
            us(kept.get(n * 99 / 100).copied().unwrap_or(0)),
            us(kept.iter().sum::<u64>()) / n as f64
        );
        std::fs::write(std::env::var("OUT").expect("OUT names the result file"), line).unwrap();
    }
}

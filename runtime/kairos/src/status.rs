//! `kairos status`: what each runtime of a diagram spread over hosts is doing, one line per host (its
//! state, its clock against the master, its links), or the same for one `kairos serve` by its endpoint.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use kairos_diagram::HostSpec;
use kairos_protocol::{FoxgloveState, LinkList, RequestBody};

use kairos_coordinator::{Host, Reach};

/// How the last start at the agreed instant went: beyond [`kairos_coordinator::start::LATE_START`], the
/// host's part started apart from the others.
fn start_words(late_ns: i64) -> String {
    if kairos_coordinator::start::started_late(late_ns) {
        format!(
            "STARTED LATE: {:.1} ms after the agreed instant (more than {} ms)",
            late_ns as f64 * 1e-6,
            kairos_coordinator::start::LATE_START.as_millis()
        )
    } else {
        format!("started together (+{:.0} µs)", late_ns as f64 * 1e-3)
    }
}

/// A receiving link end quiet for longer than is usual on its link (what its receiver learnt, else
/// [`kairos_protocol::LINK_QUIET_MS`]), in words: its sender stopped, or the path carries nothing.
fn quiet_words(link: &kairos_protocol::LinkEnd, status: &serde_json::Value) -> Option<String> {
    let receiver = kairos_coordinator::watch::component_status(status, &link.component);
    let quiet_ms = receiver["last_sample_age_ms"].as_u64()?;
    let usual_ms = receiver["quiet_after_ms"]
        .as_u64()
        .unwrap_or(kairos_protocol::LINK_QUIET_MS);
    (quiet_ms >= usual_ms).then(|| {
        format!(
            "QUIET: {} from {}: nothing for {:.1} s (unusual after {:.1} s): its sender stopped, or the \
             path between the hosts carries nothing",
            link.component,
            link.peer,
            quiet_ms as f64 * 1e-3,
            usual_ms as f64 * 1e-3
        )
    })
}

/// One host's line: `car (ws://10.0.0.2:7400): running, 4 components, clock locked ±4.2 µs, links 2 of 2
/// matched, Foxglove on ws://127.0.0.1:8765 (every output, 1 client(s))`.
fn line(name: &str, spec: &HostSpec, reach: &Reach) -> String {
    let mut host = match Host::reach(name, spec, reach) {
        Ok(host) => host,
        Err(error) => return format!("{name} ({}): NOT REACHED: {error:#}", spec.endpoint),
    };
    let mut text = format!("{name} ({}): ", spec.endpoint);
    let answered = host.call(RequestBody::Status);
    match &answered {
        Ok(status) => {
            let state = status["state"].as_str().unwrap_or("unknown");
            let _ = write!(text, "{state}");
            if let Some(components) = status["telemetry"]["components"].as_array() {
                let failed = components
                    .iter()
                    .filter(|c| c["state"].as_str() == Some("failed"))
                    .count();
                let _ = write!(text, ", {} components", components.len());
                if failed > 0 {
                    let _ = write!(text, " ({failed} FAILED)");
                }
            }
            match kairos_coordinator::clocks::clock_of(status) {
                Some(clock) if clock.state == kairos_protocol::ClockState::Master => {
                    text.push_str(", clock master");
                }
                Some(clock) => {
                    let _ = write!(text, ", clock {} (follows {})", clock.state, clock.source);
                    if clock.state.has_error() {
                        let _ = write!(text, ", error {:+.1} µs", clock.error_ns as f64 * 1e-3);
                        if let Some(bound) = clock.error_bound_ns {
                            let _ = write!(
                                text,
                                ", error bound ±{:.1} µs",
                                bound.unsigned_abs() as f64 * 1e-3
                            );
                        }
                    }
                }
                None => text.push_str(", own clock"),
            }
            if let Some(late_ns) = status["start_late_ns"].as_i64() {
                let _ = write!(text, ", {}", start_words(late_ns));
            }
        }
        Err(error) => {
            let _ = write!(text, "status refused: {error:#}");
        }
    }
    if let Ok(links) = host
        .call(RequestBody::Links)
        .and_then(|value| serde_json::from_value::<LinkList>(value).map_err(Into::into))
        && !links.links.is_empty()
    {
        let senders: Vec<_> = links.links.iter().filter(|l| l.role == "sender").collect();
        let matched = senders.iter().filter(|l| l.matched).count();
        let _ = write!(
            text,
            ", links out {matched} of {} matched, {} in",
            senders.len(),
            links.links.len() - senders.len()
        );
        for link in senders.iter().filter(|l| !l.matched) {
            let _ = write!(text, "\n    NOT MATCHED: {} -> {}", link.component, link.peer);
        }
        if let Ok(status) = &answered {
            for link in links.links.iter().filter(|l| l.role != "sender") {
                if let Some(quiet) = quiet_words(link, status) {
                    let _ = write!(text, "\n    {quiet}");
                }
            }
        }
    }
    if let Ok(foxglove) = host
        .call(RequestBody::Foxglove)
        .and_then(|value| serde_json::from_value::<FoxgloveState>(value).map_err(Into::into))
        && let Some(address) = &foxglove.address
    {
        let what = if foxglove.all {
            "every output".to_owned()
        } else {
            format!("{} output(s)", foxglove.outputs.len())
        };
        let _ = write!(
            text,
            ", Foxglove on {address} ({what}, {} client(s))",
            foxglove.clients
        );
    }
    text
}

/// Prints a line per host of the diagram at `target`, or for the runtime at `target` when it is a
/// `ws://` endpoint (its token in `token_file`).
///
/// # Errors
///
/// A diagram that cannot be read or names no hosts.
pub fn print(
    target: &str,
    token_file: Option<&Path>,
    certificate: Option<&Path>,
    clear_text_tokens: bool,
) -> anyhow::Result<bool> {
    let mut reached_all = true;
    if target.starts_with("ws://") || target.starts_with("wss://") {
        let spec = HostSpec {
            endpoint: target.to_owned(),
            token_file: token_file.map(|p| p.display().to_string()),
            zenoh: None,
            certificate: certificate.map(|p| p.display().to_string()),
            ride_out_s: None,
            ride_out_mb: None,
        };
        let text = line("runtime", &spec, &Reach::new(Path::new("."), clear_text_tokens));
        reached_all &= !text.contains("NOT REACHED");
        println!("{text}");
        return Ok(reached_all);
    }
    let path = PathBuf::from(target);
    let (_, flattened) = kairos_diagram::load_flattened(&path, &std::collections::BTreeMap::new())
        .map_err(|e| anyhow::anyhow!("{}", e.render()))?;
    let parsed = flattened.parsed;
    let hosts = &parsed.diagram.hosts;
    anyhow::ensure!(
        !hosts.is_empty(),
        "{target} names no hosts: give a diagram with a hosts section, or a runtime's ws:// endpoint"
    );
    let folder = path.parent().unwrap_or_else(|| Path::new("."));
    for (name, spec) in hosts {
        let text = line(name, spec, &Reach::new(folder, clear_text_tokens));
        reached_all &= !text.contains("NOT REACHED");
        println!("{text}");
    }
    Ok(reached_all)
}

//! A tracing layer that copies log records to the control protocol's log stream.
//!
//! Installed with the rest of logging at start-up; it costs one atomic load per event until `kairos serve`
//! opens the tap. Records go to a broadcast channel: a subscriber that falls behind skips records instead of
//! holding anyone up.

use std::sync::OnceLock;

use kairos_protocol::{LogLevel, LogRecord};
use tokio::sync::broadcast;
use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::layer::Context;
use tracing_subscriber::registry::LookupSpan;

/// Records kept for subscribers that are a little behind.
const TAP_CAPACITY: usize = 1024;

static TAP: OnceLock<broadcast::Sender<LogRecord>> = OnceLock::new();

/// Opens the tap (once) and returns a receiver of every later record.
pub fn subscribe() -> broadcast::Receiver<LogRecord> {
    TAP.get_or_init(|| broadcast::channel(TAP_CAPACITY).0).subscribe()
}

/// The layer to install.
#[derive(Debug, Default)]
pub struct LogTap;

/// The component id a span was opened for (the engine opens one per component thread).
struct ComponentId(String);

#[derive(Default)]
struct Fields {
    message: String,
    component: Option<String>,
    id: Option<String>,
}

impl Visit for Fields {
    fn record_str(&mut self, field: &Field, value: &str) {
        match field.name() {
            "message" => value.clone_into(&mut self.message),
            "component" => self.component = Some(value.to_owned()),
            "id" => self.id = Some(value.to_owned()),
            _ => {}
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        match field.name() {
            "message" => self.message = format!("{value:?}"),
            "component" => self.component = Some(format!("{value:?}").trim_matches('"').to_owned()),
            "id" => self.id = Some(format!("{value:?}").trim_matches('"').to_owned()),
            _ => {}
        }
    }
}

fn level_of(level: Level) -> LogLevel {
    match level {
        Level::TRACE => LogLevel::Trace,
        Level::DEBUG => LogLevel::Debug,
        Level::INFO => LogLevel::Info,
        Level::WARN => LogLevel::Warn,
        Level::ERROR => LogLevel::Error,
    }
}

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for LogTap {
    fn on_new_span(&self, attributes: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        if attributes.metadata().name() != "component" {
            return;
        }
        let mut fields = Fields::default();
        attributes.record(&mut fields);
        if let (Some(component), Some(span)) = (fields.id, ctx.span(id)) {
            span.extensions_mut().insert(ComponentId(component));
        }
    }

    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        let Some(tap) = TAP.get() else { return };
        if tap.receiver_count() == 0 {
            return;
        }
        let mut fields = Fields::default();
        event.record(&mut fields);
        let component = fields.component.or_else(|| {
            ctx.event_scope(event)?
                .find_map(|span| span.extensions().get::<ComponentId>().map(|c| c.0.clone()))
        });
        let at_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX));
        let _ = tap.send(LogRecord {
            at_ns,
            level: level_of(*event.metadata().level()),
            component,
            message: fields.message,
        });
    }
}

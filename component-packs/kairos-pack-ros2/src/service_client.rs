//! `ros2.service_client`: calls a ROS 2 service for each sample on its input, as a ROS 2 node on
//! `rmw_zenoh` calls one: a query on the service's key expression with the request in CDR and the
//! 33-byte attachment; the first reply is the response.

use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, Throttle,
    TypeFilter,
};
use zenoh::Wait as _;
use zenoh::liveliness::LivelinessToken;
use zenoh::query::{ConsolidationMode, QueryTarget};

use crate::names::{self, Attachment, SharedNode};
use crate::services::{self, ServiceType};

/// How long one wait for the reply lasts, so a stop gets through.
const REPLY_WAIT: Duration = Duration::from_millis(100);

/// Why a call has no response.
#[derive(Debug, thiserror::Error)]
enum CallError {
    #[error("no server offers it")]
    NoServer,
    #[error("no server answered within {0} s")]
    NoAnswer(f64),
    #[error("the server refused: {0}")]
    Refused(String),
    #[error(transparent)]
    Unreadable(#[from] services::ServiceError),
    #[error("cannot call it: {0}")]
    Zenoh(String),
    #[error("not started")]
    NotStarted,
    #[error("stopped while waiting")]
    Stopped,
}

impl CallError {
    /// Whether no server answered at all (rather than answering wrong).
    fn unanswered(&self) -> bool {
        matches!(self, CallError::NoServer | CallError::NoAnswer(_))
    }
}

/// The descriptor of `ros2.service_client`.
pub fn descriptor() -> ComponentInfo {
    let mut descriptor = Descriptor::new(
        "ros2.service_client",
        "ros2",
        "Calls a ROS 2 service (std_srvs Trigger, SetBool or Empty) on nodes running rmw_zenoh for each \
         sample on its input, and writes the response: reset a node, switch something on or off",
    )
    .label("ROS 2 service call")
    .input(
        "call",
        TypeFilter::Any,
        "Each sample calls the service once; for SetBool its value is the request (false, 0 or empty: \
         false)",
    )
    .output("success", DataType::Bool, "What the response says: done or not")
    .output(
        "message",
        DataType::Text,
        "The response's message (Trigger, SetBool)",
    );
    for property in services::service_properties()
        .into_iter()
        .chain([Property::f64("timeout_s", 5.0)
            .range(0.1, 600.0)
            .doc("How long a call waits for the response before it counts as unanswered")])
        .chain(names::node_properties())
    {
        descriptor = descriptor.property(property);
    }
    descriptor.build()
}

/// `ros2.service_client`. See [`descriptor`].
#[derive(Default)]
pub struct ServiceClient {
    node: Option<Arc<SharedNode>>,
    token: Option<LivelinessToken>,
    service: Option<ServiceType>,
    key: String,
    gid: [u8; 16],
    /// Calls made, numbered from 1 as `rmw_zenoh` numbers a client's requests.
    calls: i64,
    answered: u64,
    unanswered: u64,
    refused: u64,
    /// Failed calls are logged once a second at most, with the counts.
    warnings: Throttle,
}

impl ServiceClient {
    /// The response to one call, or why there is none; waits at most `timeout`.
    fn call(
        &mut self,
        ctx: &Context,
        data: bool,
        timeout: Duration,
    ) -> Result<services::Response, CallError> {
        let (Some(node), Some(service)) = (&self.node, self.service) else {
            return Err(CallError::NotStarted);
        };
        self.calls += 1;
        let attachment = Attachment {
            sequence: self.calls,
            source_time_ns: ctx.now().as_nanos(),
            gid: self.gid,
        };
        let replies = node
            .session
            .get(self.key.as_str())
            .payload(service.request(data))
            .attachment(attachment.to_bytes())
            // Every server, complete or not: the key's type hash is a wildcard (any release's server),
            // which no server's queryable includes, as `AllComplete` would want.
            .target(QueryTarget::All)
            .consolidation(ConsolidationMode::None)
            .timeout(timeout)
            .wait()
            .map_err(|e| CallError::Zenoh(e.to_string()))?;
        // Zenoh ends the query at `timeout`; the wait is cut in slices so a stop gets through.
        let started = Instant::now();
        loop {
            if ctx.stop_requested() {
                return Err(CallError::Stopped);
            }
            match replies.recv_timeout(REPLY_WAIT) {
                Ok(Some(reply)) => {
                    return match reply.result() {
                        Ok(sample) => Ok(service.read_response(&sample.payload().to_bytes())?),
                        Err(error) => Err(CallError::Refused(
                            error.payload().try_to_string().unwrap_or_default().into_owned(),
                        )),
                    };
                }
                Ok(None) => {}
                // The query is over with no reply: no server answered in time, or none was there.
                Err(_) if started.elapsed() >= timeout => {
                    return Err(CallError::NoAnswer(timeout.as_secs_f64()));
                }
                Err(_) => return Err(CallError::NoServer),
            }
        }
    }
}

impl Component for ServiceClient {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let endpoint = services::Endpoint::declare(ctx, "SC")?;
        tracing::info!("calling {} on {}", endpoint.service.name(), endpoint.key);
        self.gid = names::gid_of(&endpoint.token_key);
        self.key = endpoint.key;
        self.service = Some(endpoint.service);
        self.token = Some(endpoint.token);
        self.node = Some(endpoint.node);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("call")?;
        let data = match &sample.payload {
            Payload::Bool(value) => *value,
            Payload::I64(value) => *value != 0,
            Payload::F64(value) => *value != 0.0,
            Payload::Text(text) => !text.is_empty() && &**text != "false",
            _ => true,
        };
        let timeout = Duration::from_secs_f64(ctx.f64_property("timeout_s")?);
        match self.call(ctx, data, timeout) {
            Ok(response) => {
                self.answered += 1;
                ctx.write_processed("success", &sample, Payload::Bool(response.success))?;
                ctx.write_processed("message", &sample, Payload::Text(Arc::from(response.message)))?;
            }
            // A call cut short by a stop is counted with the calls nobody answered.
            Err(CallError::Stopped) => {
                self.unanswered += 1;
                ctx.publish_status(self);
                return Err(ComponentError::Stopped);
            }
            Err(why) => {
                if why.unanswered() {
                    self.unanswered += 1;
                } else {
                    self.refused += 1;
                }
                let (key, unanswered, refused) = (&self.key, self.unanswered, self.refused);
                self.warnings.warn(|| {
                    format!("a call of {key}: {why} ({unanswered} unanswered and {refused} refused in all)")
                });
            }
        }
        ctx.publish_status(self);
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "ros2",
            "key": self.key,
            "calls": self.calls,
            "answered": self.answered,
            "unanswered": self.unanswered,
            "refused": self.refused,
        }))
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        self.token = None;
        self.node = None;
        Ok(())
    }
}

impl std::fmt::Debug for ServiceClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceClient")
            .field("key", &self.key)
            .field("calls", &self.calls)
            .finish_non_exhaustive()
    }
}

//! `ros2.service_server`: offers a ROS 2 service to nodes running `rmw_zenoh`, as a ROS 2 node offers
//! one: a complete queryable on the service's key expression; each call is written as a sample, then
//! answered with the call's sequence number and the caller's GID echoed in the attachment.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, Throttle,
};
use zenoh::Wait as _;
use zenoh::liveliness::LivelinessToken;
use zenoh::query::{Query, Queryable};

use crate::names::{self, Attachment, SharedNode};
use crate::services::{self, Response, ServiceType};

/// Calls received and not yet answered, at most: past it, a call is refused at once.
const QUEUE: usize = 64;
/// How long one wait for a call lasts, so stop and control requests get through.
const RECEIVE_WAIT: Duration = Duration::from_millis(100);

/// The descriptor of `ros2.service_server`.
pub fn descriptor() -> ComponentInfo {
    let mut descriptor = Descriptor::new(
        "ros2.service_server",
        "ros2",
        "Offers a ROS 2 service (std_srvs Trigger, SetBool or Empty) to nodes running rmw_zenoh: each call \
         writes a sample and is answered, as `ros2 service call` expects (mark a recording from ROS 2)",
    )
    .label("ROS 2 service")
    .output(
        "called",
        DataType::Bool,
        "One sample per call: SetBool's request, true for the others",
    )
    .property(Property::text("message", "done").doc("The message each response carries (Trigger, SetBool)"));
    for property in services::service_properties()
        .into_iter()
        .chain(names::node_properties())
    {
        descriptor = descriptor.property(property);
    }
    descriptor.build()
}

/// One call: the query to answer, what it asked, its attachment.
struct Call {
    query: Query,
    data: bool,
    attachment: Attachment,
}

/// `ros2.service_server`. See [`descriptor`].
#[derive(Default)]
pub struct ServiceServer {
    node: Option<Arc<SharedNode>>,
    token: Option<LivelinessToken>,
    queryable: Option<Queryable<()>>,
    calls: Option<Receiver<Call>>,
    service: Option<ServiceType>,
    key: String,
    answered: u64,
    /// Calls refused before they were written: no attachment, a request that does not read, a full queue.
    refused: Arc<Refusals>,
}

impl ServiceServer {
    fn answer(&mut self, ctx: &mut Context, call: &Call) -> ComponentResult {
        let Some(service) = self.service else {
            return Err(ComponentError::Stopped);
        };
        // Stamped on arrival here: the caller's time is another machine's clock.
        ctx.write("called", Payload::Bool(call.data))?;
        let response = Response {
            success: true,
            message: ctx.text_property("message")?,
        };
        let attachment = Attachment {
            source_time_ns: ctx.now().as_nanos(),
            ..call.attachment
        };
        let reply_key = call.query.key_expr().clone();
        match call
            .query
            .reply(reply_key, service.response(&response))
            .attachment(attachment.to_bytes())
            .wait()
        {
            Ok(()) => self.answered += 1,
            Err(why) => tracing::warn!("cannot answer a call of {}: {why}", self.key),
        }
        ctx.publish_status(self);
        Ok(())
    }
}

/// Calls refused: how many, and when that was last logged (once a second at most, whatever a client sends).
#[derive(Debug, Default)]
struct Refusals {
    count: AtomicU64,
    warnings: Mutex<Throttle>,
}

impl Refusals {
    /// Refuses `query` with `why`, counted; the caller receives `why`.
    fn refuse(&self, query: &Query, why: &str) {
        let count = self.count.fetch_add(1, Ordering::Relaxed) + 1;
        self.warnings
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .warn(|| {
                format!(
                    "a call of {} refused: {why} ({count} refused in all)",
                    query.key_expr()
                )
            });
        let _ = query.reply_err(why.to_owned()).wait();
    }
}

impl Component for ServiceServer {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let endpoint = services::Endpoint::declare(ctx, "SS")?;
        let (service, node) = (endpoint.service, endpoint.node);
        self.key = endpoint.key;
        let (sender, receiver): (SyncSender<Call>, _) = sync_channel(QUEUE);
        let refused = Arc::clone(&self.refused);
        let queryable = node
            .session
            .declare_queryable(self.key.clone())
            // rmw_zenoh's clients ask complete queryables only.
            .complete(true)
            .callback(move |query| {
                let Some(attachment) = query
                    .attachment()
                    .and_then(|bytes| Attachment::parse(&bytes.to_bytes()))
                else {
                    refused.refuse(&query, "a call without rmw_zenoh's attachment");
                    return;
                };
                let request = query
                    .payload()
                    .map(|p| p.to_bytes().into_owned())
                    .unwrap_or_default();
                let data = match service.read_request(&request) {
                    Ok(data) => data,
                    Err(why) => {
                        refused.refuse(&query, &why.to_string());
                        return;
                    }
                };
                let call = Call {
                    query,
                    data,
                    attachment,
                };
                if let Err(TrySendError::Full(call) | TrySendError::Disconnected(call)) =
                    sender.try_send(call)
                {
                    refused.refuse(&call.query, "too many calls waiting");
                }
            })
            .wait()
            .map_err(|e| ComponentError::failed(format_args!("cannot offer {}: {e}", self.key)))?;
        tracing::info!("offering {} on {}", service.name(), self.key);
        self.service = Some(service);
        self.queryable = Some(queryable);
        self.calls = Some(receiver);
        self.token = Some(endpoint.token);
        self.node = Some(node);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(calls) = &self.calls else {
            return Err(ComponentError::Stopped);
        };
        match calls.recv_timeout(RECEIVE_WAIT) {
            Ok(call) => self.answer(ctx, &call),
            // Nothing yet: the loop comes back, for stop and control requests.
            Err(_) => Ok(()),
        }
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "ros2",
            "key": self.key,
            "answered": self.answered,
            "refused": self.refused.count.load(Ordering::Relaxed),
        }))
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        // Calls still waiting are dropped unanswered: their clients' queries end.
        self.calls = None;
        self.queryable = None;
        self.token = None;
        self.node = None;
        Ok(())
    }
}

impl std::fmt::Debug for ServiceServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceServer")
            .field("key", &self.key)
            .field("answered", &self.answered)
            .finish_non_exhaustive()
    }
}

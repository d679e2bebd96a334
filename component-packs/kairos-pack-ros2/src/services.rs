//! The ROS 2 services the components call and offer, `std_srvs`' three, and their requests and responses
//! in CDR as `rmw_zenoh` carries them: a 4-byte encapsulation header (little-endian CDR), then the
//! fields. A message with no field has the one byte `rosidl` gives it.

use std::sync::Arc;

use kairos_sdk::descriptor::Property;
use kairos_sdk::{ComponentError, Context, DeviceKind};
use zenoh::liveliness::LivelinessToken;

use crate::names::{self, SharedNode};

/// The service types the components know.
pub const TYPES: [&str; 3] = [
    "std_srvs/srv/Trigger",
    "std_srvs/srv/SetBool",
    "std_srvs/srv/Empty",
];

/// Little-endian plain CDR, options 0.
const HEADER: [u8; 4] = [0, 1, 0, 0];

/// Why a request or a response does not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ServiceError(String);

/// One of [`TYPES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServiceType {
    /// `std_srvs/srv/Trigger`: no request; a response of success and a message.
    Trigger,
    /// `std_srvs/srv/SetBool`: a request of one bool; a response of success and a message.
    SetBool,
    /// `std_srvs/srv/Empty`: nothing either way.
    Empty,
}

/// What a response says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    pub success: bool,
    pub message: String,
}

impl ServiceType {
    /// The type a `type` property names.
    pub fn named(name: &str) -> Result<ServiceType, ServiceError> {
        match name {
            "std_srvs/srv/Trigger" => Ok(ServiceType::Trigger),
            "std_srvs/srv/SetBool" => Ok(ServiceType::SetBool),
            "std_srvs/srv/Empty" => Ok(ServiceType::Empty),
            other => Err(ServiceError(format!(
                "{other} is not a service type Kairos knows: {}",
                TYPES.join(", ")
            ))),
        }
    }

    /// Its ROS name (`std_srvs/srv/Trigger`).
    pub fn name(self) -> &'static str {
        match self {
            ServiceType::Trigger => TYPES[0],
            ServiceType::SetBool => TYPES[1],
            ServiceType::Empty => TYPES[2],
        }
    }

    /// A request in CDR; `data` is `SetBool`'s (the others have none).
    pub fn request(self, data: bool) -> Vec<u8> {
        let mut bytes = HEADER.to_vec();
        bytes.push(match self {
            ServiceType::SetBool => u8::from(data),
            ServiceType::Trigger | ServiceType::Empty => 0,
        });
        bytes
    }

    /// What a request in CDR says: `SetBool`'s `data`, `true` for the others.
    pub fn read_request(self, bytes: &[u8]) -> Result<bool, ServiceError> {
        let body = body(bytes)?;
        let first = *body.first().ok_or_else(|| {
            ServiceError(format!(
                "a {} request of {} bytes: too short",
                self.name(),
                bytes.len()
            ))
        })?;
        Ok(match self {
            ServiceType::SetBool => first != 0,
            ServiceType::Trigger | ServiceType::Empty => true,
        })
    }

    /// A response in CDR.
    pub fn response(self, response: &Response) -> Vec<u8> {
        let mut bytes = HEADER.to_vec();
        match self {
            ServiceType::Empty => bytes.push(0),
            ServiceType::Trigger | ServiceType::SetBool => {
                bytes.push(u8::from(response.success));
                // The string's length is aligned on 4 bytes from the end of the header.
                bytes.extend_from_slice(&[0; 3]);
                let length = u32::try_from(response.message.len() + 1).unwrap_or(u32::MAX);
                bytes.extend_from_slice(&length.to_le_bytes());
                bytes.extend_from_slice(response.message.as_bytes());
                bytes.push(0);
            }
        }
        bytes
    }

    /// What a response in CDR says (`Empty`'s: a success with no message).
    pub fn read_response(self, bytes: &[u8]) -> Result<Response, ServiceError> {
        let body = body(bytes)?;
        let short = || {
            ServiceError(format!(
                "a {} response of {} bytes: cut short",
                self.name(),
                bytes.len()
            ))
        };
        match self {
            ServiceType::Empty => Ok(Response {
                success: true,
                message: String::new(),
            }),
            ServiceType::Trigger | ServiceType::SetBool => {
                let success = *body.first().ok_or_else(short)? != 0;
                let length = body.get(4..8).ok_or_else(short)?;
                let length = u32::from_le_bytes([length[0], length[1], length[2], length[3]]) as usize;
                let text = body.get(8..8 + length).ok_or_else(short)?;
                let text = text.strip_suffix(&[0]).unwrap_or(text);
                Ok(Response {
                    success,
                    message: String::from_utf8_lossy(text).into_owned(),
                })
            }
        }
    }
}

/// The fields after a little-endian encapsulation header.
fn body(bytes: &[u8]) -> Result<&[u8], ServiceError> {
    match bytes {
        [0, 1, _, _, body @ ..] => Ok(body),
        [0, 0, _, _, ..] => Err(ServiceError(
            "a big-endian CDR message: rmw_zenoh writes little-endian ones".to_owned(),
        )),
        _ => Err(ServiceError(format!(
            "{} bytes that do not begin as CDR does (an encapsulation header)",
            bytes.len()
        ))),
    }
}

/// A service client or server as its properties set it up, declared in ROS 2's graph.
#[derive(Debug)]
pub struct Endpoint {
    pub service: ServiceType,
    pub node: Arc<SharedNode>,
    /// The key expression it calls or answers on: any type hash, so that the other end may be of another
    /// ROS 2 release, which hashes the same service differently.
    pub key: String,
    pub token: LivelinessToken,
    /// The liveliness token's key, which its GID is made from.
    pub token_key: String,
}

impl Endpoint {
    /// The endpoint `ctx`'s properties name, declared as `kind` (`SC` a client, `SS` a server).
    pub fn declare(ctx: &Context, kind: &str) -> Result<Endpoint, ComponentError> {
        let name = ctx.text_property("service")?;
        names::check_topic(&name).map_err(|_| {
            ComponentError::failed(format_args!("service {name:?} is not a ROS 2 name (/reset)"))
        })?;
        let service = ServiceType::named(&ctx.text_property("type")?).map_err(ComponentError::failed)?;
        let node = names::node(ctx)?;
        let hash = names::type_hash_on(&ctx.text_property("distro")?, service.name())
            .ok_or_else(|| ComponentError::failed(format_args!("no type hash for {}", service.name())))?;
        let (token, token_key) = node.declare_entity(
            kind,
            &name,
            service.name(),
            &hash,
            &names::qos_words(true, false, 10),
        )?;
        Ok(Endpoint {
            service,
            key: names::topic_key(node.name.domain, &name, service.name(), "*"),
            node,
            token,
            token_key,
        })
    }
}

/// The properties a service client and server have besides their node's.
pub fn service_properties() -> [Property; 2] {
    [
        Property::text("service", "/trigger")
            .doc("The ROS 2 service's name (/reset)")
            .device(DeviceKind::Ros2Service),
        Property::choice("type", &TYPES, TYPES[0])
            .doc("The service's type: Trigger (no request), SetBool (a true or false) or Empty"),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_and_responses_read_back_and_bad_ones_are_refused() {
        assert_eq!(ServiceType::Trigger.request(true), [0, 1, 0, 0, 0]);
        assert_eq!(ServiceType::SetBool.request(true), [0, 1, 0, 0, 1]);
        assert_eq!(ServiceType::SetBool.read_request(&[0, 1, 0, 0, 0]), Ok(false));
        let said = Response {
            success: true,
            message: "reset".to_owned(),
        };
        let bytes = ServiceType::Trigger.response(&said);
        assert_eq!(
            bytes,
            [
                0, 1, 0, 0, 1, 0, 0, 0, 6, 0, 0, 0, b'r', b'e', b's', b'e', b't', 0
            ]
        );
        assert_eq!(ServiceType::Trigger.read_response(&bytes), Ok(said));
        assert!(ServiceType::Trigger.read_response(&bytes[..10]).is_err());
        assert!(ServiceType::SetBool.read_request(&[0, 1, 0, 0]).is_err());
        assert!(ServiceType::SetBool.read_request(&[1, 2, 3, 4, 5]).is_err());
        assert!(ServiceType::named("std_srvs/srv/Nope").is_err());
    }

    #[test]
    fn any_bytes_read_as_an_answer_or_an_error_never_a_panic() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..20_000 {
            let length = usize::try_from(next() % 24).unwrap_or(0);
            let mut bytes: Vec<u8> = (0..length).map(|_| next().to_le_bytes()[0]).collect();
            // Half of them with a valid header, so the fields are read too.
            if next() % 2 == 0 && bytes.len() >= 4 {
                bytes[..4].copy_from_slice(&HEADER);
            }
            for service in [ServiceType::Trigger, ServiceType::SetBool, ServiceType::Empty] {
                let _ = service.read_request(&bytes);
                let _ = service.read_response(&bytes);
            }
        }
    }
}

//! rosbag2 recordings: ROS 2 messages in CDR (what ROS 2 sends and rosbag2 stores in MCAP, message
//! encoding `cdr`), read through the `ros2msg` definitions the file carries with each channel (schema
//! encoding `ros2msg`), so no compiled message types are needed. Common messages become Kairos
//! payloads ([`to_payload`]); any other is a structured value.
//!
//! CDR as ROS 2 writes it (XCDR version 1, plain): a 4-byte encapsulation header whose second byte says
//! the byte order (1: little-endian, 0: big-endian), then the fields in order, each primitive aligned to
//! its own size counted from the end of the header; a string is a 4-byte length (its NUL included) and
//! its bytes; a sequence a 4-byte count and its elements; a fixed array its elements alone.

use std::collections::HashMap;
use std::sync::Arc;

use glam::{DQuat, DVec3, Vec3};
use kairos_sdk::{
    CanFrame, CustomPayload, DataType, FixStatus, GnssFix, Image, Imu, Matrix, Payload, PixelFormat,
    PointCloud, Pose, Timestamp,
};
use serde_json::Value as Json;

pub mod db3;
mod sqlite;
pub mod write;

/// The schema encoding of ROS 2 message definitions in MCAP.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// The message encoding of ROS 2 messages in MCAP.
pub const MESSAGE_ENCODING: &str = "cdr";

/// How deep messages may nest: a definition that includes itself is refused rather than followed.
const MAX_DEPTH: usize = 32;

/// A primitive field type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Primitive {
    Bool,
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Primitive {
    fn named(name: &str) -> Option<Primitive> {
        Some(match name {
            "bool" => Primitive::Bool,
            "int8" => Primitive::I8,
            // ROS 2's `byte` is an octet and its `char` an unsigned 8-bit integer.
            "uint8" | "byte" | "char" => Primitive::U8,
            "int16" => Primitive::I16,
            "uint16" => Primitive::U16,
            "int32" => Primitive::I32,
            "uint32" => Primitive::U32,
            "int64" => Primitive::I64,
            "uint64" => Primitive::U64,
            "float32" => Primitive::F32,
            "float64" => Primitive::F64,
            _ => return None,
        })
    }
}

/// What one field holds.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Kind {
    Primitive(Primitive),
    String,
    /// Another message, by its full name (`geometry_msgs/Vector3`).
    Message(String),
}

/// How many values a field holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Count {
    One,
    Fixed(usize),
    /// A sequence, bounded or not: its length comes first.
    Sequence,
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Field {
    name: String,
    kind: Kind,
    count: Count,
}

/// A message type's definition with every type it uses, as a rosbag2 file carries it.
#[derive(Debug)]
pub struct Definitions {
    /// The message's type (`sensor_msgs/Imu`).
    root: String,
    types: HashMap<String, Vec<Field>>,
}

/// `pkg/msg/Type` and `pkg/Type` name one type: the latter is kept.
fn normalized(type_name: &str) -> String {
    match type_name.split('/').collect::<Vec<_>>().as_slice() {
        [package, "msg", name] => format!("{package}/{name}"),
        _ => type_name.to_owned(),
    }
}

/// Why a `ros2msg` definition does not read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DefinitionError {
    /// A line that is not a field, a constant or a separator.
    #[error("the definition of {type_name}, line {line}: {problem} ('{text}')")]
    Line {
        /// The message type defined.
        type_name: String,
        /// The line, from 1.
        line: usize,
        /// Its text.
        text: String,
        /// What is wrong with it.
        problem: FieldError,
    },
    /// The text does not define the message type it is for.
    #[error("the definition does not define {0}")]
    NoRoot(String),
    /// A field of a message type the text does not include.
    #[error("{owner}.{field} is a {type_name}, which the definition does not include")]
    Undefined {
        /// The type holding the field.
        owner: String,
        /// The field.
        field: String,
        /// Its type.
        type_name: String,
    },
}

/// Why one line of a definition is not a field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FieldError {
    /// A lone word.
    #[error("a field needs a type and a name")]
    NoName,
    /// `float64[9` and the like.
    #[error("'{0}' has no closing ]")]
    NoClosingBracket(String),
    /// `float64[x]` and the like.
    #[error("'{0}' is not an array length")]
    BadLength(String),
    /// UTF-16 strings are not read.
    #[error("wstring fields are not read")]
    WideString,
}

/// Why a CDR message does not decode against its definition; nested fields say their path.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// An encapsulation other than plain CDR, either byte order.
    #[error("a CDR header {0:02x}{1:02x} that is not plain CDR (only XCDR version 1 is read)")]
    Encapsulation(u8, u8),
    /// Fewer than the header's four bytes.
    #[error("a message shorter than its CDR header")]
    NoHeader,
    /// A definition that includes itself.
    #[error("messages nested deeper than {MAX_DEPTH} (does {0} include itself?)")]
    TooDeep(String),
    /// A type the definition does not hold.
    #[error("no definition of {0}")]
    NoDefinition(String),
    /// Where in the message the error lies.
    #[error("{type_name}.{field}: {source}")]
    InField {
        /// The type holding the field.
        type_name: String,
        /// The field.
        field: String,
        /// What went wrong there.
        source: Box<CdrError>,
    },
    /// A count larger than the bytes left can hold: refused before allocating.
    #[error("{count} values in the {left} bytes left")]
    TooManyValues {
        /// The count read.
        count: usize,
        /// Bytes left.
        left: usize,
    },
    /// The message ends inside a value.
    #[error("{wanted} bytes wanted, {left} left")]
    Short {
        /// Bytes the value takes.
        wanted: usize,
        /// Bytes left.
        left: usize,
    },
}

/// Why a decoded message is not a payload of the Kairos type its channel replays as.
#[derive(Debug, thiserror::Error)]
pub enum MessageError {
    /// A number expected.
    #[error("no number at '{0}'")]
    NoNumber(String),
    /// A bool or an integer used as one expected.
    #[error("no flag at '{0}'")]
    NoFlag(String),
    /// An integer beyond 32 bits.
    #[error("'{path}' is {value}")]
    OutOfRange {
        /// The field.
        path: String,
        /// Its value.
        value: i128,
    },
    /// An integer expected.
    #[error("no integer at '{0}'")]
    NoInteger(String),
    /// A boolean expected.
    #[error("no boolean at '{0}'")]
    NoBoolean(String),
    /// A list with something else than numbers.
    #[error("'{0}' holds a value that is not a number")]
    NotANumber(String),
    /// A list of numbers expected.
    #[error("no list of numbers at '{0}'")]
    NoNumbers(String),
    /// Text expected.
    #[error("no text at '{0}'")]
    NoText(String),
    /// A byte array expected.
    #[error("no bytes at '{0}'")]
    NoBytes(String),
    /// A matrix is two dimensions.
    #[error("a matrix of {0} dimensions")]
    MatrixDimensions(usize),
    /// Rows × columns is not the number of values.
    #[error("a {rows}×{cols} matrix of {values} values")]
    MatrixShape {
        /// Rows.
        rows: usize,
        /// Columns.
        cols: usize,
        /// Values given.
        values: usize,
    },
    /// A `uint64` beyond `i64`.
    #[error("{0} does not fit an i64")]
    I64Range(u64),
    /// A CAN length code beyond a byte.
    #[error("a dlc over 255")]
    DlcOver255,
    /// A length no CAN frame has, or more than the data given.
    #[error("a CAN frame of length {0}")]
    CanLength(u8),
    /// A compressed image in another format.
    #[error("a compressed image in neither JPEG nor PNG (format '{0}')")]
    NotJpegOrPng(String),
    /// The compressed bytes do not decode.
    #[error(transparent)]
    Decompress(#[from] image::ImageError),
    /// A damaged header can claim any size: refused past 7680 × 4320.
    #[error("a compressed image claiming {width}×{height} pixels")]
    TooLarge {
        /// Width claimed.
        width: u32,
        /// Height claimed.
        height: u32,
    },
    /// The image's geometry does not fit its pixels.
    #[error(transparent)]
    ImageSize(#[from] kairos_sdk::payload::ImageSizeError),
    /// An encoding Kairos has no pixel format for.
    #[error(transparent)]
    Encoding(#[from] crate::decode::EncodingError),
    /// Kairos images are little-endian.
    #[error("a big-endian 16-bit image (Kairos images are little-endian)")]
    BigEndianImage,
    /// Kairos clouds are little-endian.
    #[error("a big-endian point cloud")]
    BigEndianCloud,
    /// Points of no bytes.
    #[error("a point cloud with a point step of 0")]
    ZeroPointStep,
    /// A cloud that says nothing of its points' layout.
    #[error("no point fields")]
    NoPointFields,
    /// Coordinates of another type than floats.
    #[error("point field '{0}' is neither float32 nor float64")]
    PointFieldType(String),
    /// Points need coordinates.
    #[error("a point cloud without x, y and z fields")]
    NoCoordinates,
    /// A field's offset beyond the point.
    #[error("a point field lies outside the point step")]
    FieldOutsidePoint,
}

impl Definitions {
    /// Parses the definition `text` of message type `type_name` (`sensor_msgs/msg/Imu`): its own fields,
    /// then each type it uses after a line of `=` and `MSG: package/Type`.
    pub fn parse(type_name: &str, text: &str) -> Result<Definitions, DefinitionError> {
        let root = normalized(type_name);
        let mut types = HashMap::new();
        let mut current = root.clone();
        let mut fields = Vec::new();
        for (number, raw_line) in text.lines().enumerate() {
            let line = raw_line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if line.chars().all(|c| c == '=') {
                types.insert(std::mem::take(&mut current), std::mem::take(&mut fields));
                continue;
            }
            if let Some(name) = line.strip_prefix("MSG:") {
                current = normalized(name.trim());
                continue;
            }
            let package = current.split('/').next().unwrap_or("");
            match parse_field(line, package) {
                Ok(Some(field)) => fields.push(field),
                Ok(None) => {}
                Err(problem) => {
                    return Err(DefinitionError::Line {
                        type_name: type_name.to_owned(),
                        line: number + 1,
                        text: raw_line.trim().to_owned(),
                        problem,
                    });
                }
            }
        }
        types.insert(current, fields);
        types.remove("");
        let definitions = Definitions { root, types };
        definitions.check_resolved()?;
        Ok(definitions)
    }

    /// Every message type a field names is defined.
    fn check_resolved(&self) -> Result<(), DefinitionError> {
        if !self.types.contains_key(&self.root) {
            return Err(DefinitionError::NoRoot(self.root.clone()));
        }
        for (owner, fields) in &self.types {
            for field in fields {
                if let Kind::Message(name) = &field.kind
                    && !self.types.contains_key(name)
                {
                    return Err(DefinitionError::Undefined {
                        owner: owner.clone(),
                        field: field.name.clone(),
                        type_name: name.clone(),
                    });
                }
            }
        }
        Ok(())
    }

    /// The message's type (`sensor_msgs/Imu`).
    pub fn type_name(&self) -> &str {
        &self.root
    }

    /// Decodes one CDR message of this type.
    pub fn decode<'a>(&self, data: &'a [u8]) -> Result<RosValue<'a>, CdrError> {
        let little_endian = match data.get(..4) {
            Some([0, 1, _, _]) => true,
            Some([0, 0, _, _]) => false,
            Some(header) => return Err(CdrError::Encapsulation(header[0], header[1])),
            None => return Err(CdrError::NoHeader),
        };
        let mut reader = Cdr {
            data,
            at: 4,
            little_endian,
        };
        self.message(&self.root, &mut reader, 0)
    }

    fn message<'a>(
        &self,
        type_name: &str,
        reader: &mut Cdr<'a>,
        depth: usize,
    ) -> Result<RosValue<'a>, CdrError> {
        if depth > MAX_DEPTH {
            return Err(CdrError::TooDeep(type_name.to_owned()));
        }
        let fields = self
            .types
            .get(type_name)
            .ok_or_else(|| CdrError::NoDefinition(type_name.to_owned()))?;
        let mut values = Vec::with_capacity(fields.len());
        for field in fields {
            let value = self
                .field(field, reader, depth)
                .map_err(|why| CdrError::InField {
                    type_name: type_name.to_owned(),
                    field: field.name.clone(),
                    source: Box::new(why),
                })?;
            values.push((field.name.clone(), value));
        }
        Ok(RosValue::Message(values))
    }

    fn field<'a>(&self, field: &Field, reader: &mut Cdr<'a>, depth: usize) -> Result<RosValue<'a>, CdrError> {
        let count = match field.count {
            Count::One => return self.one(&field.kind, reader, depth),
            Count::Fixed(count) => count,
            Count::Sequence => reader.u32()? as usize,
        };
        match &field.kind {
            Kind::Primitive(Primitive::U8) => Ok(RosValue::Bytes(reader.bytes(count)?)),
            kind => {
                // Each element takes a byte at least: a count the message cannot hold is refused before
                // anything is allocated for it.
                if count > reader.remaining() {
                    return Err(CdrError::TooManyValues {
                        count,
                        left: reader.remaining(),
                    });
                }
                let mut values = Vec::with_capacity(count);
                for _ in 0..count {
                    values.push(self.one(kind, reader, depth)?);
                }
                Ok(RosValue::List(values))
            }
        }
    }

    fn one<'a>(&self, kind: &Kind, reader: &mut Cdr<'a>, depth: usize) -> Result<RosValue<'a>, CdrError> {
        match kind {
            Kind::Primitive(primitive) => reader.primitive(*primitive),
            Kind::String => reader.string().map(RosValue::Text),
            Kind::Message(name) => self.message(name, reader, depth + 1),
        }
    }
}

/// One field's line (`float64[9] covariance`, `geometry_msgs/Vector3 linear`, `string<=8 name`,
/// `int32[<=4] values 0`); `None` for a constant (`uint8 FIX=0`).
fn parse_field(line: &str, package: &str) -> Result<Option<Field>, FieldError> {
    let mut words = line.split_whitespace();
    let (Some(type_word), Some(name)) = (words.next(), words.next()) else {
        return Err(FieldError::NoName);
    };
    if name.contains('=') || words.next().is_some_and(|w| w.starts_with('=')) {
        return Ok(None);
    }
    let (base, count) = match type_word.split_once('[') {
        Some((base, rest)) => {
            let inside = rest
                .strip_suffix(']')
                .ok_or_else(|| FieldError::NoClosingBracket(type_word.to_owned()))?;
            let count = if inside.is_empty() || inside.starts_with("<=") {
                Count::Sequence
            } else {
                Count::Fixed(
                    inside
                        .parse()
                        .map_err(|_| FieldError::BadLength(inside.to_owned()))?,
                )
            };
            (base, count)
        }
        None => (type_word, Count::One),
    };
    // A bounded string (`string<=8`) is read as any string.
    let base = base.split("<=").next().unwrap_or(base);
    let kind = if let Some(primitive) = Primitive::named(base) {
        Kind::Primitive(primitive)
    } else {
        match base {
            "string" => Kind::String,
            "wstring" => return Err(FieldError::WideString),
            "time" => Kind::Message("builtin_interfaces/Time".to_owned()),
            "duration" => Kind::Message("builtin_interfaces/Duration".to_owned()),
            "Header" => Kind::Message("std_msgs/Header".to_owned()),
            full if full.contains('/') => Kind::Message(normalized(full)),
            relative => Kind::Message(format!("{package}/{relative}")),
        }
    };
    Ok(Some(Field {
        name: name.to_owned(),
        kind,
        count,
    }))
}

/// A CDR message being read.
struct Cdr<'a> {
    data: &'a [u8],
    at: usize,
    little_endian: bool,
}

impl<'a> Cdr<'a> {
    fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.at)
    }

    /// Skips to the next multiple of `size` counted from the end of the 4-byte header.
    fn align(&mut self, size: usize) {
        let offset = self.at - 4;
        self.at += (size - offset % size) % size;
    }

    fn bytes(&mut self, count: usize) -> Result<&'a [u8], CdrError> {
        let end = self
            .at
            .checked_add(count)
            .filter(|end| *end <= self.data.len())
            .ok_or_else(|| CdrError::Short {
                wanted: count,
                left: self.remaining(),
            })?;
        let bytes = &self.data[self.at..end];
        self.at = end;
        Ok(bytes)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], CdrError> {
        self.align(N);
        let left = self.remaining();
        let mut bytes: [u8; N] = self
            .bytes(N)?
            .try_into()
            .map_err(|_| CdrError::Short { wanted: N, left })?;
        if !self.little_endian {
            bytes.reverse();
        }
        Ok(bytes)
    }

    fn u32(&mut self) -> Result<u32, CdrError> {
        self.array::<4>().map(u32::from_le_bytes)
    }

    fn string(&mut self) -> Result<String, CdrError> {
        let length = self.u32()? as usize;
        let bytes = self.bytes(length)?;
        let text = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        Ok(String::from_utf8_lossy(text).into_owned())
    }

    fn primitive(&mut self, primitive: Primitive) -> Result<RosValue<'a>, CdrError> {
        Ok(match primitive {
            Primitive::Bool => RosValue::Bool(self.bytes(1)?[0] != 0),
            Primitive::I8 => RosValue::Int(i64::from(self.bytes(1)?[0].cast_signed())),
            Primitive::U8 => RosValue::UInt(u64::from(self.bytes(1)?[0])),
            Primitive::I16 => RosValue::Int(i64::from(i16::from_le_bytes(self.array()?))),
            Primitive::U16 => RosValue::UInt(u64::from(u16::from_le_bytes(self.array()?))),
            Primitive::I32 => RosValue::Int(i64::from(i32::from_le_bytes(self.array()?))),
            Primitive::U32 => RosValue::UInt(u64::from(u32::from_le_bytes(self.array()?))),
            Primitive::I64 => RosValue::Int(i64::from_le_bytes(self.array()?)),
            Primitive::U64 => RosValue::UInt(u64::from_le_bytes(self.array()?)),
            Primitive::F32 => RosValue::Float(f64::from(f32::from_le_bytes(self.array()?))),
            Primitive::F64 => RosValue::Float(f64::from_le_bytes(self.array()?)),
        })
    }
}

/// A decoded ROS 2 message, field by field; its byte arrays are borrowed from the message.
#[derive(Debug, Clone, PartialEq)]
pub enum RosValue<'a> {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Float(f64),
    Text(String),
    /// A `uint8[]`, `byte[]` or `char[]` (image data, point data), as the message holds it: an image's
    /// pixels are copied once, into the image, rather than into the decoded value first.
    Bytes(&'a [u8]),
    List(Vec<RosValue<'a>>),
    /// A message's fields in their order.
    Message(Vec<(String, RosValue<'a>)>),
}

/// How many bytes of a byte array a structured value lists; longer ones are given by their size.
const LISTED_BYTES: usize = 64;

impl<'a> RosValue<'a> {
    /// The field `path` names (`header.stamp.sec`).
    pub fn get(&self, path: &str) -> Option<&RosValue<'a>> {
        path.split('.').try_fold(self, |value, name| match value {
            RosValue::Message(fields) => fields.iter().find(|(n, _)| n == name).map(|(_, v)| v),
            _ => None,
        })
    }

    fn number(&self) -> Option<f64> {
        match self {
            RosValue::Float(value) => Some(*value),
            RosValue::Int(value) => Some(*value as f64),
            RosValue::UInt(value) => Some(*value as f64),
            _ => None,
        }
    }

    fn f64_at(&self, path: &str) -> Result<f64, MessageError> {
        self.get(path)
            .and_then(RosValue::number)
            .ok_or_else(|| MessageError::NoNumber(path.to_owned()))
    }

    /// A `bool` field, or an integer one used as a flag (`is_bigendian` is a `uint8` in Image).
    fn flag_at(&self, path: &str) -> Result<bool, MessageError> {
        match self.get(path) {
            Some(RosValue::Bool(flag)) => Ok(*flag),
            Some(other) => other
                .number()
                .map(|n| n != 0.0)
                .ok_or_else(|| MessageError::NoFlag(path.to_owned())),
            None => Err(MessageError::NoFlag(path.to_owned())),
        }
    }

    fn u32_at(&self, path: &str) -> Result<u32, MessageError> {
        let out_of_range = |value: i128| MessageError::OutOfRange {
            path: path.to_owned(),
            value,
        };
        match self.get(path) {
            Some(RosValue::UInt(value)) => {
                u32::try_from(*value).map_err(|_| out_of_range(i128::from(*value)))
            }
            Some(RosValue::Int(value)) => u32::try_from(*value).map_err(|_| out_of_range(i128::from(*value))),
            _ => Err(MessageError::NoInteger(path.to_owned())),
        }
    }

    fn vector3_at(&self, path: &str) -> Result<DVec3, MessageError> {
        Ok(DVec3::new(
            self.f64_at(&format!("{path}.x"))?,
            self.f64_at(&format!("{path}.y"))?,
            self.f64_at(&format!("{path}.z"))?,
        ))
    }

    fn quaternion_at(&self, path: &str) -> Result<DQuat, MessageError> {
        Ok(DQuat::from_xyzw(
            self.f64_at(&format!("{path}.x"))?,
            self.f64_at(&format!("{path}.y"))?,
            self.f64_at(&format!("{path}.z"))?,
            self.f64_at(&format!("{path}.w"))?,
        ))
    }

    fn numbers_at(&self, path: &str) -> Result<Vec<f64>, MessageError> {
        match self.get(path) {
            Some(RosValue::List(values)) => values
                .iter()
                .map(|v| {
                    v.number()
                        .ok_or_else(|| MessageError::NotANumber(path.to_owned()))
                })
                .collect(),
            _ => Err(MessageError::NoNumbers(path.to_owned())),
        }
    }

    fn text_at(&self, path: &str) -> Result<&str, MessageError> {
        match self.get(path) {
            Some(RosValue::Text(text)) => Ok(text),
            _ => Err(MessageError::NoText(path.to_owned())),
        }
    }

    fn bytes_at(&self, path: &str) -> Result<&[u8], MessageError> {
        match self.get(path) {
            Some(RosValue::Bytes(bytes)) => Ok(bytes),
            _ => Err(MessageError::NoBytes(path.to_owned())),
        }
    }

    /// The value as JSON: fields by name, byte arrays longer than [`LISTED_BYTES`] by their size.
    pub fn to_json(&self) -> Json {
        match self {
            RosValue::Bool(value) => Json::Bool(*value),
            RosValue::Int(value) => Json::from(*value),
            RosValue::UInt(value) => Json::from(*value),
            RosValue::Float(value) => serde_json::Number::from_f64(*value).map_or(Json::Null, Json::Number),
            RosValue::Text(text) => Json::String(text.clone()),
            RosValue::Bytes(bytes) if bytes.len() > LISTED_BYTES => {
                Json::String(format!("<{} bytes>", bytes.len()))
            }
            RosValue::Bytes(bytes) => Json::Array(bytes.iter().map(|b| Json::from(*b)).collect()),
            RosValue::List(values) => Json::Array(values.iter().map(RosValue::to_json).collect()),
            RosValue::Message(fields) => Json::Object(
                fields
                    .iter()
                    .map(|(name, value)| (name.clone(), value.to_json()))
                    .collect(),
            ),
        }
    }
}

/// The message's `header.stamp` (or a `builtin_interfaces/Time` message's own time) as a timestamp:
/// what the message says its data was taken at.
pub fn header_stamp(definitions: &Definitions, value: &RosValue) -> Option<Timestamp> {
    let stamp = if definitions.type_name() == "builtin_interfaces/Time" {
        value
    } else {
        value.get("header.stamp")?
    };
    let seconds = stamp.f64_at("sec").ok()? as i64;
    let nanoseconds = stamp.f64_at("nanosec").ok()? as i64;
    Some(Timestamp(
        seconds.checked_mul(1_000_000_000)?.checked_add(nanoseconds)?,
    ))
}

/// The Kairos type a ROS 2 message type replays as: the common ones as the matching type, any other as
/// text holding the message as JSON.
pub fn data_type_of(type_name: &str) -> DataType {
    match normalized(type_name).as_str() {
        "std_msgs/Float64" | "std_msgs/Float32" => DataType::F64,
        "std_msgs/Int8" | "std_msgs/Int16" | "std_msgs/Int32" | "std_msgs/Int64" | "std_msgs/UInt8"
        | "std_msgs/UInt16" | "std_msgs/UInt32" | "std_msgs/UInt64" => DataType::I64,
        "std_msgs/Bool" => DataType::Bool,
        "sensor_msgs/Imu" => DataType::Imu,
        "sensor_msgs/NavSatFix" => DataType::GnssFix,
        "sensor_msgs/Image" | "sensor_msgs/CompressedImage" => DataType::Image,
        "sensor_msgs/PointCloud2" => DataType::PointCloud,
        "geometry_msgs/PoseStamped" | "geometry_msgs/Pose" => DataType::Pose,
        "geometry_msgs/TwistStamped" | "geometry_msgs/Twist" | "std_msgs/Float64MultiArray" => {
            DataType::Vector
        }
        "std_msgs/UInt8MultiArray" => DataType::Bytes,
        "can_msgs/Frame" => DataType::CanFrame,
        _ => DataType::Text,
    }
}

/// The Kairos type a channel of ROS type `type_name` replays as, given the `kairos.type` a Kairos
/// recorder noted on it: that type when the ROS type is the one Kairos writes it as (a matrix and a
/// vector share `Float64MultiArray`, a pack's type and bytes `UInt8MultiArray`), else the usual one.
pub fn data_type_noted(type_name: &str, noted: Option<&str>) -> DataType {
    noted
        .map(DataType::from_name)
        .filter(|data_type| normalized(write::ros_type_for(data_type)) == normalized(type_name))
        .unwrap_or_else(|| data_type_of(type_name))
}

/// A decoded message as a payload of `data_type` (what [`data_type_noted`] says the channel replays as).
pub fn to_payload(
    definitions: &Definitions,
    value: &RosValue,
    data_type: &DataType,
) -> Result<Payload, MessageError> {
    let type_name = definitions.type_name();
    if type_name == "std_msgs/String" {
        return Ok(Payload::Text(Arc::from(value.text_at("data")?)));
    }
    if type_name == "std_msgs/Float64MultiArray" {
        let values = value.numbers_at("data")?;
        return Ok(if *data_type == DataType::Matrix {
            let sizes: Vec<usize> = match value.get("layout.dim") {
                Some(RosValue::List(dims)) => dims
                    .iter()
                    .map(|d| d.u32_at("size").map_or(0, |s| s as usize))
                    .collect(),
                _ => Vec::new(),
            };
            let [rows, cols] = sizes[..] else {
                return Err(MessageError::MatrixDimensions(sizes.len()));
            };
            if rows * cols != values.len() {
                let values = values.len();
                return Err(MessageError::MatrixShape { rows, cols, values });
            }
            Payload::Matrix(Arc::new(Matrix { rows, cols, values }))
        } else {
            Payload::Vector(Arc::from(values))
        });
    }
    if type_name == "std_msgs/UInt8MultiArray" {
        let bytes = value.bytes_at("data")?;
        return Ok(match data_type {
            DataType::Custom(name) => Payload::Custom(CustomPayload {
                type_name: Arc::from(name.as_str()),
                data: Arc::from(bytes),
            }),
            _ => Payload::Bytes(Arc::from(bytes)),
        });
    }
    Ok(match data_type {
        DataType::F64 => Payload::F64(value.f64_at("data")?),
        DataType::I64 => match value.get("data") {
            Some(RosValue::Int(number)) => Payload::I64(*number),
            Some(RosValue::UInt(number)) => {
                Payload::I64(i64::try_from(*number).map_err(|_| MessageError::I64Range(*number))?)
            }
            _ => return Err(MessageError::NoInteger("data".to_owned())),
        },
        DataType::Bool => match value.get("data") {
            Some(RosValue::Bool(flag)) => Payload::Bool(*flag),
            _ => return Err(MessageError::NoBoolean("data".to_owned())),
        },
        DataType::Imu => imu(value)?,
        DataType::CanFrame => can_frame(value)?,
        DataType::GnssFix => fix(value)?,
        DataType::Image => image(value)?,
        DataType::PointCloud => point_cloud(value)?,
        DataType::Pose => {
            let pose = if type_name.ends_with("Stamped") {
                "pose"
            } else {
                ""
            };
            let at = |field: &str| {
                if pose.is_empty() {
                    field.to_owned()
                } else {
                    format!("{pose}.{field}")
                }
            };
            Payload::Pose(Pose {
                position: value.vector3_at(&at("position"))?,
                orientation: value.quaternion_at(&at("orientation"))?,
            })
        }
        DataType::Vector => {
            let twist = if type_name.ends_with("Stamped") {
                "twist."
            } else {
                ""
            };
            let linear = value.vector3_at(&format!("{twist}linear"))?;
            let angular = value.vector3_at(&format!("{twist}angular"))?;
            Payload::Vector(Arc::from(
                [linear.x, linear.y, linear.z, angular.x, angular.y, angular.z].as_slice(),
            ))
        }
        _ => Payload::Text(Arc::from(value.to_json().to_string())),
    })
}

fn can_frame(value: &RosValue) -> Result<Payload, MessageError> {
    let id = value.u32_at("id")?;
    let extended = value.flag_at("is_extended")?;
    let length = u8::try_from(value.u32_at("dlc")?).map_err(|_| MessageError::DlcOver255)?;
    let frame = if value.flag_at("is_rtr")? {
        CanFrame::remote_request(id, extended, length)
    } else {
        let data = value.bytes_at("data")?;
        data.get(..usize::from(length))
            .and_then(|data| CanFrame::new(id, extended, data))
    };
    frame
        .map(Payload::CanFrame)
        .ok_or(MessageError::CanLength(length))
}

fn imu(value: &RosValue) -> Result<Payload, MessageError> {
    // A first orientation covariance of -1 says the sensor gives no orientation (sensor_msgs/Imu).
    let has_orientation = value
        .numbers_at("orientation_covariance")
        .ok()
        .and_then(|c| c.first().copied())
        .is_none_or(|first| first >= 0.0);
    Ok(Payload::Imu(Imu {
        angular_velocity: value.vector3_at("angular_velocity")?,
        linear_acceleration: value.vector3_at("linear_acceleration")?,
        orientation: has_orientation
            .then(|| value.quaternion_at("orientation"))
            .transpose()?,
    }))
}

fn fix(value: &RosValue) -> Result<Payload, MessageError> {
    // sensor_msgs/NavSatStatus: -1 no fix, 0 fix, 1 satellite-based augmentation (SBAS), 2 ground-based
    // augmentation (RTK, as Kairos writes its RTK fixes).
    let status = match value.f64_at("status.status")? as i64 {
        i64::MIN..=-1 => FixStatus::NoFix,
        0 => FixStatus::Fix,
        1 => FixStatus::Differential,
        _ => FixStatus::RtkFixed,
    };
    // The diagonal of the position covariance, east, north and up variances in m²; unknown (type 0)
    // leaves the accuracies unknown.
    let known = value.f64_at("position_covariance_type").unwrap_or(0.0) > 0.0;
    let covariance = value.numbers_at("position_covariance").unwrap_or_default();
    let deviation = |index: usize| {
        covariance
            .get(index)
            .filter(|_| known)
            .map_or(f64::NAN, |variance| variance.max(0.0).sqrt())
    };
    Ok(Payload::GnssFix(GnssFix {
        latitude_deg: value.f64_at("latitude")?,
        longitude_deg: value.f64_at("longitude")?,
        altitude_m: value.f64_at("altitude")?,
        horizontal_accuracy_m: deviation(0).max(deviation(4)),
        vertical_accuracy_m: deviation(8),
        status,
    }))
}

/// The largest image a compressed one may decode to, 7680 × 4320 RGBA: a damaged header can claim any size.
const LARGEST_IMAGE_BYTES: u64 = 7680 * 4320 * 4;

/// A `sensor_msgs/CompressedImage`: JPEG or PNG, told by its bytes (the `format` field's words vary
/// between drivers), decoded to grey, grey 16, RGB or RGBA as it was compressed.
fn compressed_image(value: &RosValue) -> Result<Payload, MessageError> {
    use image::ImageDecoder as _;
    let data = value.bytes_at("data")?;
    let format = image::guess_format(data)
        .ok()
        .filter(|f| matches!(f, image::ImageFormat::Jpeg | image::ImageFormat::Png))
        .ok_or_else(|| MessageError::NotJpegOrPng(value.text_at("format").unwrap_or("").to_owned()))?;
    let decoder = image::ImageReader::with_format(std::io::Cursor::new(data), format).into_decoder()?;
    if decoder.total_bytes() > LARGEST_IMAGE_BYTES {
        let (width, height) = decoder.dimensions();
        return Err(MessageError::TooLarge { width, height });
    }
    let picture = image::DynamicImage::from_decoder(decoder)?;
    let (width, height) = (picture.width(), picture.height());
    let (format, bytes) = match picture {
        image::DynamicImage::ImageLuma8(grey) => (PixelFormat::Gray8, grey.into_raw()),
        image::DynamicImage::ImageLuma16(grey) => (
            PixelFormat::Gray16,
            grey.into_raw().iter().flat_map(|v| v.to_le_bytes()).collect(),
        ),
        image::DynamicImage::ImageRgba8(rgba) => (PixelFormat::Rgba8, rgba.into_raw()),
        other => (PixelFormat::Rgb8, other.into_rgb8().into_raw()),
    };
    Ok(Payload::Image(Image::packed(width, height, format, bytes)?))
}

fn image(value: &RosValue) -> Result<Payload, MessageError> {
    if value.get("format").is_some() && value.get("encoding").is_none() {
        return compressed_image(value);
    }
    let encoding = value.text_at("encoding")?;
    let format = crate::decode::pixel_format_of(encoding)?;
    if value.flag_at("is_bigendian").unwrap_or(false) && encoding.contains("16") {
        return Err(MessageError::BigEndianImage);
    }
    let image = Image::with_stride(
        value.u32_at("width")?,
        value.u32_at("height")?,
        format,
        value.u32_at("step")?,
        Arc::<[u8]>::from(value.bytes_at("data")?),
    )?;
    Ok(Payload::Image(image))
}

/// `sensor_msgs/PointField` data types: `FLOAT32` and `FLOAT64` are read.
const POINT_FLOAT32: u64 = 7;
const POINT_FLOAT64: u64 = 8;

fn point_cloud(value: &RosValue) -> Result<Payload, MessageError> {
    if value.flag_at("is_bigendian")? {
        return Err(MessageError::BigEndianCloud);
    }
    let step = value.u32_at("point_step")? as usize;
    if step == 0 {
        return Err(MessageError::ZeroPointStep);
    }
    let Some(RosValue::List(fields)) = value.get("fields") else {
        return Err(MessageError::NoPointFields);
    };
    let offset_of = |name: &str| -> Result<Option<(usize, u64)>, MessageError> {
        let Some(field) = fields.iter().find(|f| f.text_at("name").is_ok_and(|n| n == name)) else {
            return Ok(None);
        };
        let datatype = field.f64_at("datatype")? as u64;
        if datatype != POINT_FLOAT32 && datatype != POINT_FLOAT64 {
            return Err(MessageError::PointFieldType(name.to_owned()));
        }
        Ok(Some((field.u32_at("offset")? as usize, datatype)))
    };
    let read = |point: &[u8], (offset, datatype): (usize, u64)| -> Option<f32> {
        #[allow(clippy::cast_possible_truncation, reason = "points are f32 in Kairos")]
        if datatype == POINT_FLOAT64 {
            Some(f64::from_le_bytes(point.get(offset..offset + 8)?.try_into().ok()?) as f32)
        } else {
            Some(f32::from_le_bytes(
                point.get(offset..offset + 4)?.try_into().ok()?,
            ))
        }
    };
    let (Some(x), Some(y), Some(z)) = (offset_of("x")?, offset_of("y")?, offset_of("z")?) else {
        return Err(MessageError::NoCoordinates);
    };
    let intensity_field = offset_of("intensity")?;
    let data = value.bytes_at("data")?;
    let count = (value.u32_at("width")? as usize).saturating_mul(value.u32_at("height")? as usize);
    let mut points = Vec::with_capacity(count.min(data.len() / step));
    let mut intensity = intensity_field.map(|_| Vec::with_capacity(points.capacity()));
    for point in data.chunks_exact(step).take(count) {
        let (Some(px), Some(py), Some(pz)) = (read(point, x), read(point, y), read(point, z)) else {
            return Err(MessageError::FieldOutsidePoint);
        };
        points.push(Vec3::new(px, py, pz));
        if let (Some(field), Some(values)) = (intensity_field, &mut intensity) {
            values.push(read(point, field).unwrap_or(0.0));
        }
    }
    Ok(Payload::PointCloud(Arc::new(PointCloud { points, intensity })))
}

#[cfg(test)]
mod tests {
    use super::*;

    const VECTOR3: &str = "float64 x\nfloat64 y\nfloat64 z\n";

    /// A little-endian CDR message of `body` (already aligned as CDR wants it).
    fn cdr(body: &[u8]) -> Vec<u8> {
        let mut data = vec![0, 1, 0, 0];
        data.extend_from_slice(body);
        data
    }

    #[test]
    fn fields_align_to_their_size_from_the_header_s_end() {
        let definitions =
            Definitions::parse("test_msgs/msg/Mixed", "uint8 a\nfloat64 b\nstring c\nint16[] d\n").unwrap();
        let mut body = vec![7];
        body.extend_from_slice(&[0; 7]);
        body.extend_from_slice(&2.5f64.to_le_bytes());
        body.extend_from_slice(&3u32.to_le_bytes());
        body.extend_from_slice(b"hi\0");
        body.push(0);
        body.extend_from_slice(&2u32.to_le_bytes());
        body.extend_from_slice(&(-3i16).to_le_bytes());
        body.extend_from_slice(&4i16.to_le_bytes());
        let message = cdr(&body);
        let value = definitions.decode(&message).unwrap();
        assert_eq!(value.get("a"), Some(&RosValue::UInt(7)));
        assert_eq!(value.get("b"), Some(&RosValue::Float(2.5)));
        assert_eq!(value.get("c"), Some(&RosValue::Text("hi".to_owned())));
        assert_eq!(
            value.get("d"),
            Some(&RosValue::List(vec![RosValue::Int(-3), RosValue::Int(4)]))
        );
    }

    #[test]
    fn nested_types_constants_comments_and_relative_names_resolve() {
        let text = format!(
            "# a twist\nuint8 KIND=3\nVector3 linear  # same package\ngeometry_msgs/msg/Vector3 angular\n\
             {}\nMSG: geometry_msgs/Vector3\n{VECTOR3}",
            "=".repeat(80)
        );
        let definitions = Definitions::parse("geometry_msgs/msg/Twist", &text).unwrap();
        let body: Vec<u8> = [1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let message = cdr(&body);
        let value = definitions.decode(&message).unwrap();
        let Payload::Vector(vector) =
            to_payload(&definitions, &value, &data_type_of(definitions.type_name())).unwrap()
        else {
            panic!("a twist is a vector");
        };
        assert_eq!(&vector[..], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    }

    #[test]
    fn malformed_definitions_and_messages_are_errors_that_say_where() {
        let missing = Definitions::parse("a/msg/B", "c/D field\n")
            .unwrap_err()
            .to_string();
        assert!(missing.contains("a/B.field is a c/D"), "{missing}");
        let bad = Definitions::parse("a/msg/B", "float64[x] values\n").unwrap_err();
        assert!(
            matches!(
                &bad,
                DefinitionError::Line {
                    line: 1,
                    problem: FieldError::BadLength(_),
                    ..
                }
            ),
            "{bad:?}"
        );
        let bad = bad.to_string();
        assert!(bad.contains("line 1") && bad.contains("array length"), "{bad}");
        let looping = Definitions::parse(
            "a/msg/B",
            &format!("B inner\n{}\nMSG: a/B\nB inner\n", "=".repeat(3)),
        )
        .unwrap();
        assert!(
            looping
                .decode(&cdr(&[]))
                .unwrap_err()
                .to_string()
                .contains("include itself")
        );
        let definitions = Definitions::parse("a/msg/B", "float64[] values\nstring name\n").unwrap();
        let huge = cdr(&u32::MAX.to_le_bytes());
        let huge_error = definitions.decode(&huge).unwrap_err();
        assert!(
            matches!(&huge_error, CdrError::InField { field, .. } if field == "values"),
            "{huge_error:?}"
        );
        assert!(huge_error.to_string().contains("a/B.values"));
        assert!(definitions.decode(&[0, 1]).is_err());
        assert_eq!(
            definitions.decode(&[0, 9, 0, 0]),
            Err(CdrError::Encapsulation(0, 9))
        );
    }

    #[test]
    fn big_endian_messages_read_the_same() {
        let definitions = Definitions::parse("std_msgs/msg/Float64", "float64 data\n").unwrap();
        let mut data = vec![0, 0, 0, 0];
        data.extend_from_slice(&1.25f64.to_be_bytes());
        let value = definitions.decode(&data).unwrap();
        assert_eq!(
            to_payload(&definitions, &value, &data_type_of(definitions.type_name())).unwrap(),
            Payload::F64(1.25)
        );
    }
}

"""The worker protocol's bytes: frames and payloads (docs/python.md, "The worker protocol").

A frame is a little-endian u32 length (of what follows), a kind byte and a body. Payloads are a tag byte
and fixed little-endian fields; image pixels travel inline only when they are small, otherwise the runtime
names a shared-memory buffer that both processes map.
"""

import struct

from .types import (
    BOOL, BYTES, CAN_FRAME, F64, FIX_STATUSES, GNSS_FIX, I64, IMAGE, IMU, MATRIX, PIXEL_FORMATS, POINT_CLOUD,
    POSE, TEXT, VECTOR, CanFrame, Custom, GnssFix, Imu, Pose,
)

PROTOCOL_VERSION = 1

TAGS = {F64: 0, I64: 1, BOOL: 2, TEXT: 3, BYTES: 4, VECTOR: 5, MATRIX: 6, IMAGE: 7, POINT_CLOUD: 8, IMU: 9,
        GNSS_FIX: 10, CAN_FRAME: 11, POSE: 12}
CUSTOM_TAG = 13
TYPE_OF_TAG = {tag: name for name, tag in TAGS.items()}
FORMATS = list(PIXEL_FORMATS)

# Where an image's pixels are.
PIXELS_INLINE = 0
PIXELS_SHARED = 1  # in a read: a buffer of the runtime (fd, id, len); in a write: a buffer from ALLOC
PIXELS_HELD = 2  # in a write only: the pixels of an input sample the runtime holds for this worker

HEADER = struct.Struct("<IB")
U8 = struct.Struct("<B")
U16 = struct.Struct("<H")
U32 = struct.Struct("<I")
I64S = struct.Struct("<q")
F64S = struct.Struct("<d")
SAMPLE_HEAD = struct.Struct("<qqQQ")  # timestamp, time of issue, sequence, held handle
IMAGE_HEAD = struct.Struct("<IIIBB")  # width, height, stride, format, where
SHARED_REF = struct.Struct("<iQQ")  # fd in the runtime, buffer id, length
IMU_S = struct.Struct("<6dB4d")
GNSS_S = struct.Struct("<5dB")
CAN_S = struct.Struct("<IBB")
POSE_S = struct.Struct("<7d")


def frame(kind, body=b""):
    return HEADER.pack(len(body) + 1, ord(kind)) + body


class Reader:
    """Reads fields off a body in order."""

    __slots__ = ("data", "at")

    def __init__(self, data, at=0):
        self.data = data
        self.at = at

    def take(self, fmt):
        values = fmt.unpack_from(self.data, self.at)
        self.at += fmt.size
        return values

    def one(self, fmt):
        value = fmt.unpack_from(self.data, self.at)[0]
        self.at += fmt.size
        return value

    def raw(self, length):
        start = self.at
        self.at += length
        if self.at > len(self.data):
            raise ValueError("a worker frame ends inside a field")
        return self.data[start:self.at]

    def sized(self):
        return self.raw(self.one(U32))


def encode_payload(out, data_type, value, extra, image_pixels=None):
    """Appends a payload to bytearray `out`. `image_pixels` gives, for an image, `(where, fields)`: how its
    pixels travel (see the `PIXELS_*` constants)."""
    tag = TAGS.get(data_type)
    if tag is None:
        out += U8.pack(CUSTOM_TAG)
        name = value.type_name.encode()
        out += U16.pack(len(name)) + name + U32.pack(len(value.data)) + value.data
        return
    out += U8.pack(tag)
    if data_type == F64:
        out += F64S.pack(value)
    elif data_type == I64:
        out += I64S.pack(value)
    elif data_type == BOOL:
        out += U8.pack(1 if value else 0)
    elif data_type == TEXT:
        encoded = value.encode()
        out += U32.pack(len(encoded)) + encoded
    elif data_type == BYTES:
        out += U32.pack(len(value)) + value
    elif data_type == VECTOR:
        out += U32.pack(value.shape[0]) + value.tobytes()
    elif data_type == MATRIX:
        out += U32.pack(value.shape[0]) + U32.pack(value.shape[1]) + value.tobytes()
    elif data_type == IMAGE:
        where, fields = image_pixels
        height, width = value.shape[0], value.shape[1]
        stride = value.strides[0] if where == PIXELS_HELD else width * value.itemsize * _channels(value)
        out += IMAGE_HEAD.pack(width, height, stride, FORMATS.index(extra), where) + fields
    elif data_type == POINT_CLOUD:
        out += U32.pack(value.shape[0]) + U8.pack(extra is not None) + value.tobytes()
        if extra is not None:
            out += extra.tobytes()
    elif data_type == IMU:
        orientation = value.orientation
        out += IMU_S.pack(*value.angular_velocity, *value.linear_acceleration, orientation is not None,
                          *(orientation or (0.0, 0.0, 0.0, 1.0)))
    elif data_type == GNSS_FIX:
        out += GNSS_S.pack(value.latitude_deg, value.longitude_deg, value.altitude_m, value.horizontal_accuracy_m,
                           value.vertical_accuracy_m, FIX_STATUSES.index(value.status))
    elif data_type == CAN_FRAME:
        # Flags: 1 extended, 2 FD, 4 remote request (then the length it asks for, and no data).
        flags = int(value.extended) | int(value.fd) << 1 | int(value.remote) << 2
        length = value.remote_length if value.remote else len(value.data)
        out += CAN_S.pack(value.id, flags, length) + (b"" if value.remote else bytes(value.data))
    elif data_type == POSE:
        out += POSE_S.pack(*value.position, *value.orientation)


def _channels(array):
    return 1 if array.ndim == 2 else array.shape[2]


def decode_payload(reader, image_of):
    """(data type, value, extra) from `reader`; `image_of(width, height, stride, format, where, reader)` makes
    an image's array (and reads its pixel fields)."""
    tag = reader.one(U8)
    if tag == CUSTOM_TAG:
        name = bytes(reader.raw(reader.one(U16))).decode()
        return name, Custom(name, bytes(reader.sized())), None
    data_type = TYPE_OF_TAG.get(tag)
    if data_type == F64:
        return F64, reader.one(F64S), None
    if data_type == I64:
        return I64, reader.one(I64S), None
    if data_type == BOOL:
        return BOOL, reader.one(U8) != 0, None
    if data_type == TEXT:
        return TEXT, bytes(reader.sized()).decode(), None
    if data_type == BYTES:
        return BYTES, bytes(reader.sized()), None
    if data_type == VECTOR:
        from .component import numpy
        count = reader.one(U32)
        return VECTOR, numpy().frombuffer(bytes(reader.raw(count * 8)), dtype="<f8"), None
    if data_type == MATRIX:
        from .component import numpy
        rows, cols = reader.one(U32), reader.one(U32)
        values = numpy().frombuffer(bytes(reader.raw(rows * cols * 8)), dtype="<f8")
        return MATRIX, values.reshape(rows, cols), None
    if data_type == IMAGE:
        width, height, stride, format_index, where = reader.take(IMAGE_HEAD)
        format_ = FORMATS[format_index]
        return IMAGE, image_of(width, height, stride, format_, where, reader), format_
    if data_type == POINT_CLOUD:
        from .component import numpy
        np = numpy()
        count, has_intensity = reader.one(U32), reader.one(U8)
        points = np.frombuffer(bytes(reader.raw(count * 12)), dtype="<f4").reshape(count, 3)
        intensity = np.frombuffer(bytes(reader.raw(count * 4)), dtype="<f4") if has_intensity else None
        return POINT_CLOUD, points, intensity
    if data_type == IMU:
        fields = reader.take(IMU_S)
        orientation = tuple(fields[7:11]) if fields[6] else None
        return IMU, Imu(tuple(fields[0:3]), tuple(fields[3:6]), orientation), None
    if data_type == GNSS_FIX:
        fields = reader.take(GNSS_S)
        return GNSS_FIX, GnssFix(*fields[:5], status=FIX_STATUSES[fields[5]]), None
    if data_type == CAN_FRAME:
        can_id, flags, length = reader.take(CAN_S)
        if flags & 4:
            return CAN_FRAME, CanFrame(can_id, b"", bool(flags & 1), remote=True, remote_length=length), None
        # More than 8 bytes is FD by itself: the flag says so only of a shorter frame.
        fd = bool(flags & 2) and length <= 8
        return CAN_FRAME, CanFrame(can_id, bytes(reader.raw(length)), bool(flags & 1), fd), None
    if data_type == POSE:
        fields = reader.take(POSE_S)
        return POSE, Pose(tuple(fields[0:3]), tuple(fields[3:7])), None
    raise ValueError(f"unknown payload tag {tag}")

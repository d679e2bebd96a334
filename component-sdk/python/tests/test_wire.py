"""The worker protocol's bytes: every payload survives encode then decode, field for field."""

import struct

import numpy as np
import pytest

from kairos_sdk import (
    BOOL, BYTES, CAN_FRAME, F64, GNSS_FIX, I64, IMAGE, IMU, MATRIX, POINT_CLOUD, POSE, TEXT, VECTOR, CanFrame,
    Custom, Descriptor, GnssFix, Imu, Pose, Sample, wire,
)
from kairos_sdk.component import normalize
from kairos_sdk.types import PIXEL_FORMATS
from kairos_sdk.worker import WorkerContext


def inline_pixels(array):
    """An image's pixels as they travel inline: `U32 length + bytes`, rows packed."""
    pixels = np.ascontiguousarray(array).tobytes()
    return wire.PIXELS_INLINE, wire.U32.pack(len(pixels)) + pixels


def image_of(width, height, stride, format_, where, reader):
    """Builds the array of an inline image, as a worker does."""
    assert where == wire.PIXELS_INLINE
    dtype = np.uint16 if format_ == "gray16" else np.uint8
    channels = PIXEL_FORMATS[format_]
    shape = (height, width) if channels == 1 else (height, width, channels)
    item = np.dtype(dtype).itemsize
    strides = (stride, item) if channels == 1 else (stride, channels * item, item)
    return np.ndarray(shape, dtype, buffer=bytes(reader.sized()), strides=strides)


def round_trip(data_type, value, format_=None, intensity=None):
    """(decoded type, value, extra) after normalizing, encoding and decoding `value`; every byte read."""
    data_type, value, extra = normalize("out", data_type, value, format_, intensity)
    body = bytearray()
    pixels = inline_pixels(value) if data_type == IMAGE else None
    wire.encode_payload(body, data_type, value, extra, pixels)
    reader = wire.Reader(bytes(body))
    decoded = wire.decode_payload(reader, image_of)
    assert reader.at == len(body), "the decoder read every byte the encoder wrote"
    return decoded


@pytest.mark.parametrize("data_type, value", [
    (F64, 0.1), (F64, -1e300), (F64, float("inf")),
    (I64, 0), (I64, -(2 ** 63)), (I64, 2 ** 63 - 1),
    (BOOL, True), (BOOL, False),
    (TEXT, ""), (TEXT, "Grüße, 世界 ✓"),
    (BYTES, b""), (BYTES, bytes(range(256))),
    (IMU, Imu((0.1, -0.2, 0.3), (0.0, 0.0, 9.81))),
    (IMU, Imu((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), orientation=(0.0, 0.0, 0.7071, 0.7071))),
    (GNSS_FIX, GnssFix(48.8584, 2.2945, 35.0, 0.02, 0.05, "rtk_fixed")),
    (GNSS_FIX, GnssFix(-33.9, 151.2, -1.5, status="no_fix")),
    (CAN_FRAME, CanFrame(0x123, b"\x01\x02\x03")),
    (CAN_FRAME, CanFrame(0x1ABCDEF0, bytes(range(64)), extended=True)),
    (CAN_FRAME, CanFrame(0x7FF)),
    (CAN_FRAME, CanFrame(0x123, b"\x01", fd=True)),
    (CAN_FRAME, CanFrame(0x123, remote=True, remote_length=8)),
    (POSE, Pose((1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0))),
    ("mypack.boxes", Custom("mypack.boxes", b"\x00\xff payload")),
])
def test_scalars_and_records_round_trip(data_type, value):
    assert round_trip(data_type, value) == (data_type, value, None)


def test_a_custom_type_written_as_bytes_comes_back_custom():
    assert round_trip("mypack.boxes", b"abc") == ("mypack.boxes", Custom("mypack.boxes", b"abc"), None)


@pytest.mark.parametrize("values", [[], [1.5], [0.0, -2.25, 1e-300, 7.0]])
def test_vectors_round_trip(values):
    data_type, vector, extra = round_trip(VECTOR, values)
    assert data_type == VECTOR and extra is None
    assert vector.dtype == np.float64 and vector.tolist() == values


def test_matrices_keep_their_shape_and_order():
    matrix = np.arange(12, dtype=np.float64).reshape(3, 4) / 7
    data_type, decoded, _ = round_trip(MATRIX, matrix)
    assert data_type == MATRIX and decoded.shape == (3, 4)
    np.testing.assert_array_equal(decoded, matrix)
    # A column-major array is sent in row order all the same.
    data_type, decoded, _ = round_trip(MATRIX, np.asfortranarray(matrix))
    np.testing.assert_array_equal(decoded, matrix)


@pytest.mark.parametrize("format_, shape, dtype", [
    ("gray8", (5, 7), np.uint8),
    ("gray16", (5, 7), np.uint16),
    ("rgb8", (4, 3, 3), np.uint8),
    ("bgr8", (2, 9, 3), np.uint8),
    ("rgba8", (3, 3, 4), np.uint8),
    ("bgra8", (1, 1, 4), np.uint8),
])
def test_images_round_trip_inline(format_, shape, dtype):
    rng = np.random.default_rng(7)
    image = rng.integers(0, np.iinfo(dtype).max, size=shape, dtype=dtype)
    data_type, decoded, extra = round_trip(IMAGE, image, format_)
    assert (data_type, extra) == (IMAGE, format_)
    assert decoded.dtype == dtype and decoded.shape == shape
    np.testing.assert_array_equal(decoded, image)


def test_an_image_view_is_sent_with_packed_rows():
    image = np.arange(10 * 8, dtype=np.uint8).reshape(10, 8)
    crop = image[2:6, 1:5]  # rows 8 bytes apart in memory, 4 wide
    _, decoded, extra = round_trip(IMAGE, crop)
    assert extra == "gray8"
    np.testing.assert_array_equal(decoded, crop)


def test_image_header_fields():
    image = np.zeros((3, 5, 3), np.uint8)
    body = bytearray()
    wire.encode_payload(body, IMAGE, image, "bgr8", inline_pixels(image))
    assert body[0] == wire.TAGS[IMAGE]
    width, height, stride, format_index, where = wire.IMAGE_HEAD.unpack_from(body, 1)
    assert (width, height, stride, wire.FORMATS[format_index], where) == (5, 3, 15, "bgr8", wire.PIXELS_INLINE)
    assert wire.U32.unpack_from(body, 1 + wire.IMAGE_HEAD.size)[0] == 45


@pytest.mark.parametrize("with_intensity", [False, True])
def test_point_clouds_round_trip(with_intensity):
    points = np.array([[0.0, 1.0, 2.0], [-3.5, 4.25, 1e6]], dtype=np.float64)
    intensity = [0.5, 1.0] if with_intensity else None
    data_type, decoded, extra = round_trip(POINT_CLOUD, points, intensity=intensity)
    assert data_type == POINT_CLOUD and decoded.dtype == np.float32 and decoded.shape == (2, 3)
    np.testing.assert_array_equal(decoded, points.astype(np.float32))
    if with_intensity:
        assert extra.dtype == np.float32 and extra.tolist() == [0.5, 1.0]
    else:
        assert extra is None


def test_an_empty_point_cloud_round_trips():
    data_type, decoded, extra = round_trip(POINT_CLOUD, np.zeros((0, 3)))
    assert decoded.shape == (0, 3) and extra is None


def test_tags_are_stable():
    # The runtime decodes by these numbers: changing one breaks every worker.
    assert wire.TAGS == {F64: 0, I64: 1, BOOL: 2, TEXT: 3, BYTES: 4, VECTOR: 5, MATRIX: 6, IMAGE: 7,
                         POINT_CLOUD: 8, IMU: 9, GNSS_FIX: 10, CAN_FRAME: 11, POSE: 12}
    assert wire.CUSTOM_TAG == 13


def test_f64_payload_bytes():
    body = bytearray()
    wire.encode_payload(body, F64, 1.0, None)
    assert bytes(body) == b"\x00" + struct.pack("<d", 1.0)


def test_frames_carry_their_length_and_kind():
    assert wire.frame("w", b"abc") == struct.pack("<IB", 4, ord("w")) + b"abc"
    assert wire.frame("D") == struct.pack("<IB", 1, ord("D"))


def test_a_truncated_field_is_an_error():
    body = bytearray()
    wire.encode_payload(body, TEXT, "hello", None)
    with pytest.raises(ValueError, match="ends inside a field"):
        wire.decode_payload(wire.Reader(bytes(body[:-2])), image_of)


def test_an_unknown_tag_is_an_error():
    with pytest.raises(ValueError, match="unknown payload tag 99"):
        wire.decode_payload(wire.Reader(b"\x63"), image_of)


# ----- the worker's side of a sample -----


class RecordingConnection:
    """Stands in for the socket: keeps the frames the worker sends."""

    def __init__(self):
        self.sent = []

    def send(self, kind, body=b""):
        self.sent.append((kind, bytes(body)))


def worker_context(descriptor):
    hello = {"id": "probe", "properties": {}, "pid": 0, "inputs": []}
    return WorkerContext(RecordingConnection(), hello, descriptor)


def test_a_worker_write_is_a_frame_the_runtime_decodes():
    ctx = worker_context(Descriptor("probe").output("level", F64).output("mask", IMAGE))
    ctx.write("level", 3, timestamp=42)
    mask = np.full((4, 6), 255, np.uint8)
    ctx.write("mask", mask)
    (kind, level), (kind_2, image) = ctx._conn.sent
    assert kind == kind_2 == "w"
    assert struct.unpack_from("<HBq", level) == (0, 1, 42)
    assert wire.decode_payload(wire.Reader(level, 11), image_of) == (F64, 3.0, None)
    assert struct.unpack_from("<HBq", image) == (1, 0, 0)
    data_type, decoded, extra = wire.decode_payload(wire.Reader(image, 11), image_of)
    assert (data_type, extra) == (IMAGE, "gray8")
    np.testing.assert_array_equal(decoded, mask)


def test_a_worker_reads_a_sample_with_inline_pixels():
    ctx = worker_context(Descriptor("probe").input("image", IMAGE))
    image = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    body = bytearray(wire.SAMPLE_HEAD.pack(1000, 1500, 7, 0))
    wire.encode_payload(body, IMAGE, image, "rgb8", inline_pixels(image))
    sample = ctx._sample(wire.Reader(bytes(body)))
    assert isinstance(sample, Sample)
    assert (sample.timestamp, sample.time_of_issue, sample.sequence, sample.type, sample.format) == (
        1000, 1500, 7, IMAGE, "rgb8")
    np.testing.assert_array_equal(sample.data, image)


def test_a_worker_reads_a_point_cloud_with_intensity():
    ctx = worker_context(Descriptor("probe").input("cloud", POINT_CLOUD))
    _, points, intensity = normalize("o", POINT_CLOUD, np.ones((3, 3)), intensity=[1, 2, 3])
    body = bytearray(wire.SAMPLE_HEAD.pack(5, 5, 0, 0))
    wire.encode_payload(body, POINT_CLOUD, points, intensity)
    sample = ctx._sample(wire.Reader(bytes(body)))
    assert sample.type == POINT_CLOUD and sample.format is None
    assert sample.intensity.tolist() == [1.0, 2.0, 3.0]

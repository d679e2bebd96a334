"""The component base class, the errors that leave `core`, and what every context checks before a write."""

import math
import sys

from .types import (
    BOOL, BYTES, CAN_FRAME, F64, GNSS_FIX, I64, IMAGE, IMU, MATRIX, PIXEL_FORMATS, POINT_CLOUD, POSE, TEXT,
    VECTOR, CanFrame, Custom, GnssFix, Imu, Pose, Sample,
)


class Stopped(BaseException):
    """The runtime asked the component to stop: leave `core` (letting it propagate does that).

    A `BaseException`, like `KeyboardInterrupt`, so that `except Exception` in a component does not swallow it.
    """


class Interrupted(BaseException):
    """A pause, a property change or an action waits: leave `core`; the runtime calls it again after."""


class EndOfStream(BaseException):
    """Every input this read waits on has ended (a replay reached its end)."""


class ComponentFailed(Exception):
    """The runtime refused a request (a write on a stopped output, ...): the message says why."""


class WrongType(TypeError):
    """A value written on an output that does not carry its type; the message names the port and the type."""


def numpy():
    """numpy, or an error that says which interpreter lacks it."""
    try:
        import numpy as np
    except ImportError:
        raise ImportError(
            f"numpy is needed for vectors, matrices, images and point clouds; install it for {sys.executable} "
            "(pip install numpy)"
        ) from None
    return np


class Component:
    """Subclass it, give it a `descriptor`, and write `core`.

    The runtime calls `birth` once before the first `core`, `core` over and over (a threaded component
    reads what it needs, blocking; a periodic one is called once per period), and `death` at the end.
    `property_changed` and `action` are called between two `core` calls.
    """

    #: The component's `Descriptor`.
    descriptor = None

    def birth(self, ctx):
        pass

    def core(self, ctx):
        raise NotImplementedError(f"{type(self).__name__} has no core(self, ctx)")

    def death(self, ctx):
        pass

    def property_changed(self, name, value, ctx):
        pass

    def action(self, name, ctx):
        pass


def _describe(value):
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{type(value).__name__} {text}"


def infer_type(value):
    """The data type a value would be written as on an output that follows its input."""
    if isinstance(value, bool):
        return BOOL
    if isinstance(value, int):
        return I64
    if isinstance(value, float):
        return F64
    if isinstance(value, str):
        return TEXT
    if isinstance(value, (bytes, bytearray, memoryview)):
        return BYTES
    for data_type, cls in ((IMU, Imu), (GNSS_FIX, GnssFix), (CAN_FRAME, CanFrame), (POSE, Pose)):
        if isinstance(value, cls):
            return data_type
    if isinstance(value, Custom):
        return value.type_name
    shape = getattr(value, "shape", None)
    dtype = getattr(value, "dtype", None)
    if shape is not None and dtype is not None:
        if dtype.kind in "ui" and len(shape) in (2, 3):
            return IMAGE
        if dtype.kind == "f" and len(shape) == 2 and shape[1] == 3 and dtype.itemsize == 4:
            return POINT_CLOUD
        if len(shape) == 1:
            return VECTOR
        if len(shape) == 2:
            return MATRIX
        if len(shape) == 0:
            # A numpy scalar: its own kind, as the Python number it stands for would be.
            return {"b": BOOL, "i": I64, "u": I64}.get(dtype.kind, F64)
    raise WrongType(f"cannot tell which data type {_describe(value)} is")


def image_geometry(width, height, format_):
    """(dtype, shape) of a numpy image of `format_`: height × width, × channels but for grey."""
    np = numpy()
    if format_ not in PIXEL_FORMATS:
        raise ValueError(f"pixel format {format_!r} is not one of {', '.join(PIXEL_FORMATS)}")
    if width <= 0 or height <= 0:
        raise ValueError(f"an image of {width}x{height} pixels is empty")
    channels = PIXEL_FORMATS[format_]
    dtype = np.dtype(np.uint16 if format_ == "gray16" else np.uint8)
    return dtype, (height, width) if channels == 1 else (height, width, channels)


def image_format(array, format_):
    """The pixel format of a numpy image, from `format_` or from its dtype and channels."""
    np = numpy()
    if array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 1):
        channels = 1
    elif array.ndim == 3:
        channels = array.shape[2]
    else:
        raise WrongType(f"an image is height × width or height × width × channels, not {array.ndim} dimensions")
    if format_ is None:
        if channels == 1:
            format_ = "gray16" if array.dtype == np.uint16 else "gray8"
        else:
            format_ = {3: "rgb8", 4: "rgba8"}.get(channels)
            if format_ is None:
                raise WrongType(f"an image has 1, 3 or 4 channels, not {channels}")
    if format_ not in PIXEL_FORMATS:
        raise WrongType(f"pixel format {format_!r} is not one of {', '.join(PIXEL_FORMATS)}")
    if PIXEL_FORMATS[format_] != channels:
        raise WrongType(f"a {format_} image has {PIXEL_FORMATS[format_]} channels, the array has {channels}")
    wanted = np.uint16 if format_ == "gray16" else np.uint8
    if array.dtype != wanted:
        raise WrongType(f"a {format_} image is an array of {np.dtype(wanted).name}, not {array.dtype.name}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise WrongType(f"an image of {array.shape[1]}x{array.shape[0]} pixels is empty")
    return format_


def normalize(port, data_type, value, format_=None, intensity=None):
    """`value` as a payload of `data_type` written on output `port`: numbers as float/int/bool, arrays as
    contiguous numpy arrays of the right dtype; `WrongType` naming the port and the type otherwise.

    Returns `(data_type, value, extra)`: `extra` is an image's format or a point cloud's intensities.
    """

    def wrong(hint):
        raise WrongType(f"output '{port}' carries {data_type}: got {_describe(value)} ({hint})")

    if data_type == F64:
        if isinstance(value, bool) or not _is_number(value):
            wrong("write a float")
        return F64, float(value), None
    if data_type == I64:
        if isinstance(value, bool) or not _is_integer(value):
            wrong("write an int")
        return I64, int(value), None
    if data_type == BOOL:
        # numpy's booleans (`np.bool_`, named `bool` since numpy 2) are not Python bools.
        numpy_bool = getattr(getattr(value, "dtype", None), "kind", None) == "b" and getattr(value, "ndim", 1) == 0
        if not (isinstance(value, bool) or numpy_bool):
            wrong("write True or False")
        return BOOL, bool(value), None
    if data_type == TEXT:
        if not isinstance(value, str):
            wrong("write a str")
        return TEXT, value, None
    if data_type == BYTES:
        if not isinstance(value, (bytes, bytearray, memoryview)):
            wrong("write bytes")
        return BYTES, bytes(value), None
    if data_type in (VECTOR, MATRIX):
        np = numpy()
        try:
            array = np.ascontiguousarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            wrong("write a sequence of numbers or a numpy array")
        wanted = 1 if data_type == VECTOR else 2
        if array.ndim != wanted:
            wrong(f"write an array of {wanted} dimension{'s' if wanted > 1 else ''}, not {array.ndim}")
        return data_type, array, None
    if data_type == IMAGE:
        if getattr(value, "dtype", None) is None or getattr(value, "ndim", None) is None:
            wrong("write a numpy array of height × width × channels")
        try:
            return IMAGE, value, image_format(value, format_)
        except WrongType as error:
            raise WrongType(f"output '{port}' carries image: {error}") from None
    if data_type == POINT_CLOUD:
        np = numpy()
        try:
            points = np.ascontiguousarray(value, dtype=np.float32)
        except (TypeError, ValueError):
            wrong("write an N × 3 array of x, y, z")
        if points.ndim != 2 or points.shape[1] != 3:
            wrong(f"write an N × 3 array of x, y, z, not shape {points.shape}")
        if intensity is not None:
            intensity = np.ascontiguousarray(intensity, dtype=np.float32)
            if intensity.shape != (points.shape[0],):
                raise WrongType(f"output '{port}': {points.shape[0]} points but intensity of shape {intensity.shape}")
        return POINT_CLOUD, points, intensity
    for name, cls in ((IMU, Imu), (GNSS_FIX, GnssFix), (CAN_FRAME, CanFrame), (POSE, Pose)):
        if data_type == name:
            if not isinstance(value, cls):
                wrong(f"write a kairos_sdk.{cls.__name__}")
            return name, value, None
    # A pack-defined type.
    if isinstance(value, Custom):
        if value.type_name != data_type:
            wrong(f"write kairos_sdk.Custom({data_type!r}, data)")
        return data_type, value, None
    if isinstance(value, (bytes, bytearray, memoryview)):
        return data_type, Custom(data_type, bytes(value)), None
    wrong(f"write kairos_sdk.Custom({data_type!r}, data) or bytes")


def _is_number(value):
    if isinstance(value, (int, float)):
        return True
    kind = getattr(getattr(value, "dtype", None), "kind", None)
    return kind in ("f", "i", "u") and getattr(value, "ndim", 1) == 0


def _is_integer(value):
    if isinstance(value, int):
        return True
    if isinstance(value, float):
        return False
    kind = getattr(getattr(value, "dtype", None), "kind", None)
    return kind in ("i", "u") and getattr(value, "ndim", 1) == 0


class ContextBase:
    """What the runtime's context and the harness's have in common: names, properties and write checks."""

    def __init__(self, component_id, descriptor, properties):
        self.id = component_id
        self.descriptor = descriptor
        self.properties = dict(properties)
        self._input_names = [p["name"] for p in descriptor.inputs]
        self._outputs = {p["name"]: i for i, p in enumerate(descriptor.outputs)}

    def property(self, name):
        """A property's current value."""
        if name not in self.properties:
            raise KeyError(f"component '{self.id}' has no property '{name}'")
        return self.properties[name]

    def input_index(self, name):
        try:
            return self._input_names.index(name)
        except ValueError:
            raise KeyError(
                f"component '{self.id}' has no input '{name}' (inputs: {', '.join(self._input_names) or 'none'})"
            ) from None

    def output_index(self, name):
        try:
            return self._outputs[name]
        except KeyError:
            raise KeyError(
                f"component '{self.id}' has no output '{name}' (outputs: {', '.join(self._outputs) or 'none'})"
            ) from None

    def checked(self, output, value, format_=None, intensity=None):
        """(output index, data type, value, extra) for a write, or `WrongType`."""
        index = self.output_index(output)
        port = self.descriptor.outputs[index]
        data_type = port["data_type"] if "follows_input" not in port else infer_type(value)
        data_type, value, extra = normalize(output, data_type, value, format_, intensity)
        return index, data_type, value, extra

    def write_processed(self, output, input_sample, data, **options):
        """Writes the result of processing `input_sample`: it keeps that sample's timestamp."""
        self.write(output, data, timestamp=input_sample.timestamp, **options)

    def forward(self, output, sample):
        """Passes `sample` on unchanged but for its time of issue (images: the same pixels, no copy)."""
        self.write(output, sample.data, timestamp=sample.timestamp, format=sample.format, intensity=sample.intensity)

    def set_frequency(self, hertz):
        if not hertz > 0 or not math.isfinite(hertz):
            raise ValueError(f"a frequency is a positive number of hertz, got {hertz!r}")
        self.set_period(1.0 / hertz)


__all__ = [
    "Component", "ComponentFailed", "ContextBase", "EndOfStream", "Interrupted", "Sample", "Stopped",
    "WrongType", "infer_type", "normalize",
]

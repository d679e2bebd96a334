"""Kairos components in Python.

    from kairos_sdk import Component, Descriptor, Property, F64

    class Gain(Component):
        descriptor = (
            Descriptor("gain", category="math", doc="Multiplies each sample by a factor")
            .input("in", F64)
            .output("out", F64)
            .property(Property.f64("factor", 2.0).range(-100, 100).live())
        )

        def core(self, ctx):
            sample = ctx.read("in")
            ctx.write_processed("out", sample, sample.data * ctx.property("factor"))

Test it offline with `kairos_sdk.harness.Harness`; run it in a diagram by putting its file in a pack folder
(a `kairos-pack.toml` beside it) on the pack path. Guide: docs/python.md.
"""

from .component import (
    Component, ComponentFailed, EndOfStream, Interrupted, Stopped, WrongType,
)
from .descriptor import Descriptor, DescriptorError, Property
from .harness import Harness
from .types import (
    ANY, BOOL, BYTES, CAN_FRAME, F64, GNSS_FIX, I64, IMAGE, IMU, MATRIX, POINT_CLOUD, POSE, TEXT, VECTOR,
    CanFrame, Custom, GnssFix, Imu, Pose, Sample,
)

__version__ = "0.1.0"

__all__ = [
    "ANY", "BOOL", "BYTES", "CAN_FRAME", "F64", "GNSS_FIX", "I64", "IMAGE", "IMU", "MATRIX", "POINT_CLOUD",
    "POSE", "TEXT", "VECTOR", "CanFrame", "Component", "ComponentFailed", "Custom", "Descriptor",
    "DescriptorError", "EndOfStream", "GnssFix", "Harness", "Imu", "Interrupted", "Pose", "Property", "Sample",
    "Stopped", "WrongType",
]

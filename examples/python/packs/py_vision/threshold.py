"""A colour threshold: the pixels whose red, green and blue lie within bounds, as a mask."""

import numpy as np

from kairos_sdk import F64, IMAGE, Component, Descriptor, Property


def _descriptor():
    descriptor = (
        Descriptor("threshold", category="vision", label="Colour threshold",
                   doc="A mask of the pixels whose colour lies within bounds (numpy)")
        .input("image", IMAGE, doc="An RGB image")
        .output("mask", IMAGE, doc="255 where the colour is within the bounds, 0 elsewhere")
        .output("fraction", F64, doc="The share of the image within the bounds, 0 to 1")
    )
    for colour in ("red", "green", "blue"):
        descriptor.property(Property.i64(f"{colour}_min", 0).range(0, 255).live().doc(f"Lowest {colour} kept"))
        descriptor.property(Property.i64(f"{colour}_max", 255).range(0, 255).live().doc(f"Highest {colour} kept"))
    return descriptor


class ColourThreshold(Component):
    descriptor = _descriptor()

    def birth(self, ctx):
        self.bounds = self._read_bounds(ctx)

    def property_changed(self, name, value, ctx):
        self.bounds = self._read_bounds(ctx)

    @staticmethod
    def _read_bounds(ctx):
        low = np.array([ctx.property(f"{c}_min") for c in ("red", "green", "blue")], dtype=np.uint8)
        high = np.array([ctx.property(f"{c}_max") for c in ("red", "green", "blue")], dtype=np.uint8)
        return low, high

    def core(self, ctx):
        sample = ctx.read("image")
        if sample.format not in ("rgb8", "bgr8"):
            raise ValueError(f"threshold takes rgb8 or bgr8 images, got {sample.format}")
        pixels = sample.data if sample.format == "rgb8" else sample.data[:, :, ::-1]
        low, high = self.bounds
        inside = np.all((pixels >= low) & (pixels <= high), axis=2)
        height, width = inside.shape
        # Drawn straight into the runtime's shared memory: the readers get it without a copy.
        mask = ctx.new_image(width, height, "gray8")
        np.multiply(inside, 255, out=mask, casting="unsafe")
        ctx.write_processed("mask", sample, mask)
        ctx.write_processed("fraction", sample, float(inside.mean()))

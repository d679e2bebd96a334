"""Canny edges with OpenCV (opencv-python-headless), when it is installed."""

from kairos_sdk import IMAGE, Component, Descriptor, Property


class CannyEdges(Component):
    descriptor = (
        Descriptor("canny", category="vision", label="Canny edges (OpenCV)",
                   doc="Edges of an image by OpenCV's Canny detector; needs opencv-python-headless")
        .input("image", IMAGE, doc="An RGB, BGR or grey image")
        .output("edges", IMAGE, doc="255 on edges, 0 elsewhere")
        .property(Property.f64("low", 50.0).range(0, 1000).live().doc("Hysteresis: the lower gradient threshold"))
        .property(Property.f64("high", 150.0).range(0, 1000).live().doc("Hysteresis: the upper gradient threshold"))
    )

    def birth(self, ctx):
        try:
            import cv2
        except ImportError:
            raise ImportError("Canny edges needs OpenCV: pip install opencv-python-headless "
                              "into the interpreter that runs this pack") from None
        self.cv2 = cv2

    def core(self, ctx):
        cv2 = self.cv2
        sample = ctx.read("image")
        conversions = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY,
                       "bgra8": cv2.COLOR_BGRA2GRAY}
        grey = sample.data if sample.format == "gray8" else cv2.cvtColor(sample.data, conversions[sample.format])
        height, width = grey.shape
        edges = ctx.new_image(width, height, "gray8")
        cv2.Canny(grey, ctx.property("low"), ctx.property("high"), edges=edges)
        ctx.write_processed("edges", sample, edges)

"""Passes every sample on unchanged: images keep their pixels (no copy), numbers their value."""

from kairos_sdk import ANY, Component, Descriptor


class PassThrough(Component):
    descriptor = (
        Descriptor("pass_through", category="flow", label="Pass-through (Python)",
                   doc="Forwards every sample as it is; the cost of one hop through Python")
        .input("in", ANY, doc="Anything")
        .output_following("out", "in", doc="The same samples")
    )

    def core(self, ctx):
        ctx.forward("out", ctx.read("in"))

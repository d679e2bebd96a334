"""The offline harness: scripted inputs, a manual clock, and writes checked as the runtime checks them."""

import math

import numpy as np
import pytest

from kairos_sdk import (
    ANY, BOOL, F64, I64, IMAGE, POINT_CLOUD, TEXT, VECTOR, Component, Descriptor, EndOfStream, Harness,
    Interrupted, Property, Sample, Stopped, WrongType,
)
from kairos_sdk.component import ContextBase
from kairos_sdk.harness import HarnessContext, Output

MS = 1_000_000


class Gain(Component):
    descriptor = (
        Descriptor("gain", category="math", doc="Multiplies each sample by a factor")
        .input("in", F64)
        .output("out", F64)
        .property(Property.f64("factor", 2.0).range(-100, 100).live())
        .property(Property.i64("precision", 6))
    )

    def __init__(self):
        self.changes = []

    def core(self, ctx):
        sample = ctx.read("in")
        ctx.write_processed("out", sample, round(sample.data * ctx.property("factor"), ctx.property("precision")))

    def property_changed(self, name, value, ctx):
        self.changes.append((name, value, ctx.property(name)))


class Counter(Component):
    descriptor = (
        Descriptor("counter", category="generators").periodic()
        .output("out", I64)
        .property(Property.f64("rate", 10.0).range(0.001, 1000).live())
        .property(Property.i64("start", 0))
        .action("reset")
    )

    def birth(self, ctx):
        ctx.set_frequency(ctx.property("rate"))
        self.count = ctx.property("start")

    def core(self, ctx):
        ctx.write("out", self.count)
        self.count += 1
        ctx.set_status({"count": self.count, "at": (ctx.now(),)})

    def property_changed(self, name, value, ctx):
        if name == "rate":
            ctx.set_frequency(value)

    def action(self, name, ctx):
        self.count = ctx.property("start")
        ctx.write("out", -1)


class Merge(Component):
    descriptor = (
        Descriptor("merge")
        .input("a", ANY)
        .input("b", ANY)
        .output("which", TEXT)
        .output("out", F64)
    )

    def core(self, ctx):
        name, sample = ctx.read_any(["a", "b"])
        ctx.write_processed("which", sample, name)
        ctx.write_processed("out", sample, float(sample.data))


class Fuse(Component):
    """Pairs left and right samples within 5 ms and writes their mean."""

    descriptor = (
        Descriptor("fuse")
        .input("left", F64)
        .input("right", F64)
        .output("mean", F64)
        .output("ended", BOOL)
    )

    def core(self, ctx):
        try:
            left, right = ctx.read_synchronized(["left", "right"], 0.005)
        except EndOfStream:
            ctx.write("ended", True)
            raise
        ctx.write("mean", (left.data + right.data) / 2, timestamp=min(left.timestamp, right.timestamp))


class Threshold(Component):
    descriptor = (
        Descriptor("threshold", category="vision")
        .input("image", IMAGE)
        .output("mask", IMAGE)
        .property(Property.i64("level", 128).range(0, 255).live())
    )

    def core(self, ctx):
        sample = ctx.read("image")
        grey = sample.data if sample.data.ndim == 2 else sample.data.mean(axis=2)
        mask = ctx.new_image(grey.shape[1], grey.shape[0], format="gray8")
        mask[grey > ctx.property("level")] = 255
        ctx.write_processed("mask", sample, mask)


class Liar(Component):
    descriptor = Descriptor("liar").input("in", F64).output("out", F64)

    def core(self, ctx):
        ctx.read("in")
        ctx.write("out", "not a number")


def test_gain_scales_and_keeps_timestamps():
    h = Harness(Gain)
    h.push("in", 1.5, timestamp=10 * MS)
    h.push("in", -2.0)
    h.push("in", 4)  # an int for an f64 input is delivered as a float
    out = h.run()
    assert out.values("out") == [3.0, -4.0, 8.0]
    samples = out.samples("out")
    assert [s.timestamp for s in samples] == [10 * MS, 11 * MS, 12 * MS]
    assert [s.time_of_issue for s in samples] == [10 * MS, 11 * MS, 12 * MS]
    assert [s.sequence for s in samples] == [0, 1, 2]
    assert all(s.type == F64 for s in samples)
    assert h.now == 12 * MS
    # The next run goes on from there: sequences continue.
    h.push("in", 1.0)
    assert [(s.sequence, s.timestamp, s.data) for s in h.run().samples("out")] == [(3, 13 * MS, 2.0)]


def test_output_lists_every_output():
    out = Harness(Merge).run()
    assert out.all == {"which": [], "out": []}
    with pytest.raises(KeyError, match="no output 'missing'"):
        out.samples("missing")


def test_properties_are_checked_when_the_harness_is_made():
    assert Harness(Gain, properties={"factor": 3}).properties == {"factor": 3.0, "precision": 6}
    with pytest.raises(ValueError, match="no property 'gian'"):
        Harness(Gain, properties={"gian": 3.0})
    with pytest.raises(ValueError, match=r"property 'factor': 500.0 is outside -100..100"):
        Harness(Gain, properties={"factor": 500})
    with pytest.raises(ValueError, match="property 'precision' takes an integer"):
        Harness(Gain, properties={"precision": 2.5})


def test_live_property_changes_reach_the_component():
    h = Harness(Gain)
    h.set_property("factor", 10)  # before the first run: the initial value, no change delivered
    h.push("in", 1.0)
    assert h.run().values("out") == [10.0]
    assert h.component.changes == []
    h.set_property("factor", -1)
    assert h.component.changes == [("factor", -1.0, -1.0)]
    h.push("in", 1.0)
    assert h.run().values("out") == [-1.0]
    with pytest.raises(ValueError, match="property 'factor': 101.0 is outside"):
        h.set_property("factor", 101)
    with pytest.raises(ValueError, match="property 'precision' is not live"):
        h.set_property("precision", 2)
    with pytest.raises(ValueError, match="no property 'gain'"):
        h.set_property("gain", 1.0)


def test_a_component_instance_can_be_given():
    component = Gain()
    h = Harness(component, properties={"factor": 0.5})
    h.push("in", 3.0)
    assert h.run().values("out") == [1.5]
    assert h.component is component
    assert h.ctx.id == "under_test"


def test_a_class_without_descriptor_is_refused():
    class Bare(Component):
        def core(self, ctx):
            pass

    with pytest.raises(TypeError, match="Bare has no descriptor"):
        Harness(Bare)


def test_pushes_are_checked_against_the_input():
    h = Harness(Gain)
    with pytest.raises(ValueError, match=r"no input 'input' \(inputs: in\)"):
        h.push("input", 1.0)
    with pytest.raises(WrongType, match="input 'in' accepts f64: cannot deliver str 'one'"):
        h.push("in", "one")


def test_a_periodic_generator_runs_on_the_manual_clock():
    h = Harness(Counter, properties={"start": 5})
    out = h.run_periodic(4)
    assert out.values("out") == [5, 6, 7, 8]
    assert [s.timestamp for s in out.samples("out")] == [0, 100 * MS, 200 * MS, 300 * MS]
    assert h.now == 400 * MS
    assert h.status == {"count": 9, "at": [300 * MS]}  # as the studio sees it, through JSON
    h.set_property("rate", 100.0)
    assert [s.timestamp for s in h.run_periodic(2).samples("out")] == [400 * MS, 410 * MS]


def test_actions_run_between_cycles():
    h = Harness(Counter)
    h.run_periodic(3)
    assert h.action("reset").values("out") == [-1]
    assert h.run_periodic(2).values("out") == [0, 1]
    with pytest.raises(ValueError, match=r"no action 'rewind' \(actions: reset\)"):
        h.action("rewind")


def test_a_periodic_run_needs_a_period():
    with pytest.raises(RuntimeError, match="set no period"):
        Harness(Gain).run_periodic(1)


def test_clock_moves_by_hand():
    h = Harness(Counter)
    h.clock.advance(1.5)
    assert h.now == 1_500_000_000
    assert h.run_periodic(1).samples("out")[0].timestamp == 1_500_000_000
    with pytest.raises(ValueError, match="only moves forward"):
        h.clock.advance(-1)


def test_read_any_serves_each_input_in_push_order():
    h = Harness(Merge)
    h.push("a", 1.0, timestamp=1 * MS)
    h.push("b", 2, timestamp=2 * MS)
    h.push("a", 3.0, timestamp=3 * MS)
    h.push("b", True, timestamp=4 * MS)
    out = h.run()
    assert out.values("which") == ["a", "b", "a", "b"]
    assert out.values("out") == [1.0, 2.0, 3.0, 1.0]
    assert [s.timestamp for s in out.samples("out")] == [1 * MS, 2 * MS, 3 * MS, 4 * MS]


def test_read_synchronized_pairs_by_timestamp_and_drops_the_unmatched():
    h = Harness(Fuse)
    for input_name, millis, value in [("left", 0, 1.0), ("right", 1, 3.0), ("left", 10, 10.0), ("right", 12, 20.0),
                                      ("left", 20, 0.0), ("right", 30, 8.0), ("left", 31, 2.0)]:
        h.push(input_name, value, timestamp=millis * MS)
    out = h.run()
    # left 20 can never match once right 30 is there: dropped.
    assert out.values("mean") == [2.0, 15.0, 5.0]
    assert [s.timestamp for s in out.samples("mean")] == [0, 10 * MS, 30 * MS]
    assert out.values("ended") == []
    # A half-matched sample waits across runs.
    h.push("left", 40.0, timestamp=40 * MS)
    assert h.run().values("mean") == []
    h.push("right", 42.0, timestamp=43 * MS)
    assert h.run().values("mean") == [41.0]
    # Ending the inputs while one waits for its match ends the stream.
    h.push("left", 50.0, timestamp=50 * MS)
    last = h.finish()
    assert last.values("ended") == [True]
    assert last.values("mean") == []
    assert h.state == "dead"


def test_writing_the_wrong_type_raises_as_under_the_runtime():
    h = Harness(Liar)
    h.push("in", 1.0)
    with pytest.raises(WrongType, match="output 'out' carries f64: got str 'not a number'"):
        h.run()


def test_an_image_threshold_with_numpy():
    h = Harness(Threshold, properties={"level": 100})
    frame = np.array([[0, 50, 150], [200, 100, 101]], np.uint8)
    h.push("image", frame, timestamp=7 * MS)
    colour = np.zeros((2, 2, 3), np.uint8)
    colour[0, 0] = (255, 255, 255)
    h.push("image", colour, format="bgr8")
    out = h.run()
    first, second = out.samples("mask")
    assert first.format == "gray8" and first.type == IMAGE and first.timestamp == 7 * MS
    np.testing.assert_array_equal(first.data, [[0, 0, 255], [255, 0, 255]])
    np.testing.assert_array_equal(second.data, [[255, 0], [0, 0]])
    h.set_property("level", 0)
    h.push("image", frame)
    np.testing.assert_array_equal(h.run().values("mask")[0], [[0, 255, 255], [255, 255, 255]])


def test_input_pixels_are_read_only_and_a_copy_of_what_was_pushed():
    class Painter(Component):
        descriptor = Descriptor("painter").input("image", IMAGE).output("image_out", IMAGE)

        def core(self, ctx):
            sample = ctx.read("image")
            sample.data[0, 0] = 1  # under the runtime other readers share these pixels

    frame = np.zeros((2, 2), np.uint8)
    h = Harness(Painter)
    h.push("image", frame)
    frame[1, 1] = 9  # changing the test's array later changes nothing delivered
    with pytest.raises(ValueError, match="read-only"):
        h.run()


def test_forwarding_keeps_the_format_the_intensity_and_the_timestamp():
    class Probe(Component):
        descriptor = (
            Descriptor("probe")
            .input("in", ANY)
            .output_following("out", "in")
        )

        def core(self, ctx):
            ctx.forward("out", ctx.read("in"))

    h = Harness(Probe)
    image = np.full((2, 3, 3), 7, np.uint8)
    h.push("in", image, timestamp=5 * MS, format="bgr8")
    h.push("in", np.ones((4, 3), np.float32), timestamp=6 * MS, intensity=[1, 2, 3, 4])
    h.push("in", "text", timestamp=7 * MS)
    image_out, cloud, text = h.run().samples("out")
    assert (image_out.type, image_out.format, image_out.timestamp) == (IMAGE, "bgr8", 5 * MS)
    np.testing.assert_array_equal(image_out.data, image)
    assert cloud.type == POINT_CLOUD and cloud.intensity.tolist() == [1.0, 2.0, 3.0, 4.0]
    assert (text.type, text.data, text.sequence) == (TEXT, "text", 2)


def test_written_arrays_are_kept_as_they_were_written():
    class Reuser(Component):
        descriptor = Descriptor("reuser").input("in", F64).output("out", VECTOR)

        def birth(self, ctx):
            self.buffer = np.zeros(2)

        def core(self, ctx):
            self.buffer[:] = ctx.read("in").data
            ctx.write("out", self.buffer)

    h = Harness(Reuser)
    h.push("in", 1.0)
    h.push("in", 2.0)
    assert [v.tolist() for v in h.run().values("out")] == [[1.0, 1.0], [2.0, 2.0]]


def test_errors_in_the_component_reach_the_test():
    class Broken(Component):
        descriptor = Descriptor("broken").input("in", F64).output("out", F64)

        def core(self, ctx):
            ctx.write("out", 1 / ctx.read("in").data)

    h = Harness(Broken)
    h.push("in", 0.0)
    with pytest.raises(ZeroDivisionError):
        h.run()


def test_stopped_ends_the_component_as_the_runtime_does():
    class StopAtNegative(Component):
        descriptor = Descriptor("stopper").input("in", F64).output("out", F64)

        def core(self, ctx):
            sample = ctx.read("in")
            if sample.data < 0:
                raise Stopped()
            ctx.forward("out", sample)

        def death(self, ctx):
            ctx.write("out", math.nan)

    h = Harness(StopAtNegative)
    for value in (1.0, -1.0, 2.0):
        h.push("in", value)
    assert h.run().values("out") == [1.0]
    assert h.state == "stopped"
    h.push("in", 3.0)
    assert h.run().values("out") == []
    assert [math.isnan(v) for v in h.finish().values("out")] == [True]


def test_interrupted_ends_one_core_call_only():
    class Skipper(Component):
        descriptor = Descriptor("skipper").input("in", I64).output("out", I64)

        def core(self, ctx):
            sample = ctx.read("in")
            if sample.data % 2:
                raise Interrupted()
            ctx.forward("out", sample)

    h = Harness(Skipper)
    for value in range(5):
        h.push("in", value)
    assert h.run().values("out") == [0, 2, 4]
    assert h.state == "running"


def test_finish_ends_the_inputs_then_calls_death():
    class Summer(Component):
        descriptor = Descriptor("summer").input("in", F64).output("total", F64)

        def birth(self, ctx):
            self.total = 0.0

        def core(self, ctx):
            while True:
                try:
                    self.total += ctx.read("in").data
                except EndOfStream:
                    ctx.write("total", self.total)
                    raise

        def death(self, ctx):
            ctx.set_status("dead")

    h = Harness(Summer)
    h.push("in", 1.0)
    h.push("in", 2.5)
    assert h.run().values("total") == []
    h.push("in", 0.5)
    assert h.finish().values("total") == [4.0]
    assert h.status == "dead"
    with pytest.raises(RuntimeError, match="finish"):
        h.run()


def test_try_read_sampling_and_is_connected():
    class Triggered(Component):
        descriptor = (
            Descriptor("triggered")
            .input("tick", BOOL)
            .input("level", F64, policy="sampling")
            .input("spare", F64)
            .output("out", F64)
        )

        def core(self, ctx):
            tick = ctx.read("tick")
            level = ctx.try_read("level")
            if level is not None and not ctx.is_connected("spare"):
                ctx.write_processed("out", tick, level.data)

    h = Harness(Triggered)
    h.push("tick", True)  # no level yet: nothing written
    h.push("level", 1.0)
    h.push("tick", True)
    h.push("tick", True)  # the level again: a Sampling input repeats its newest
    h.push("level", 2.0)
    h.push("level", 3.0)
    h.push("tick", True)
    assert h.run().values("out") == [1.0, 1.0, 3.0]
    assert h.ctx.is_connected("tick") and not h.ctx.is_connected("spare")
    with pytest.raises(KeyError, match="no input 'nothing'"):
        h.ctx.is_connected("nothing")


def test_a_periodic_component_sees_pushed_samples_once_the_clock_reaches_them():
    class Sampler(Component):
        descriptor = (
            Descriptor("sampler").periodic()
            .input("in", F64, policy="last_or_next")
            .output("out", F64)
        )

        def birth(self, ctx):
            ctx.set_period(0.010)

        def core(self, ctx):
            sample = ctx.try_read("in")
            ctx.write("out", math.nan if sample is None else sample.data)

    h = Harness(Sampler)
    for millis in (1, 2, 3, 15, 35):
        h.push("in", float(millis), timestamp=millis * MS)
    values = h.run_periodic(4).values("out")  # ticks at 0, 10, 20, 30 ms
    assert math.isnan(values[0]) and values[1:3] == [3.0, 15.0] and math.isnan(values[3])
    assert h.run_periodic(1).values("out") == [35.0]


def test_sleep_wait_until_and_now_use_the_manual_clock():
    class Sleeper(Component):
        descriptor = Descriptor("sleeper").output("out", I64)

        def core(self, ctx):
            ctx.sleep(0.25)
            ctx.write("out", ctx.now())
            ctx.wait_until(ctx.now() + 5 * MS)
            ctx.wait_until(0)  # in the past: no effect
            ctx.write("out", ctx.now(), timestamp=123)
            assert not ctx.stop_requested()

    h = Harness(Sleeper)
    first, second = h.run().samples("out")
    assert (first.data, first.timestamp) == (250 * MS, 250 * MS)
    assert (second.data, second.timestamp, second.time_of_issue) == (255 * MS, 123, 255 * MS)
    assert h.now == 255 * MS


def test_new_image_is_plain_numpy():
    class Maker(Component):
        descriptor = Descriptor("maker").output("image", IMAGE)

        def core(self, ctx):
            image = ctx.new_image(4, 3, format="rgba8")
            assert image.shape == (3, 4, 4) and image.dtype == np.uint8 and not image.any()
            assert ctx.new_image(2, 2, format="gray16").dtype == np.uint16
            with pytest.raises(ValueError, match="pixel format 'rgb' is not one of"):
                ctx.new_image(2, 2, format="rgb")
            with pytest.raises(ValueError, match="is empty"):
                ctx.new_image(0, 2)
            ctx.write("image", image, format="rgba8")

    (sample,) = Harness(Maker).run().samples("image")
    assert sample.format == "rgba8" and sample.data.shape == (3, 4, 4)


def test_push_sample_keeps_its_times():
    h = Harness(Merge)
    h.push_sample("a", Sample(2.5, timestamp=4 * MS, time_of_issue=6 * MS, sequence=9))
    (sample,) = h.run().samples("out")
    assert (sample.timestamp, sample.time_of_issue) == (4 * MS, 6 * MS)
    assert h.now == 6 * MS


def test_the_context_is_a_context_base_with_the_workers_methods():
    from kairos_sdk.worker import WorkerContext

    assert issubclass(HarnessContext, ContextBase)
    public = {name for name in vars(WorkerContext) if not name.startswith("_")}
    missing = {name for name in public if not callable(getattr(HarnessContext, name, None))}
    assert not missing, f"the harness context lacks {sorted(missing)}"
    assert isinstance(Harness(Gain).run(), Output)


def test_a_component_without_inputs_gets_one_core_per_run():
    class Once(Component):
        descriptor = Descriptor("once").output("out", I64).property(Property.bool("on", True))

        def core(self, ctx):
            if ctx.property("on"):
                ctx.write("out", 1)

    h = Harness(Once)
    assert h.run().values("out") == [1]
    assert h.run().values("out") == [1]
    assert h.finish().values("out") == []
    assert Harness(Once, properties={"on": False}).run().values("out") == []


def test_ticks_keep_their_spacing_when_core_sleeps():
    class Slow(Component):
        descriptor = Descriptor("slow").periodic().output("out", I64)

        def birth(self, ctx):
            ctx.set_period(0.1)

        def core(self, ctx):
            ctx.write("out", ctx.now())
            ctx.sleep(0.03)

    h = Harness(Slow)
    assert h.run_periodic(3).values("out") == [0, 100 * MS, 200 * MS]
    assert h.now == 300 * MS

"""Runs one component offline, on scripted input samples and a manual clock, for tests.

    from kairos_sdk.harness import Harness

    def test_gain():
        h = Harness(Gain, properties={"factor": 3.0})
        h.push("in", 1.5, timestamp=10_000_000)
        h.push("in", 2.0)                      # 1 ms after the previous one
        out = h.run()
        assert out.values("out") == [4.5, 6.0]
        assert out.samples("out")[0].timestamp == 10_000_000

The Python counterpart of the Rust SDK's `Harness`. Samples are delivered one at a time, in the order they
were pushed, the clock set to each one's timestamp, and `core` is called until the component finds nothing
more to read: a blocking read with nothing scripted left ends that `core` call. Periodic components run a
number of periods, the clock jumping from tick to tick. Writes are checked exactly as under the runtime,
and exceptions in the component's code reach the test unchanged.
"""

import collections
import json

from .component import (
    ContextBase, EndOfStream, Interrupted, Stopped, WrongType, _describe, image_geometry, infer_type, normalize,
    numpy,
)
from .descriptor import Descriptor
from .types import ANY, IMAGE, POINT_CLOUD, Sample

#: The spacing of pushed samples given no timestamp.
DEFAULT_SPACING_NS = 1_000_000

_NEWEST_FIRST = ("LastOrNext", "WaitForNext")


class _NothingScripted(BaseException):
    """A blocking read found nothing left to deliver: the current call ends (as the runtime's reactive
    components end theirs with no data). A `BaseException` so that `except Exception` does not catch it."""


class ManualClock:
    """The harness clock: nanoseconds that move only when told to."""

    def __init__(self, start=0):
        self.now = int(start)

    def set(self, timestamp):
        """Sets the time to `timestamp` (ns)."""
        self.now = int(timestamp)

    def advance(self, seconds):
        """Moves the time forward by `seconds`."""
        if seconds < 0:
            raise ValueError(f"the clock only moves forward, got {seconds} s")
        self.now += round(seconds * 1e9)


class Output:
    """What the component wrote, by output name, in order."""

    def __init__(self, output_names):
        #: Every declared output's samples (an empty list for an output that wrote nothing).
        self.all = {name: [] for name in output_names}

    def samples(self, output):
        """The samples written on `output`."""
        try:
            return self.all[output]
        except KeyError:
            raise KeyError(f"no output '{output}' (outputs: {', '.join(self.all) or 'none'})") from None

    def values(self, output):
        """The data of the samples written on `output`."""
        return [sample.data for sample in self.samples(output)]

    def extend(self, other):
        """Adds the samples of `other` after these (to gather several runs)."""
        for name, samples in other.all.items():
            self.all.setdefault(name, []).extend(samples)

    def __repr__(self):
        counts = ", ".join(f"{name}: {len(samples)}" for name, samples in self.all.items())
        return f"Output({counts})"


class _Input:
    """One input's delivered, unread samples, read under the input's default policy."""

    def __init__(self, policy):
        self.policy = policy
        self.unread = collections.deque()
        self.last = None  # what a Sampling reader read last, read again when nothing newer came
        self.pushed = False
        self.closed = False

    def take(self):
        """(sample, fresh) or (None, False). WaitForNext reads as LastOrNext: samples are delivered one at
        a time before `core` runs, so waiting for "the next" would pass over the one just delivered."""
        if self.policy == "Sampling":
            if self.unread:
                self.last = self.unread.pop()
                self.unread.clear()
                return self.last, True
            return self.last, False
        if not self.unread:
            return None, False
        if self.policy in _NEWEST_FIRST:
            sample = self.unread.pop()
            self.unread.clear()
            return sample, True
        return self.unread.popleft(), True


class HarnessContext(ContextBase):
    """The `ctx` a component gets under the harness: the methods of the runtime's, on scripted inputs."""

    def __init__(self, component_id, descriptor, properties, clock):
        super().__init__(component_id, descriptor, properties)
        self.clock = clock
        self.period_ns = None
        self.status = None
        self.fresh_reads = 0
        self._inputs = {p["name"]: _Input(p["default_policy"]) for p in descriptor.inputs}
        self._output_names = [p["name"] for p in descriptor.outputs]
        self._sequences = [0] * len(self._output_names)
        self._written = Output(self._output_names)
        self._any_rotation = 0
        self._synchronizers = {}

    # ----- what the harness drives -----

    def _deliver(self, input_name, sample):
        self._inputs[input_name].unread.append(sample)

    def _close_inputs(self):
        for port in self._inputs.values():
            port.closed = True

    def _drain(self):
        written, self._written = self._written, Output(self._output_names)
        return written

    # ----- inputs -----

    def _take(self, input_name):
        self.input_index(input_name)
        sample, fresh = self._inputs[input_name].take()
        if fresh:
            self.fresh_reads += 1
        return sample

    def _wait(self, input_names):
        """Nothing to read on `input_names`: the stream ended if every one is closed, else the call ends."""
        if input_names and all(self._inputs[name].closed for name in input_names):
            raise EndOfStream()
        raise _NothingScripted()

    def is_connected(self, input_name):
        """True for an input something was pushed to."""
        self.input_index(input_name)
        return self._inputs[input_name].pushed

    def read(self, input_name):
        """The next scripted sample of `input_name` under its policy; with none left, the call ends."""
        sample = self._take(input_name)
        if sample is None:
            self._wait([input_name])
        return sample

    def try_read(self, input_name):
        """A sample of `input_name` if one is there under its policy, else `None`."""
        return self._take(input_name)

    def read_any(self, input_names):
        """(name, sample) from whichever of `input_names` has data, starting after the one served last."""
        for name in input_names:
            self.input_index(name)
        count = len(input_names)
        for step in range(count):
            position = (self._any_rotation + step) % count
            sample = self._take(input_names[position])
            if sample is not None:
                self._any_rotation = position + 1
                return input_names[position], sample
        self._wait(input_names)

    def read_synchronized(self, input_names, tolerance):
        """One sample per input, their timestamps within `tolerance` seconds of each other; a sample that
        can no longer be matched (another input is past it by more than the tolerance) is dropped."""
        for name in input_names:
            self.input_index(name)
        key = tuple(input_names)
        pending = self._synchronizers.setdefault(key, [None] * len(input_names))
        tolerance_ns = int(tolerance * 1e9)
        while True:
            for position, name in enumerate(input_names):
                if pending[position] is None:
                    pending[position] = self._take(name)
            missing = [name for name, slot in zip(input_names, pending) if slot is None]
            if missing:
                # Matched samples wait in `pending` for the next call, as the runtime's synchroniser keeps them.
                if any(self._inputs[name].closed for name in missing):
                    raise EndOfStream()
                raise _NothingScripted()
            stamps = [sample.timestamp for sample in pending]
            newest = max(stamps)
            if newest - min(stamps) <= tolerance_ns:
                matched = list(pending)
                pending[:] = [None] * len(input_names)
                return matched
            # Timestamps only grow per input: one older than the newest minus the tolerance never matches.
            for position, sample in enumerate(pending):
                if newest - sample.timestamp > tolerance_ns:
                    pending[position] = None

    # ----- outputs -----

    def new_image(self, width, height, format="rgb8"):  # noqa: A002 - the keyword users write
        """A writable image of `height` × `width` (× channels), zeros."""
        dtype, shape = image_geometry(width, height, format)
        return numpy().zeros(shape, dtype)

    def write(self, output, data, timestamp=None, format=None, intensity=None):  # noqa: A002
        """Writes `data` on `output`; `timestamp` (ns) when the data originated, else now. Checked against
        the output's type: `WrongType` names the port and the type."""
        index, data_type, value, extra = self.checked(output, data, format, intensity)
        now = self.clock.now
        sample = Sample(_frozen(value), now if timestamp is None else int(timestamp), now,
                        self._sequences[index], data_type)
        if data_type == IMAGE:
            sample.format = extra
        elif data_type == POINT_CLOUD and extra is not None:
            sample.intensity = _frozen(extra)
        self._sequences[index] += 1
        self._written.all[output].append(sample)

    # ----- time and the rest -----

    def now(self):
        """The harness clock, in nanoseconds."""
        return self.clock.now

    def sleep(self, seconds):
        """Moves the harness clock forward by `seconds` (no real waiting)."""
        self.clock.advance(max(0.0, seconds))

    def wait_until(self, timestamp):
        """Moves the harness clock to `timestamp` (ns) if it is later."""
        self.clock.set(max(self.clock.now, int(timestamp)))

    def set_period(self, seconds):
        """The period of a periodic component, in seconds."""
        if not seconds > 0:
            raise ValueError(f"a period is a positive number of seconds, got {seconds!r}")
        self.period_ns = round(seconds * 1e9)

    def stop_requested(self):
        """Never: the harness stops a component by not calling it again."""
        return False

    def set_status(self, status):
        """Keeps `status` as the runtime would show it: through JSON."""
        self.status = json.loads(json.dumps(status))


def _frozen(value):
    """A numpy array as readers get it under the runtime, a copy they cannot change; other values as they are."""
    if getattr(value, "flags", None) is None or getattr(value, "ndim", 0) == 0:
        return value
    array = value.copy()
    array.flags.writeable = False
    return array


class Harness:
    """Runs one component offline. See the module documentation.

    `component` is a `Component` subclass or an instance of one; `properties` maps names to initial
    values, checked against the descriptor (the others take their defaults).
    """

    def __init__(self, component, properties=None, id="under_test"):  # noqa: A002 - as the runtime names it
        self.component = component() if isinstance(component, type) else component
        descriptor = getattr(self.component, "descriptor", None)
        if not isinstance(descriptor, Descriptor):
            raise TypeError(f"{type(self.component).__name__} has no descriptor: give it "
                            "`descriptor = Descriptor(\"name\", ...)`")
        self.descriptor = descriptor
        values = {prop.name: prop.default for prop in descriptor.properties}
        for name, value in (properties or {}).items():
            values[name] = self._property(name).check(value)
        #: The harness clock (`h.clock.advance(seconds)`, `h.clock.set(ns)`).
        self.clock = ManualClock()
        self.ctx = HarnessContext(id, descriptor, values, self.clock)
        #: "new" before birth, "running", "stopped" (the component raised `Stopped`), "finished" (its
        #: inputs ended: `EndOfStream`), "dead" after `finish`.
        self.state = "new"
        self._pending = collections.deque()
        self._sequences = {p["name"]: 0 for p in descriptor.inputs}
        self._last_pushed = None

    # ----- scripting -----

    @property
    def now(self):
        """The harness clock's time, in nanoseconds."""
        return self.clock.now

    @property
    def status(self):
        """What the component published last with `ctx.set_status`, or `None`."""
        return self.ctx.status

    @property
    def properties(self):
        """The current property values."""
        return dict(self.ctx.properties)

    def push(self, input, data, timestamp=None, format=None, intensity=None):  # noqa: A002
        """Scripts a sample of `data` on `input`, both times at `timestamp` (ns; default: 1 ms after the
        previous push, or after now). `format` is an image's pixel format, `intensity` a point cloud's."""
        if timestamp is None:
            base = self.clock.now if self._last_pushed is None else self._last_pushed
            timestamp = base + DEFAULT_SPACING_NS
        sample = Sample(data, int(timestamp), int(timestamp), self._sequences.get(input, 0), format=format,
                        intensity=intensity)
        self.push_sample(input, sample)
        return self

    def push_sample(self, input, sample):  # noqa: A002
        """Scripts a whole `Sample` on `input`; its data is converted to a type the input accepts."""
        port = next((p for p in self.descriptor.inputs if p["name"] == input), None)
        if port is None:
            names = ", ".join(p["name"] for p in self.descriptor.inputs) or "none"
            raise ValueError(f"no input '{input}' (inputs: {names})")
        data_type, value, extra = _accepted(input, port["filter"], sample)
        delivered = Sample(_frozen(value), sample.timestamp, sample.time_of_issue or sample.timestamp,
                           sample.sequence, data_type)
        if data_type == IMAGE:
            delivered.format = extra
        elif data_type == POINT_CLOUD and extra is not None:
            delivered.intensity = _frozen(extra)
        self._pending.append((input, delivered))
        self._sequences[input] = sample.sequence + 1
        self._last_pushed = delivered.timestamp
        self.ctx._inputs[input].pushed = True
        return self

    def set_property(self, name, value):
        """Sets a property, checked against the descriptor. Before the first run it is the initial value;
        after, a live change delivered through `property_changed` (a property that is not live is refused,
        as the runtime refuses it)."""
        prop = self._property(name)
        value = prop.check(value)
        if self.state == "new":
            self.ctx.properties[name] = value
            return
        self._check_alive()
        if not prop.is_live:
            raise ValueError(f"property '{name}' is not live: it cannot change while the component runs "
                             "(set it in Harness(..., properties=...) or mark it .live())")
        self.ctx.properties[name] = value
        self._call(lambda: self.component.property_changed(name, value, self.ctx))

    def action(self, name):
        """Triggers action `name` and returns what the component wrote (since the last collection)."""
        if name not in [a["name"] for a in self.descriptor.actions]:
            names = ", ".join(a["name"] for a in self.descriptor.actions) or "none"
            raise ValueError(f"no action '{name}' (actions: {names})")
        self._check_alive()
        self._start()
        self._call(lambda: self.component.action(name, self.ctx))
        return self.ctx._drain()

    # ----- running -----

    def run(self):
        """Delivers every sample pushed since the last run, one at a time, calling `core` after each until
        it reads nothing more, and returns what the component wrote. A component without inputs gets one
        `core` call."""
        self._check_alive()
        self._start()
        if not self._pending and not self.descriptor.inputs:
            self._cycle_until_idle()
        while self._pending:
            input_name, sample = self._pending.popleft()
            self.clock.set(_arrival(sample))
            if self.state != "running":
                continue  # a stopped component reads nothing more
            self.ctx._deliver(input_name, sample)
            self._cycle_until_idle()
        return self.ctx._drain()

    def run_periodic(self, cycles):
        """Calls `core` `cycles` times, one period apart, from the current time; the period is the one the
        component set (`ctx.set_period`, `ctx.set_frequency`). Pushed samples reach the inputs once the
        clock reaches their timestamps."""
        self._check_alive()
        self._start()
        tick = self.clock.now
        for _ in range(cycles):
            if self.state != "running":
                break
            period = self.ctx.period_ns
            if period is None:
                raise RuntimeError("the component set no period in birth "
                                   "(call ctx.set_period or ctx.set_frequency)")
            while self._pending and _arrival(self._pending[0][1]) <= self.clock.now:
                self.ctx._deliver(*self._pending.popleft())
            self._call(lambda: self.component.core(self.ctx))
            # Ticks keep their spacing when `core` sleeps; one that ran past its tick starts the next late.
            tick += period
            self.clock.set(max(self.clock.now, tick))
        return self.ctx._drain()

    def finish(self):
        """Delivers what is still pushed, ends the inputs (reads then raise `EndOfStream`, as at the end of
        a replay) and lets the component finish, calls `death`, and returns the last outputs."""
        self._check_alive()
        self._start()
        out = self.run() if self._pending else self._output()
        if self.descriptor.inputs and self.state == "running":
            self.ctx._close_inputs()
            self._cycle_until_idle()
        self._call(lambda: self.component.death(self.ctx), ending=True)
        self.state = "dead"
        out.extend(self.ctx._drain())
        return out

    # ----- internals -----

    def _output(self):
        return Output([p["name"] for p in self.descriptor.outputs])

    def _property(self, name):
        prop = self.descriptor.property_named(name)
        if prop is None:
            names = ", ".join(p.name for p in self.descriptor.properties) or "none"
            raise ValueError(f"no property '{name}' (properties: {names})")
        return prop

    def _check_alive(self):
        if self.state == "dead":
            raise RuntimeError("the component is dead: finish() was called")

    def _start(self):
        if self.state == "new":
            self.state = "running"
            self._call(lambda: self.component.birth(self.ctx))

    def _call(self, call, ending=False):
        """Calls into the component: what it raises ends the call as it ends it under the runtime (see the
        worker), and the component's own errors reach the test."""
        try:
            call()
        except (_NothingScripted, Interrupted):
            pass
        except Stopped:
            if not ending:
                self.state = "stopped"
        except EndOfStream:
            if not ending:
                self.state = "finished"

    def _cycle_until_idle(self):
        """Calls `core` while it keeps reading new samples."""
        while self.state == "running":
            self.ctx.fresh_reads = 0
            self._call(lambda: self.component.core(self.ctx))
            if self.ctx.fresh_reads == 0:
                return


def _arrival(sample):
    """When a scripted sample reaches its input: when it was issued, and never before its timestamp."""
    return max(sample.timestamp, sample.time_of_issue)


def _accepted(input_name, type_filter, sample):
    """(data type, value, extra) of `sample` as input `input_name` accepts it; `WrongType` if it cannot."""
    value = sample.data
    if type_filter == ANY:
        candidates = [sample.type or infer_type(value)]
    else:
        accepted = type_filter["one_of"]
        preferred = sample.type
        if not preferred:
            try:
                preferred = infer_type(value)
            except WrongType:
                preferred = None
        candidates = ([preferred] if preferred in accepted else []) + [t for t in accepted if t != preferred]
    for data_type in candidates:
        try:
            if data_type == IMAGE:
                return normalize(input_name, IMAGE, value, sample.format)
            return normalize(input_name, data_type, value, None, sample.intensity)
        except WrongType:
            continue
    accepted = "any type" if type_filter == ANY else " or ".join(type_filter["one_of"])
    raise WrongType(f"input '{input_name}' accepts {accepted}: cannot deliver {_describe(value)}")


__all__ = ["Harness", "HarnessContext", "ManualClock", "Output"]

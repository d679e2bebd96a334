"""What a component declares: inputs, outputs, properties with ranges, actions.

A builder that mirrors the Rust SDK's `Descriptor`:

    descriptor = (
        Descriptor("threshold", category="vision", doc="Keeps the pixels brighter than a level")
        .input("image", IMAGE, doc="The camera")
        .output("mask", IMAGE, doc="255 where brighter, 0 elsewhere")
        .property(Property.i64("level", 128).range(0, 255).live().doc("The grey level"))
        .action("reset", doc="Forgets the background")
    )
"""

import math
import re

from .types import ANY, BUILT_IN_TYPES

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TYPE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")

#: Reader policies, as diagrams spell them, and as the runtime's descriptors name them.
POLICIES = {
    "fifo": "Fifo",
    "last_or_next": "LastOrNext",
    "wait_for_next": "WaitForNext",
    "sampling": "Sampling",
    "never_skipping": "NeverSkipping",
}

MODES = ("threaded", "periodic")


class DescriptorError(ValueError):
    """A descriptor that cannot be registered; the message names the field and the fix."""


def _check_name(kind, name):
    if not isinstance(name, str) or not _NAME.match(name):
        raise DescriptorError(f"{kind} name {name!r} must be letters, digits and '_', not starting with a digit")


def _check_type(where, data_type):
    if not isinstance(data_type, str) or not _TYPE_NAME.match(data_type):
        raise DescriptorError(f"{where}: type {data_type!r} is not a type name (one of {', '.join(BUILT_IN_TYPES)})")


def _float_or_none(value):
    return None if value is None else float(value)


def _type_json(data_type):
    """A data type as the runtime's descriptors spell it: built-in types by name, a pack's as
    `{"custom": name}`."""
    return data_type if data_type in BUILT_IN_TYPES else {"custom": data_type}


class Property:
    """A property: a kind, a default, and optionally a range, a unit, a document, and whether it is live
    (changed while the diagram runs, through `property_changed`)."""

    def __init__(self, name, kind, default):
        _check_name("property", name)
        self.name = name
        self.kind = kind
        self.default = default
        self.min = None
        self.max = None
        self.choices = None
        self.is_live = False
        self.text = ""
        self.unit_text = ""

    @classmethod
    def f64(cls, name, default):
        if isinstance(default, bool) or not isinstance(default, (int, float)) or not math.isfinite(default):
            raise DescriptorError(f"property '{name}': default {default!r} is not a finite number")
        return cls(name, "f64", float(default))

    @classmethod
    def i64(cls, name, default):
        if isinstance(default, bool) or not isinstance(default, int):
            raise DescriptorError(f"property '{name}': default {default!r} is not an integer")
        return cls(name, "i64", default)

    @classmethod
    def bool(cls, name, default):
        if not isinstance(default, bool):
            raise DescriptorError(f"property '{name}': default {default!r} is not True or False")
        return cls(name, "bool", default)

    @classmethod
    def text(cls, name, default=""):
        if not isinstance(default, str):
            raise DescriptorError(f"property '{name}': default {default!r} is not text")
        return cls(name, "text", default)

    @classmethod
    def path(cls, name, default=""):
        prop = cls.text(name, default)
        prop.kind = "path"
        return prop

    @classmethod
    def choice(cls, name, choices, default):
        choices = list(choices)
        if not choices or not all(isinstance(c, str) for c in choices):
            raise DescriptorError(f"property '{name}': choices must be a non-empty list of text")
        if default not in choices:
            raise DescriptorError(f"property '{name}': default {default!r} is not one of {choices}")
        prop = cls(name, "choice", default)
        prop.choices = choices
        return prop

    def range(self, min=None, max=None):  # noqa: A002 - mirrors the Rust builder
        """Bounds, inclusive; `None` leaves a side open."""
        if self.kind not in ("f64", "i64"):
            raise DescriptorError(f"property '{self.name}': only numbers have a range")
        # Kinds first: comparing a text bound would raise a bare TypeError.
        for bound in (min, max):
            if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float))):
                raise DescriptorError(f"property '{self.name}': bound {bound!r} is not a number")
            if self.kind == "i64" and bound is not None and not isinstance(bound, int):
                raise DescriptorError(f"property '{self.name}': an integer property takes integer bounds")
        if min is not None and max is not None and min > max:
            raise DescriptorError(f"property '{self.name}': range {min}..{max} is empty")
        if (min is not None and self.default < min) or (max is not None and self.default > max):
            raise DescriptorError(f"property '{self.name}': default {self.default} is outside {min}..{max}")
        self.min, self.max = min, max
        return self

    def live(self):
        """Marks the property as changeable while the diagram runs."""
        self.is_live = True
        return self

    def doc(self, text):
        self.text = text
        return self

    def unit(self, unit):
        self.unit_text = unit
        return self

    def check(self, value):
        """The value converted to this property's kind; `ValueError` naming the property when it does not fit."""
        kind = self.kind
        if kind == "f64":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"property '{self.name}' takes a number, got {value!r}")
            value = float(value)
            if math.isnan(value):
                # The runtime refuses NaN: it fits no range.
                raise ValueError(f"property '{self.name}' takes a number, got NaN")
        elif kind == "i64":
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"property '{self.name}' takes an integer, got {value!r}")
        elif kind == "bool":
            if not isinstance(value, bool):
                raise ValueError(f"property '{self.name}' takes true or false, got {value!r}")
        elif not isinstance(value, str):
            raise ValueError(f"property '{self.name}' takes text, got {value!r}")
        if kind == "choice" and value not in self.choices:
            raise ValueError(f"property '{self.name}' takes one of {self.choices}, got {value!r}")
        if self.min is not None and value < self.min or self.max is not None and value > self.max:
            raise ValueError(f"property '{self.name}': {value} is outside {self.min}..{self.max}")
        return value

    def to_json(self):
        if self.kind == "f64":
            # Bounds are f64 on the runtime's side: 0, not 0.0, would not be the same JSON.
            kind = {"f64": {"min": _float_or_none(self.min), "max": _float_or_none(self.max)}}
        elif self.kind == "i64":
            kind = {"i64": {"min": self.min, "max": self.max}}
        elif self.kind == "choice":
            kind = {"choice": list(self.choices)}
        else:
            kind = self.kind
        info = {"name": self.name, "kind": kind, "default": self.default, "live": self.is_live, "doc": self.text}
        if self.unit_text:
            info["unit"] = self.unit_text
        return info


class Descriptor:
    """A component's declaration. `name` is the type's short name (the pack's name is put before it) or
    the whole `pack.name`."""

    def __init__(self, name, category="", doc="", label=""):
        if not isinstance(name, str) or not _TYPE_NAME.match(name):
            raise DescriptorError(f"component name {name!r} must be letters, digits and '_' (optionally pack.name)")
        self.name = name
        self.category = category
        self.doc = doc
        self.label = label
        self.mode = "threaded"
        self.blocking_reason = None
        self.inputs = []
        self.outputs = []
        self.properties = []
        self.actions = []

    def _taken(self, name):
        taken = [p["name"] for p in self.inputs] + [p["name"] for p in self.outputs]
        if name in taken:
            raise DescriptorError(f"port '{name}' is declared twice")

    def input(self, name, types=ANY, doc="", policy="fifo"):
        """An input accepting `types`: one type name, a list of them, or `ANY`."""
        _check_name("input", name)
        self._taken(name)
        if policy not in POLICIES:
            raise DescriptorError(f"input '{name}': policy {policy!r} is not one of {', '.join(POLICIES)}")
        if types == ANY:
            filter_ = "any"
        else:
            listed = [types] if isinstance(types, str) else list(types)
            if not listed:
                raise DescriptorError(f"input '{name}' accepts no type: give one, several, or ANY")
            for data_type in listed:
                _check_type(f"input '{name}'", data_type)
            filter_ = {"one_of": listed}
        self.inputs.append({"name": name, "filter": filter_, "default_policy": POLICIES[policy], "doc": doc})
        return self

    def output(self, name, data_type, doc="", buffer=16):
        """An output of `data_type`."""
        _check_type(f"output '{name}'", data_type)
        return self._output(name, data_type, doc, buffer, None)

    def output_following(self, name, input_name, doc="", buffer=16):
        """An output carrying samples of whatever type feeds input `input_name` (a pass-through)."""
        if input_name not in [p["name"] for p in self.inputs]:
            raise DescriptorError(f"output '{name}' follows '{input_name}', which is not an input declared before it")
        return self._output(name, f"same as {input_name}", doc, buffer, input_name)

    def _output(self, name, data_type, doc, buffer, follows):
        _check_name("output", name)
        self._taken(name)
        if not isinstance(buffer, int) or isinstance(buffer, bool) or buffer < 1:
            raise DescriptorError(f"output '{name}': buffer {buffer!r} must be a positive number of samples")
        info = {"name": name, "data_type": data_type, "default_buffer_size": buffer, "doc": doc}
        if follows is not None:
            info["follows_input"] = follows
        self.outputs.append(info)
        return self

    def property(self, prop):
        if not isinstance(prop, Property):
            raise DescriptorError(f"property {prop!r} is not made with Property.f64/i64/bool/text/path/choice")
        if prop.name in [p.name for p in self.properties]:
            raise DescriptorError(f"property '{prop.name}' is declared twice")
        self.properties.append(prop)
        return self

    def action(self, name, doc=""):
        _check_name("action", name)
        self.actions.append({"name": name, "doc": doc})
        return self

    def periodic(self):
        """Runs `core` once per period (set with `ctx.set_period` or `ctx.set_frequency` in `birth`)."""
        self.mode = "periodic"
        return self

    def blocking(self, reason):
        """Says that a call may wait for long (on a device, a socket, its own timing), and why, in words: the
        component then shares an execution group's thread only as the group's driver."""
        if not isinstance(reason, str) or not reason.strip():
            raise DescriptorError("blocking needs the reason, in words (\"waits for each frame of the camera\")")
        self.blocking_reason = reason.strip()
        return self

    def type_name(self, pack):
        return self.name if "." in self.name else f"{pack}.{self.name}"

    def property_named(self, name):
        for prop in self.properties:
            if prop.name == name:
                return prop
        return None

    def output_named(self, name):
        for port in self.outputs:
            if port["name"] == name:
                return port
        return None

    def to_json(self, pack):
        """The descriptor as the runtime reads it (its `ComponentInfo`)."""
        return {
            "type_name": self.type_name(pack),
            "pack": pack,
            "label": self.label,
            "category": self.category,
            "doc": self.doc,
            "mode": self.mode,
            "inputs": [_port_json(p, "filter") for p in self.inputs],
            "outputs": [_port_json(p, "data_type") for p in self.outputs],
            "properties": [p.to_json() for p in self.properties],
            "actions": self.actions,
        } | ({"blocking": self.blocking_reason} if self.blocking_reason else {})


def _port_json(port, field):
    """A port with its type field spelled as the runtime reads it."""
    value = port[field]
    if isinstance(value, dict):  # an input filter {"one_of": [...]}
        value = {"one_of": [_type_json(t) for t in value["one_of"]]}
    elif field == "data_type":
        value = _type_json(value)
    return {**port, field: value}

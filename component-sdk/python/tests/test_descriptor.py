"""Descriptors: what is refused, and the JSON the runtime reads (its `ComponentInfo`, serde's shape)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from kairos_sdk import (
    ANY, BOOL, F64, I64, IMAGE, IMU, POINT_CLOUD, TEXT, VECTOR, Custom, Descriptor, DescriptorError, Imu,
    Property, WrongType,
)
from kairos_sdk.component import infer_type, normalize

LIBRARY = Path(__file__).resolve().parents[3] / "studio" / "tests" / "library.json"


def canonical(value):
    """JSON text with sorted keys: 100000 and 100000.0 differ here, as they do on the wire."""
    return json.dumps(value, sort_keys=True, ensure_ascii=False)


def library_entry(type_name):
    if not LIBRARY.is_file():
        pytest.skip(f"{LIBRARY} is not in this checkout")
    components = json.loads(LIBRARY.read_text(encoding="utf-8"))["components"]
    return next(c for c in components if c["type_name"] == type_name)


# ----- refused descriptors -----


@pytest.mark.parametrize("name", ["9lives", "has space", "dash-ed", "", "a.", ".a", "a..b", 3])
def test_component_names_are_checked(name):
    with pytest.raises(DescriptorError, match="component name"):
        Descriptor(name)


def test_pack_qualified_names_are_accepted():
    assert Descriptor("mypack.filter").type_name("other") == "mypack.filter"
    assert Descriptor("filter").type_name("mypack") == "mypack.filter"


@pytest.mark.parametrize("build, kind", [
    (lambda d: d.input("in put", F64), "input"),
    (lambda d: d.output("1out", F64), "output"),
    (lambda d: d.action("re-set"), "action"),
])
def test_port_and_action_names_are_checked(build, kind):
    with pytest.raises(DescriptorError, match=f"{kind} name"):
        build(Descriptor("probe"))


def test_property_names_are_checked():
    with pytest.raises(DescriptorError, match="property name 'bad name'"):
        Property.f64("bad name", 1.0)


def test_an_empty_range_is_refused():
    with pytest.raises(DescriptorError, match=r"property 'level': range 5\.\.2 is empty"):
        Property.f64("level", 3.0).range(5, 2)


@pytest.mark.parametrize("prop, bounds", [
    (Property.i64("level", 300), (0, 255)),
    (Property.f64("gain", -1.0), (0.0, None)),
    (Property.f64("gain", 11.0), (None, 10.0)),
])
def test_a_default_outside_its_range_is_refused(prop, bounds):
    with pytest.raises(DescriptorError, match=f"property '{prop.name}': default .* is outside"):
        prop.range(*bounds)


def test_ranges_only_for_numbers_and_integer_bounds_for_integers():
    with pytest.raises(DescriptorError, match="only numbers have a range"):
        Property.text("name", "x").range(0, 1)
    with pytest.raises(DescriptorError, match="integer bounds"):
        Property.i64("count", 1).range(0, 2.5)
    with pytest.raises(DescriptorError, match="is not a number"):
        Property.f64("gain", 1.0).range("0", 2)


@pytest.mark.parametrize("make, message", [
    (lambda: Property.f64("gain", "1"), "not a finite number"),
    (lambda: Property.f64("gain", math.inf), "not a finite number"),
    (lambda: Property.f64("gain", True), "not a finite number"),
    (lambda: Property.i64("count", 1.0), "not an integer"),
    (lambda: Property.bool("on", 1), "not True or False"),
    (lambda: Property.text("name", None), "not text"),
    (lambda: Property.choice("mode", [], "a"), "non-empty list"),
    (lambda: Property.choice("mode", ["a", "b"], "c"), "'c' is not one of"),
])
def test_defaults_of_the_wrong_kind_are_refused(make, message):
    with pytest.raises(DescriptorError, match=message):
        make()


def test_duplicate_ports_are_refused():
    with pytest.raises(DescriptorError, match="port 'x' is declared twice"):
        Descriptor("probe").input("x", F64).input("x", F64)
    with pytest.raises(DescriptorError, match="port 'x' is declared twice"):
        Descriptor("probe").input("x", F64).output("x", F64)
    with pytest.raises(DescriptorError, match="port 'y' is declared twice"):
        Descriptor("probe").output("y", F64).output("y", I64)


def test_duplicate_properties_are_refused():
    with pytest.raises(DescriptorError, match="property 'gain' is declared twice"):
        Descriptor("probe").property(Property.f64("gain", 1.0)).property(Property.i64("gain", 1))


def test_a_bad_policy_is_refused_and_the_good_ones_listed():
    with pytest.raises(DescriptorError, match="input 'in': policy 'lifo' is not one of fifo, last_or_next"):
        Descriptor("probe").input("in", F64, policy="lifo")


def test_bad_types_are_refused():
    with pytest.raises(DescriptorError, match="input 'in' accepts no type"):
        Descriptor("probe").input("in", [])
    with pytest.raises(DescriptorError, match="output 'out': type 'f 64' is not a type name"):
        Descriptor("probe").output("out", "f 64")
    with pytest.raises(DescriptorError, match="input 'in': type 3"):
        Descriptor("probe").input("in", [F64, 3])


def test_outputs_are_checked():
    with pytest.raises(DescriptorError, match="buffer 0 must be a positive"):
        Descriptor("probe").output("out", F64, buffer=0)
    with pytest.raises(DescriptorError, match="follows 'in', which is not an input declared before it"):
        Descriptor("probe").output_following("out", "in")
    with pytest.raises(DescriptorError, match="not made with Property"):
        Descriptor("probe").property({"name": "gain"})


# ----- property values -----


def test_property_values_are_checked_and_converted():
    gain = Property.f64("gain", 1.0).range(-10, 10)
    assert gain.check(3) == 3.0 and isinstance(gain.check(3), float)
    with pytest.raises(ValueError, match=r"property 'gain': 11.0 is outside -10\.\.10"):
        gain.check(11)
    with pytest.raises(ValueError, match="property 'gain' takes a number, got True"):
        gain.check(True)
    with pytest.raises(ValueError, match="property 'gain' takes a number, got NaN"):
        Property.f64("gain", 1.0).check(float("nan"))
    count = Property.i64("count", 1).range(0, None)
    assert count.check(5) == 5
    with pytest.raises(ValueError, match="takes an integer, got 2.5"):
        count.check(2.5)
    with pytest.raises(ValueError, match="-1 is outside 0..None"):
        count.check(-1)
    mode = Property.choice("mode", ["fast", "exact"], "fast")
    assert mode.check("exact") == "exact"
    with pytest.raises(ValueError, match=r"property 'mode' takes one of \['fast', 'exact'\], got 'slow'"):
        mode.check("slow")
    with pytest.raises(ValueError, match="takes true or false"):
        Property.bool("on", False).check(0)
    with pytest.raises(ValueError, match="takes text"):
        Property.path("file").check(3)


# ----- the JSON the runtime reads -----


def test_gain_json_is_the_runtimes_own():
    gain = (
        Descriptor("gain", category="math", doc="Multiplies each sample by a gain, keeping its timestamp",
                   label="Gain")
        .input("in", [F64, I64, BOOL], doc="The signal")
        .output("out", F64, doc="gain × in")
        .property(Property.f64("gain", 1).live().doc("The factor"))
    )
    assert canonical(gain.to_json("core")) == canonical(library_entry("core.gain"))


def test_counter_json_is_the_runtimes_own():
    counter = (
        Descriptor("counter", category="generators", doc="Counts: start, start + step, start + 2 × step, ...",
                   label="Counter")
        .periodic()
        .output("out", I64, doc="The count")
        .property(Property.f64("rate", 10).range(0.001, 100000).live().doc("Samples per second (Hz)").unit("Hz"))
        .property(Property.i64("start", 0).doc("The first value"))
        .property(Property.i64("step", 1).live().doc("Added at each sample"))
        .action("reset", doc="Starts counting again from `start`")
    )
    assert canonical(counter.to_json("core")) == canonical(library_entry("core.counter"))


def test_delay_json_is_the_runtimes_own():
    delay = (
        Descriptor("delay", category="flow", label="Delay",
                   doc="Holds each sample for `delay_ms` before passing it on: stands in for a slow algorithm "
                       "when sizing buffers")
        .input("in", ANY, doc="Any stream")
        .output_following("out", "in", doc="The input, later; timestamps kept")
        .property(Property.f64("delay_ms", 10).range(0, 60000).live().doc("Time spent on each sample").unit("ms"))
        .blocking("it holds each sample for delay_ms before passing it on")
    )
    assert canonical(delay.to_json("core")) == canonical(library_entry("core.delay"))


def test_a_blocking_component_says_why_and_an_empty_reason_is_refused():
    with pytest.raises(DescriptorError, match="reason"):
        Descriptor("waits").blocking("  ")
    assert "blocking" not in Descriptor("plain").to_json("p")


def test_every_field_is_spelled_as_serde_spells_it():
    descriptor = (
        Descriptor("vision.detector", category="vision", doc="Finds things")
        .input("image", IMAGE, doc="The camera", policy="last_or_next")
        .input("pose", ["pose", "mypack.odometry"], policy="never_skipping")
        .input("anything", ANY, policy="sampling")
        .input("trigger", BOOL, policy="wait_for_next")
        .output("boxes", "mypack.boxes", doc="What it found", buffer=4)
        .output_following("echo", "anything")
        .property(Property.f64("score", 0.5).range(0, 1).unit("").doc("Least score"))
        .property(Property.i64("every", 2).range(1, None))
        .property(Property.bool("draw", True).live())
        .property(Property.text("label", "x"))
        .property(Property.path("model"))
        .property(Property.choice("device", ["cpu", "gpu"], "cpu"))
        .action("snapshot")
    )
    assert descriptor.to_json("ignored") == {
        "type_name": "vision.detector",
        "pack": "ignored",
        "label": "",
        "category": "vision",
        "doc": "Finds things",
        "mode": "threaded",
        "inputs": [
            {"name": "image", "filter": {"one_of": ["image"]}, "default_policy": "LastOrNext", "doc": "The camera"},
            {"name": "pose", "filter": {"one_of": ["pose", {"custom": "mypack.odometry"}]},
             "default_policy": "NeverSkipping", "doc": ""},
            {"name": "anything", "filter": "any", "default_policy": "Sampling", "doc": ""},
            {"name": "trigger", "filter": {"one_of": ["bool"]}, "default_policy": "WaitForNext", "doc": ""},
        ],
        "outputs": [
            {"name": "boxes", "data_type": {"custom": "mypack.boxes"}, "default_buffer_size": 4,
             "doc": "What it found"},
            {"name": "echo", "data_type": {"custom": "same as anything"}, "default_buffer_size": 16, "doc": "",
             "follows_input": "anything"},
        ],
        "properties": [
            {"name": "score", "kind": {"f64": {"min": 0.0, "max": 1.0}}, "default": 0.5, "live": False,
             "doc": "Least score"},
            {"name": "every", "kind": {"i64": {"min": 1, "max": None}}, "default": 2, "live": False, "doc": ""},
            {"name": "draw", "kind": "bool", "default": True, "live": True, "doc": ""},
            {"name": "label", "kind": "text", "default": "x", "live": False, "doc": ""},
            {"name": "model", "kind": "path", "default": "", "live": False, "doc": ""},
            {"name": "device", "kind": {"choice": ["cpu", "gpu"]}, "default": "cpu", "live": False, "doc": ""},
        ],
        "actions": [{"name": "snapshot", "doc": ""}],
    }
    text = json.dumps(descriptor.to_json("ignored"))
    # Untagged values and f64 bounds exactly as serde writes them.
    assert '"kind": {"f64": {"min": 0.0, "max": 1.0}}, "default": 0.5' in text
    assert '"kind": {"i64": {"min": 1, "max": null}}, "default": 2' in text


def test_to_json_leaves_the_descriptor_as_declared():
    descriptor = Descriptor("probe").output("out", "mypack.thing")
    descriptor.to_json("p")
    assert descriptor.outputs[0]["data_type"] == "mypack.thing"
    assert descriptor.output_named("out")["data_type"] == "mypack.thing"


# ----- what a write must be -----


@pytest.mark.parametrize("data_type, value, hint", [
    (F64, "1.0", "write a float"),
    (F64, True, "write a float"),
    (I64, 1.5, "write an int"),
    (BOOL, 1, "write True or False"),
    (TEXT, b"bytes", "write a str"),
    ("bytes", "text", "write bytes"),
    (VECTOR, [[1.0, 2.0]], "write an array of 1 dimension, not 2"),
    ("matrix", [1.0, 2.0], "write an array of 2 dimensions, not 1"),
    (VECTOR, ["a", "b"], "write a sequence of numbers"),
    (IMAGE, [[1, 2]], "write a numpy array"),
    (POINT_CLOUD, np.zeros((4, 2)), "write an N × 3 array"),
    (IMU, (1, 2, 3), "write a kairos_sdk.Imu"),
    ("mypack.boxes", 3, "write kairos_sdk.Custom"),
])
def test_normalize_names_the_port_and_the_type(data_type, value, hint):
    with pytest.raises(WrongType, match=f"(?s)output 'result' carries {data_type}: got .*{hint}"):
        normalize("result", data_type, value)


def test_normalize_converts_what_fits():
    assert normalize("o", F64, 2) == (F64, 2.0, None)
    assert normalize("o", F64, np.float32(0.5)) == (F64, 0.5, None)
    assert normalize("o", I64, np.int16(-3)) == (I64, -3, None)
    assert normalize("o", BOOL, np.True_) == (BOOL, True, None)
    assert normalize("o", BOOL, np.float64(2.0) > 1.0) == (BOOL, True, None)
    data_type, vector, _ = normalize("o", VECTOR, [1, 2, 3])
    assert data_type == VECTOR and vector.dtype == np.float64 and vector.tolist() == [1.0, 2.0, 3.0]
    data_type, value, _ = normalize("o", "mypack.boxes", b"\x01\x02")
    assert value == Custom("mypack.boxes", b"\x01\x02")
    with pytest.raises(WrongType, match=r"Custom\('mypack.boxes', data\)"):
        normalize("o", "mypack.boxes", Custom("other.type", b""))
    assert normalize("o", IMU, Imu((0, 0, 0), (0, 0, 9.8)))[0] == IMU


def test_images_are_checked_against_their_format():
    gray = np.zeros((4, 6), np.uint8)
    assert normalize("o", IMAGE, gray) == (IMAGE, gray, "gray8")
    assert normalize("o", IMAGE, np.zeros((4, 6), np.uint16))[2] == "gray16"
    assert normalize("o", IMAGE, np.zeros((4, 6, 3), np.uint8))[2] == "rgb8"
    assert normalize("o", IMAGE, np.zeros((4, 6, 3), np.uint8), "bgr8")[2] == "bgr8"
    with pytest.raises(WrongType, match="a rgb8 image has 3 channels, the array has 1"):
        normalize("o", IMAGE, gray, "rgb8")
    with pytest.raises(WrongType, match="output 'o' carries image: a gray8 image is an array of uint8, not float32"):
        normalize("o", IMAGE, np.zeros((4, 6), np.float32), "gray8")
    with pytest.raises(WrongType, match="output 'o' carries image: an image has 1, 3 or 4 channels, not 2"):
        normalize("o", IMAGE, np.zeros((4, 6, 2), np.uint8))
    with pytest.raises(WrongType, match="is empty"):
        normalize("o", IMAGE, np.zeros((0, 6), np.uint8))
    with pytest.raises(WrongType, match="pixel format 'yuv' is not one of"):
        normalize("o", IMAGE, gray, "yuv")


def test_point_cloud_intensity_must_match_its_points():
    points = np.zeros((5, 3), np.float64)
    data_type, value, intensity = normalize("o", POINT_CLOUD, points, intensity=[1, 2, 3, 4, 5])
    assert value.dtype == np.float32 and intensity.dtype == np.float32 and intensity.shape == (5,)
    with pytest.raises(WrongType, match="output 'o': 5 points but intensity of shape"):
        normalize("o", POINT_CLOUD, points, intensity=[1, 2])


@pytest.mark.parametrize("value, data_type", [
    (True, BOOL), (3, I64), (3.5, F64), ("x", TEXT), (b"x", "bytes"),
    (np.True_, BOOL), (np.int32(3), I64), (np.uint8(3), I64), (np.float32(1.5), F64),
    (np.zeros(3), VECTOR), (np.zeros((2, 2)), "matrix"), (np.zeros((2, 2), np.uint8), IMAGE),
    (np.zeros((7, 3), np.float32), POINT_CLOUD), (Imu((0, 0, 0), (0, 0, 0)), IMU),
    (Custom("mypack.boxes", b""), "mypack.boxes"),
])
def test_infer_type(value, data_type):
    assert infer_type(value) == data_type


def test_infer_type_refuses_what_it_cannot_tell():
    with pytest.raises(WrongType, match="cannot tell which data type list"):
        infer_type([1, 2])

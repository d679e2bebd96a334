"""What the runtime learns of a pack's files: one class per component name."""

import textwrap

from kairos_sdk.describe import _one_class_per_name, describe_file

CLASS = textwrap.dedent(
    """
    from kairos_sdk import Component, Descriptor, F64

    class {name}(Component):
        descriptor = Descriptor("scale").input("in", F64)

        def core(self, ctx):
            ctx.read("in")
    """
)


def test_a_name_declared_by_two_classes_names_both_and_offers_neither(tmp_path):
    found = []
    for file, name in (("first.py", "Scale"), ("second.py", "Scaler")):
        path = tmp_path / file
        path.write_text(CLASS.format(name=name))
        components, errors = describe_file("pybad", str(path))
        assert errors == []
        found += components
    components, errors = _one_class_per_name(found, [])
    assert components == []
    assert len(errors) == 2
    message = errors[0]["message"]
    assert "'pybad.scale'" in message
    assert "class Scale in first.py:4" in message and "class Scaler in second.py:4" in message
    assert {e["file"] for e in errors} == {str(tmp_path / "first.py"), str(tmp_path / "second.py")}

"""What a Python pack offers: `python -m kairos_sdk.describe PACK FILE...` prints it as JSON.

The runtime runs this when it loads a pack: every file is imported as the worker will import it, and each
`Component` subclass defined there with a `Descriptor` becomes a component type. A file that does not
import (a syntax error, a missing module) is reported with its line, and the other files still load.
"""

import importlib.util
import inspect
import json
import os
import sys
import traceback

from .component import Component
from .descriptor import Descriptor


def _line_in(error, path):
    if isinstance(error, SyntaxError) and error.filename == path:
        return error.lineno
    frames = [f for f in traceback.extract_tb(error.__traceback__) if f.filename == path]
    return frames[-1].lineno if frames else None


def describe_file(pack, path):
    """(components, errors) of one file."""
    name = f"kairos_pack_{pack}_{os.path.splitext(os.path.basename(path))[0]}"
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except BaseException as error:  # noqa: BLE001 - any import failure is reported with its line
        message = "".join(traceback.format_exception_only(type(error), error)).strip().splitlines()[-1]
        return [], [{"file": path, "line": _line_in(error, path), "message": message, "left_out": "this file"}]
    components, errors = [], []
    for _, cls in sorted(vars(module).items()):
        if not (inspect.isclass(cls) and issubclass(cls, Component) and cls is not Component):
            continue
        if cls.__module__ != name:
            continue  # imported from elsewhere: described where it is defined
        try:
            line = inspect.getsourcelines(cls)[1]
        except (OSError, TypeError):
            line = None
        if not isinstance(cls.descriptor, Descriptor):
            errors.append({"file": path, "line": line,
                           "message": f"class {cls.__name__} has no descriptor: give it "
                                      "`descriptor = Descriptor(\"name\", ...)`",
                           "left_out": f"class {cls.__name__}"})
            continue
        info = cls.descriptor.to_json(pack)
        info["python"] = {"file": path, "class": cls.__name__, "line": line}
        components.append(info)
    return components, errors


def _one_class_per_name(components, errors):
    """Components whose type name no other class declares, and an error naming every class and file of a
    name declared twice (neither is offered: which one a diagram would get must not depend on file order)."""
    by_name = {}
    for info in components:
        by_name.setdefault(info["type_name"], []).append(info)
    kept = []
    for name, infos in by_name.items():
        if len(infos) == 1:
            kept += infos
            continue
        places = "; ".join(
            f"class {i['python']['class']} in {os.path.basename(i['python']['file'])}:{i['python']['line']}"
            for i in infos
        )
        for info in infos:
            errors.append({"file": info["python"]["file"], "line": info["python"]["line"],
                           "message": f"the component name '{name}' is declared by more than one class ({places}): "
                                      "give each its own name in Descriptor(...)",
                           "left_out": f"'{name}'"})
    return kept, errors


def main(argv):
    if len(argv) < 2:
        sys.stderr.write("usage: python -m kairos_sdk.describe PACK FILE...\n")
        return 2
    pack, files = argv[0], argv[1:]
    # What the pack's modules print while they are imported goes to standard error, not into the answer.
    answer = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    folder = os.path.dirname(os.path.abspath(files[0]))
    sys.path.insert(0, folder)
    components, errors = [], []
    for path in files:
        found, failed = describe_file(pack, os.path.abspath(path))
        components += found
        errors += failed
    components, errors = _one_class_per_name(components, errors)
    json.dump({"python": sys.executable, "version": list(sys.version_info[:3]),
               "components": components, "errors": errors}, answer)
    answer.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

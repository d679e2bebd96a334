#!/usr/bin/env python3
"""Benchmark 19, against a peer: one hop through a Python pass-through, Kairos vs a dora-rs 1.1 Python node.

Both chains are source -> Python pass-through -> sink, latency from the source's stamp to the sink's
read, on this machine in one run, interleaved, three repetitions each, for two payloads:
- an integer at 1 kHz. Kairos: core.counter -> py_vision.pass_through (a worker process,
  `ctx.forward(ctx.read("in"))`) -> core.latency_probe -> core.csv_writer, NeverSkipping links
  (`kairos run`). dora-rs 1.1: the Rust source and sink of benchmark 18 around a Python node on
  `dora-rs` 1.1 that sends each input on (`node.send_output("out", event["value"], event["metadata"])`);
- a 1920x1080 RGB image at 30 Hz. Kairos: sensors.camera instead of the counter (its stamp is taken
  before it renders the frame, so Kairos's figure includes the rendering, about 0.7 ms). dora: a Python
  source sending one prepared numpy frame (as a pyarrow array, the stamp in the metadata) at each 33 ms
  tick, the same pass-through node, a Python sink.

Run from the repository root after `tests/run --setup-only` (the Kairos worker's numpy comes from
target/test-python): `python3 benches/peers/dora_python/run.py`.
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "dora_chain"))
import run as chain  # noqa: E402  (benchmark 18's helpers: building dora and kairos, summaries)

ROOT = chain.ROOT
SECONDS = 7

PASS_NODE = '''from dora import Node

node = Node()
for event in node:
    if event["type"] == "INPUT":
        node.send_output("out", event["value"], event["metadata"])
'''


IMAGE_SOURCE = '''import time

import numpy as np
import pyarrow as pa
from dora import Node

frame = pa.array(np.full(1920 * 1080 * 3, 7, np.uint8))
node = Node()
for event in node:
    if event["type"] == "INPUT":
        node.send_output("out", frame, {"stamp": time.time_ns()})
'''

IMAGE_SINK = '''import json
import os
import time

from dora import Node

latencies = []
node = Node()
for event in node:
    if event["type"] == "INPUT":
        latencies.append((time.time_ns() - event["metadata"]["stamp"]) / 1e3)
kept = sorted(latencies[30:])
n = max(len(kept), 1)
with open(os.environ["OUT"], "w") as out:
    json.dump({"samples": len(kept), "p50_us": kept[n // 2], "p99_us": kept[n * 99 // 100],
               "mean_us": sum(kept) / n}, out)
'''

IMAGE_WARM_UP = 30


def kairos_diagram(csv_path, image):
    source = ('Component(id: "source", type: "sensors.camera", properties: {"rate": 30.0, "width": 1920, '
              '"height": 1080})') if image else 'Component(id: "source", type: "core.counter", properties: {"rate": 1000.0})'
    output = "image" if image else "out"
    return ('Diagram(format: 1, components: [' + source + ', '
            'Component(id: "pass", type: "py_vision.pass_through"), '
            'Component(id: "probe", type: "core.latency_probe"), '
            f'Component(id: "csv", type: "core.csv_writer", properties: {{"path": "{csv_path}"}})], '
            'connections: ['
            'Connection(from: "source.' + output + '", to: "pass.in", policy: NeverSkipping), '
            'Connection(from: "pass.out", to: "probe.in", policy: NeverSkipping), '
            'Connection(from: "probe.latency_ms", to: "csv.in1", policy: NeverSkipping, buffer_size: 1024)])')


def run_kairos(folder, image):
    csv_path = folder / "python.csv"
    diagram = folder / "python.ron"
    diagram.write_text(kairos_diagram(csv_path, image))
    csv_path.unlink(missing_ok=True)
    env = dict(os.environ, PATH=f"{ROOT / 'target' / 'test-python' / 'bin'}:{os.environ['PATH']}")
    chain.run([str(ROOT / "target" / "release" / "kairos"), "run", str(diagram), "--pack-path",
               str(ROOT / "examples" / "python" / "packs"), "--for", f"{SECONDS}s"],
              stderr=subprocess.DEVNULL, env=env)
    latencies = chain.kairos_latencies(csv_path)
    if image:
        kept = sorted(latencies[IMAGE_WARM_UP:])
        n = len(kept)
        return {"samples": n, "p50_us": kept[n // 2], "p99_us": kept[n * 99 // 100], "mean_us": sum(kept) / n}
    return chain.summary(latencies)


def run_dora(folder, dora, node, image):
    (folder / "pass.py").write_text(PASS_NODE)
    (folder / "image_source.py").write_text(IMAGE_SOURCE)
    (folder / "image_sink.py").write_text(IMAGE_SINK)
    if image:
        source = ["  - id: source", "    path: image_source.py", "    inputs:", "      tick: dora/timer/millis/33"]
        sink = ["  - id: sink", "    path: image_sink.py", "    inputs:", "      in: pass/out"]
    else:
        source = ["  - id: source", f"    path: {node}", "    args: source", "    inputs:",
                  "      tick: dora/timer/millis/1"]
        sink = ["  - id: sink", f"    path: {node}", "    args: sink", "    inputs:", "      in: pass/out"]
    dataflow = folder / "python.yml"
    dataflow.write_text("\n".join([
        "nodes:", *source, "    outputs:", "      - out",
        "  - id: pass", "    path: pass.py", "    inputs:", "      in: source/out", "    outputs:", "      - out",
        *sink,
    ]) + "\n")
    out = folder / "dora.json"
    out.unlink(missing_ok=True)
    # The Python node runs with the interpreter of dora's own environment (dora-rs and pyarrow).
    env = dict(os.environ, OUT=str(out), SAMPLES=str(SECONDS * 1000 - 1000),
               PATH=f"{Path(dora).parent}:{os.environ['PATH']}")
    if image:
        # The image source never ends on its own: stop the dataflow after the run's seconds.
        process = subprocess.Popen([str(dora), "run", str(dataflow), "--stop-after", f"{SECONDS}s"], cwd=folder,
                                   env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        process.wait(timeout=SECONDS + 60)
    else:
        chain.run([str(dora), "run", str(dataflow)], cwd=folder, env=env, stdout=subprocess.DEVNULL,
                  stderr=subprocess.DEVNULL)
    return json.loads(out.read_text())


def main():
    dora, node = chain.prepare()
    print(f"machine: {os.cpu_count()} cores; source -> Python pass-through -> sink, {SECONDS} s per run, "
          f"first {chain.WARM_UP} integers or {IMAGE_WARM_UP} images left out")
    print("| payload | variant | p50 | p99 | mean | samples |")
    print("| --- | --- | --- | --- | --- | --- |")
    for image in (False, True):
        payload = "1080p RGB image, 30 Hz" if image else "integer, 1 kHz"
        results = {"Kairos, Python component": [], "dora-rs 1.1, Python node": []}
        with tempfile.TemporaryDirectory() as temporary:
            folder = Path(temporary)
            for _ in range(3):
                results["Kairos, Python component"].append(run_kairos(folder, image))
                results["dora-rs 1.1, Python node"].append(run_dora(folder, dora, node, image))
        for name, runs in results.items():
            print(f"| {payload} | {name} | {chain.spread([r['p50_us'] for r in runs])} | "
                  f"{chain.spread([r['p99_us'] for r in runs])} | {chain.spread([r['mean_us'] for r in runs])} | "
                  f"{statistics.median(r['samples'] for r in runs):.0f} |")
        ratios = [k["p50_us"] / d["p50_us"] for k, d in zip(*results.values())]
        print(f"| {payload} | p50 Kairos / dora-rs | {statistics.median(ratios):.3f}× "
              f"[{min(ratios):.3f}–{max(ratios):.3f}] | | | |")


if __name__ == "__main__":
    main()

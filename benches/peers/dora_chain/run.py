#!/usr/bin/env python3
"""Benchmark 18: a 17-stage chain at 1 kHz, end-to-end latency (source's stamp to the last stage's read).

Three variants, interleaved, three repetitions each, on this machine in one run:
- Kairos, one runtime: core.counter at 1 kHz -> 15 x core.gain -> core.latency_probe (`kairos run`);
- Kairos split over two hosts: stages 9 to 17 on a `kairos serve` on loopback, the link over Zenoh
  (`kairos deploy`);
- dora-rs 1.1 (`dora-rs-cli` from PyPI, a Rust node on `dora-node-api` from crates.io): a timer-driven
  source, 15 relays and a sink, `dora run`.

Every stage reads NeverSkipping in Kairos (dora's inputs queue as well). Run from the repository root:
`python3 benches/peers/dora_chain/run.py` (needs PyPI and crates.io once, then works offline).
"""

import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
HERE = Path(__file__).resolve().parent
TARGET = ROOT / "target" / "peers"
STAGES = 17
SECONDS = 7
WARM_UP = 1000


def run(command, **kwargs):
    return subprocess.run(command, check=True, **kwargs)


def prepare():
    venv = TARGET / "dora-venv"
    if not (venv / "bin" / "dora").exists():
        run([sys.executable, "-m", "venv", str(venv)])
        run([str(venv / "bin" / "pip"), "install", "-q", "dora-rs-cli==1.1.0"])
    env = dict(os.environ, CARGO_TARGET_DIR=str(TARGET / "dora-chain"))
    run(["cargo", "build", "-q", "--release", "--manifest-path", str(HERE / "Cargo.toml")], env=env)
    run(["cargo", "build", "-q", "--release", "-p", "kairos"], cwd=ROOT)
    return venv / "bin" / "dora", TARGET / "dora-chain" / "release" / "kairos-peer-dora-chain"


def dora_dataflow(node):
    lines = ["nodes:", "  - id: source", f"    path: {node}", "    args: source", "    inputs:",
             "      tick: dora/timer/millis/1", "    outputs:", "      - out"]
    previous = "source"
    for stage in range(1, STAGES - 1):
        lines += [f"  - id: relay{stage}", f"    path: {node}", "    args: relay", "    inputs:",
                  f"      in: {previous}/out", "    outputs:", "      - out"]
        previous = f"relay{stage}"
    lines += ["  - id: sink", f"    path: {node}", "    args: sink", "    inputs:", f"      in: {previous}/out"]
    return "\n".join(lines) + "\n"


def kairos_chain(csv_path, split):
    """The chain; with `split`, stages 9 to 17 and the CSV on host b."""
    on_b = lambda index: ', host: "b"' if split and index >= 9 else ""
    components = [f'Component(id: "s0", type: "core.counter", properties: {{"rate": 1000.0}})']
    connections = []
    for stage in range(1, STAGES - 1):
        components.append(f'Component(id: "s{stage}", type: "core.gain", properties: {{"gain": 1.0}}{on_b(stage)})')
        connections.append(f'Connection(from: "s{stage - 1}.out", to: "s{stage}.in", policy: NeverSkipping)')
    last = STAGES - 1
    components.append(f'Component(id: "s{last}", type: "core.latency_probe"{on_b(last)})')
    connections.append(f'Connection(from: "s{last - 1}.out", to: "s{last}.in", policy: NeverSkipping)')
    components.append(f'Component(id: "csv", type: "core.csv_writer", properties: {{"path": "{csv_path}"}}{on_b(last)})')
    connections.append(f'Connection(from: "s{last}.latency_ms", to: "csv.in1", policy: NeverSkipping, buffer_size: 1024)')
    hosts = ('hosts: {"b": Host(endpoint: "ws://127.0.0.1:7611", token_file: "b.token", '
             'zenoh: "tcp/127.0.0.1:17447")}, ') if split else ""
    return f"Diagram(format: 1, {hosts}components: [{', '.join(components)}], connections: [{', '.join(connections)}])"


def summary(latencies_us):
    kept = sorted(latencies_us[WARM_UP:])
    n = len(kept)
    return {"samples": n, "p50_us": kept[n // 2], "p99_us": kept[n * 99 // 100], "mean_us": sum(kept) / n}


def kairos_latencies(csv_path):
    with open(csv_path) as f:
        rows = list(csv.reader(f))[1:]
    return [float(row[-1]) * 1e3 for row in rows]


def run_kairos(folder, split):
    kairos = ROOT / "target" / "release" / "kairos"
    csv_path = folder / ("split.csv" if split else "one.csv")
    diagram = folder / ("split.ron" if split else "one.ron")
    diagram.write_text(kairos_chain(csv_path, split))
    csv_path.unlink(missing_ok=True)
    if not split:
        run([str(kairos), "run", str(diagram), "--for", f"{SECONDS}s"], stderr=subprocess.DEVNULL)
        return summary(kairos_latencies(csv_path))
    server = subprocess.Popen([str(kairos), "serve", "--listen", "127.0.0.1:7611", "--token-file",
                               str(folder / "b.token")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for _ in range(100):
            if (folder / "b.token").exists():
                break
            time.sleep(0.05)
        time.sleep(0.3)
        run([str(kairos), "deploy", str(diagram), "--for", f"{SECONDS}s"], stderr=subprocess.DEVNULL)
    finally:
        server.terminate()
        server.wait()
    (folder / "b.token").unlink(missing_ok=True)
    return summary(kairos_latencies(csv_path))


def run_dora(folder, dora, node):
    dataflow = folder / "chain.yml"
    dataflow.write_text(dora_dataflow(node))
    out = folder / "dora.json"
    out.unlink(missing_ok=True)
    env = dict(os.environ, OUT=str(out), SAMPLES=str(SECONDS * 1000 - 1000))
    run([str(dora), "run", str(dataflow)], cwd=folder, env=env, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL)
    return json.loads(out.read_text())


def spread(values):
    return f"{statistics.median(values):.0f} µs [{min(values):.0f}–{max(values):.0f}]"


def main():
    dora, node = prepare()
    results = {"kairos, one runtime": [], "kairos, two hosts": [], "dora-rs 1.1": []}
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        for _ in range(3):
            results["kairos, one runtime"].append(run_kairos(folder, split=False))
            results["kairos, two hosts"].append(run_kairos(folder, split=True))
            results["dora-rs 1.1"].append(run_dora(folder, dora, node))
    print(f"machine: {os.cpu_count()} cores; {STAGES} stages at 1 kHz, {SECONDS} s per run, first {WARM_UP} samples left out")
    print("| variant | p50 | p99 | mean | samples |")
    print("| --- | --- | --- | --- | --- |")
    for name, runs in results.items():
        print(f"| {name} | {spread([r['p50_us'] for r in runs])} | {spread([r['p99_us'] for r in runs])} | "
              f"{spread([r['mean_us'] for r in runs])} | {statistics.median(r['samples'] for r in runs):.0f} |")
    dora_p50 = [r["p50_us"] for r in results["dora-rs 1.1"]]
    for name in ("kairos, one runtime", "kairos, two hosts"):
        ratios = [r["p50_us"] / d for r, d in zip(results[name], dora_p50)]
        print(f"| p50 {name} / dora-rs | {statistics.median(ratios):.3f}× [{min(ratios):.3f}–{max(ratios):.3f}] |")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Drive a Kairos runtime (`kairos serve`) over the control protocol.

Connects, deploys an example diagram, starts it, prints telemetry for a few seconds, changes a property,
reads the change back, and stops. Exits 0 only if every step succeeded.

    kairos serve --token-file token.txt            # prints: listening on ws://127.0.0.1:7400
    python3 examples/clients/python/demo.py --url ws://127.0.0.1:7400 --token-file token.txt

Needs the `websockets` package (pip install websockets). The protocol is documented in docs/protocol.md.
"""

import argparse
import asyncio
import itertools
import json
import pathlib
import sys

import websockets

PROTOCOL = 1
REPOSITORY = pathlib.Path(__file__).resolve().parents[3]


class Client:
    """One session: requests with increasing ids, replies matched to them, events kept aside."""

    def __init__(self, socket):
        self.socket = socket
        self.ids = itertools.count(1)
        self.events = []

    async def request(self, kind, **fields):
        request_id = next(self.ids)
        await self.socket.send(json.dumps({"id": request_id, "type": kind, **fields}))
        while True:
            message = await self.socket.recv()
            if isinstance(message, bytes):
                continue  # a sample frame; this demo does not subscribe to any
            decoded = json.loads(message)
            if decoded["type"] == "reply" and decoded.get("id") == request_id:
                if not decoded["ok"]:
                    error = decoded["error"]
                    raise RuntimeError(f"{kind} failed ({error['code']}): {error['message']}")
                return decoded["result"]
            self.events.append(decoded)

    async def next_event(self, kind, timeout):
        for index, event in enumerate(self.events):
            if event["type"] == kind:
                return self.events.pop(index)
        while True:
            message = await asyncio.wait_for(self.socket.recv(), timeout)
            if isinstance(message, bytes):
                continue
            decoded = json.loads(message)
            if decoded["type"] == kind:
                return decoded
            self.events.append(decoded)


def step(text):
    print(f"-- {text}", flush=True)


async def demo(url, token, diagram_path, seconds):
    async with websockets.connect(url, max_size=8 << 20) as socket:
        client = Client(socket)
        step("hello")
        welcome = await client.request("hello", protocol=PROTOCOL, client="demo.py", token=token)
        print(f"   connected to {welcome['server']} as {welcome['role']}")

        step("library")
        library = await client.request("library")
        print(f"   {len(library['components'])} component types in {len(library['packs'])} packs")

        step(f"deploy {diagram_path.name}")
        deployed = await client.request("deploy", diagram=diagram_path.read_text())
        print(f"   {deployed['components']} components, {len(deployed['diagnostics'])} warnings")

        step("start")
        await client.request("start")
        await client.request("subscribe_telemetry", interval_ms=500)
        step(f"telemetry for {seconds} s")
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while loop.time() < end:
            telemetry = await client.next_event("telemetry", timeout=5)
            for link in telemetry["links"]:
                print(
                    f"   {link['link']:<28} {link['rate_hz']:7.1f}/s  written {link['written']:6}"
                    f"  dropped {link['overwritten']}"
                )
        step("set gain1.gain = 4.0")
        await client.request("set_property", component="gain1", property="gain", value=4.0)
        diagram = (await client.request("get_diagram"))["diagram"]
        if '"gain": 4.0' not in diagram:
            raise RuntimeError("the deployed diagram does not show the new gain")

        step("a refused value keeps the old one")
        try:
            await client.request("set_property", component="gain1", property="gain", value="loud")
        except RuntimeError as refused:
            print(f"   refused as expected: {refused}")
        else:
            raise RuntimeError("a text gain was accepted")

        step("stop")
        await client.request("stop")
        status = await client.request("status")
        print(f"   state: {status['state']}")
        states = {c["id"]: c["state"] for c in status["telemetry"]["components"]}
        if any(state not in ("stopped", "finished") for state in states.values()):
            raise RuntimeError(f"components still running after stop: {states}")
    step("done")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", default="ws://127.0.0.1:7400")
    parser.add_argument("--token-file", help="the file holding the runtime's token")
    parser.add_argument("--diagram", type=pathlib.Path, default=REPOSITORY / "examples" / "hello.ron")
    parser.add_argument("--seconds", type=float, default=2.0)
    arguments = parser.parse_args()
    token = None
    if arguments.token_file:
        token = pathlib.Path(arguments.token_file).read_text().splitlines()[0].strip()
    try:
        asyncio.run(demo(arguments.url, token, arguments.diagram, arguments.seconds))
    except Exception as error:  # every failure ends the demo with a message and exit code 1
        print(f"FAILED: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Gymnasium's mountain car as a simulator in its own process, bridged to a Kairos diagram over UDP.

The bridge speaks Kairos' binary sample frame (`KSB1`, docs/net.md) both ways, one frame a datagram:

- each step's observation goes to the diagram's `net.udp_receiver` (encoding kairos) as a vector stamped
  with both times: its timestamp is the SIMULATION's time (a fixed start plus steps × step), its time of
  issue the wall clock's when it was sent;
- the diagram's answer comes back from its `net.udp_sender` (encoding kairos) as an f64: the action.

It runs in lock-step: the simulator waits for the diagram's action before its next step, so the loop runs
as fast as both sides compute and the diagram sees simulated time in its timestamps, whatever the wall clock
does. Run the diagram first, then this script:

    kairos run examples/sim/gym_over_udp.ron --for 30s &
    python3 examples/sim/bridge/udp_mountain_car.py --episodes 3
"""

import argparse
import socket
import struct
import sys
import time

HEAD = struct.Struct("<4sBH")
TIMES = struct.Struct("<qqQ")
KIND_F64, KIND_VECTOR = 0, 5
# 2026-01-01T00:00:00Z: the simulation's time starts here, so runs stamp alike.
START_NS = 1_767_225_600_000_000_000


def frame(output, kind, timestamp_ns, issued_ns, sequence, payload):
    name = output.encode()
    return HEAD.pack(b"KSB1", kind, len(name)) + name + TIMES.pack(timestamp_ns, issued_ns, sequence) + payload


def action_of(datagram):
    """The f64 a KSB1 frame carries, or None for anything else."""
    if len(datagram) < HEAD.size:
        return None
    magic, kind, length = HEAD.unpack_from(datagram)
    at = HEAD.size + length + TIMES.size
    if magic != b"KSB1" or kind != KIND_F64 or len(datagram) < at + 8:
        return None
    return struct.unpack_from("<d", datagram, at)[0]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--to", default="127.0.0.1:5600", help="the diagram's net.udp_receiver")
    parser.add_argument("--listen", default="127.0.0.1:5601", help="where the diagram's net.udp_sender sends")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--step", type=float, default=1 / 30, help="simulated seconds per step")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import gymnasium  # noqa: PLC0415 - only the simulator's process needs it

    host, port = args.to.rsplit(":", 1)
    listen_host, listen_port = args.listen.rsplit(":", 1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((listen_host, int(listen_port)))
    sock.settimeout(2.0)
    env = gymnasium.make("MountainCarContinuous-v0")
    observation, _ = env.reset(seed=args.seed)
    step_ns = int(round(args.step * 1e9))
    steps, episode, episode_steps, episode_return = 0, 1, 0, 0.0
    while episode <= args.episodes:
        payload = struct.pack(f"<{len(observation)}d", *(float(v) for v in observation))
        sent = frame("mountain_car.observation", KIND_VECTOR, START_NS + steps * step_ns, time.time_ns(),
                     steps, payload)
        sock.sendto(sent, (host, int(port)))
        try:
            action = None
            while action is None:
                action = action_of(sock.recv(65536))
        except socket.timeout:
            print(f"no action from the diagram within 2 s at step {steps}: is it running?", file=sys.stderr)
            return 1
        observation, reward, terminated, truncated, _ = env.step([max(-1.0, min(1.0, action))])
        steps += 1
        episode_steps += 1
        episode_return += float(reward)
        if terminated or truncated:
            why = "terminated (goal reached)" if terminated else "truncated (time limit)"
            print(f"episode {episode}: {episode_steps} steps, return {episode_return:.1f}, {why}", flush=True)
            observation, _ = env.reset()
            episode += 1
            episode_steps, episode_return = 0, 0.0
    return 0


if __name__ == "__main__":
    sys.exit(main())

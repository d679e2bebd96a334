#!/usr/bin/env bash
# Benchmark 21, the soak across machines (issue: "a rig holds in the field"): two hosts in two network
# namespaces joined by a veth pair. Host a runs a 640×480 camera at 30 Hz and an IMU at 200 Hz; host b
# records both (NeverSkipping links, so a blip must lose nothing). The Zenoh port is blocked between the
# hosts for SOAK_BLIP_S seconds every SOAK_BLIP_EVERY_S. Measured: each `kairos serve`'s resident memory
# every 10 s, the links' final counts as `kairos deploy` says them, and the recording as `kairos inspect`
# reads it. Goal: memory at the end ≤ 1.1× memory at minute 5, nothing lost, the recording whole.
#
#   sudo benches/soak/run.sh                      # 60 minutes, a 3 s blip every 5 minutes
#   SOAK_MINUTES=3 SOAK_BLIP_EVERY_S=45 benches/soak/run.sh    # a short trial
#
# Needs root (network namespaces, tc) and, for an hour, about 12 GB free under SOAK_DIR (the zstd
# recording). KAIROS names the binary (default: target/release/kairos, built if missing).
set -euo pipefail
cd "$(dirname "$0")/../.."

minutes=${SOAK_MINUTES:-60}
blip_every=${SOAK_BLIP_EVERY_S:-300}
blip=${SOAK_BLIP_S:-3}
kairos=${KAIROS:-target/release/kairos}
if [ ! -x "$kairos" ]; then
    cargo build --release -p kairos
fi
kairos=$(realpath "$kairos")
work=$(mktemp -d "${SOAK_DIR:-/tmp}/kairos-soak.XXXXXX")
id=$$
ns_a=ksoak_a$id ns_b=ksoak_b$id dev_a=ksa$id dev_b=ksb$id
addr_a=10.201.$((id % 250)).1 addr_b=10.201.$((id % 250)).2
pids=()

cleanup() {
    for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
    wait 2>/dev/null || true
    ip netns del "$ns_a" 2>/dev/null || true
    ip netns del "$ns_b" 2>/dev/null || true
}
trap cleanup EXIT

ip netns add "$ns_a"
ip netns add "$ns_b"
ip link add "$dev_a" netns "$ns_a" type veth peer name "$dev_b" netns "$ns_b"
ip -n "$ns_a" addr add "$addr_a/24" dev "$dev_a"
ip -n "$ns_b" addr add "$addr_b/24" dev "$dev_b"
for end in "$ns_a $dev_a" "$ns_b $dev_b"; do
    set -- $end
    ip -n "$1" link set "$2" up
    ip -n "$1" link set lo up
done

mkdir -p "$work/a" "$work/b" "$work/here"
serve() { # namespace folder address
    (cd "$2" && exec ip netns exec "$1" "$kairos" serve --listen "$3:7400" --token-file token.txt \
        >serve.out 2>serve.log) &
    pids+=($!)
}
serve "$ns_a" "$work/a" "$addr_a"
serve "$ns_b" "$work/b" "$addr_b"
for host in a b; do
    for _ in $(seq 100); do [ -s "$work/$host/token.txt" ] && break; sleep 0.1; done
    cp "$work/$host/token.txt" "$work/here/$host.token"
done
# `ip netns exec` execs kairos: the process in the folder is the server itself.
serve_pid() { pgrep -f "serve --listen $1:7400" | head -1; }
pid_a=$(serve_pid "$addr_a") pid_b=$(serve_pid "$addr_b")

cat >"$work/here/soak.ron" <<RON
Diagram(format: 1,
    hosts: {
        "a": Host(endpoint: "ws://$addr_a:7400", token_file: "a.token", zenoh: "tcp/$addr_a:7447"),
        "b": Host(endpoint: "ws://$addr_b:7400", token_file: "b.token", zenoh: "tcp/$addr_b:7447"),
    },
    packs: [Pack(name: "sensors", version: "^0.1"), Pack(name: "recording", version: "^0.1")],
    components: [
        Component(id: "camera", type: "sensors.camera", host: "a", properties: {"width": 640, "height": 480, "rate": 30.0}),
        Component(id: "imu", type: "sensors.imu", host: "a", properties: {"rate": 200.0}),
        Component(id: "recorder", type: "recording.recorder", host: "b", properties: {"path": "soak.mcap"}),
    ],
    connections: [
        Connection(from: "camera.image", to: "recorder.in1", policy: NeverSkipping, buffer_size: 16),
        Connection(from: "imu.imu", to: "recorder.in2", policy: NeverSkipping, buffer_size: 256),
    ],
)
RON

(cd "$work/here" && exec ip netns exec "$ns_a" "$kairos" deploy soak.ron --for "${minutes}m" \
    --allow-clear-text-tokens >deploy.log 2>&1) &
deploying=$!
pids+=("$deploying")

block_zenoh() { # add|del
    local action=$1
    for end in "$ns_a $dev_a" "$ns_b $dev_b"; do
        set -- $end
        if [ "$action" = add ]; then
            tc -n "$1" qdisc add dev "$2" root handle 1: htb default 20
            tc -n "$1" class add dev "$2" parent 1: classid 1:10 htb rate 1mbit
            tc -n "$1" class add dev "$2" parent 1: classid 1:20 htb rate 10gbit
            tc -n "$1" qdisc add dev "$2" parent 1:10 handle 10: pfifo limit 0
            tc -n "$1" filter add dev "$2" parent 1: protocol ip prio 1 u32 match ip dport 7447 0xffff flowid 1:10
            tc -n "$1" filter add dev "$2" parent 1: protocol ip prio 2 u32 match ip sport 7447 0xffff flowid 1:10
        else
            tc -n "$1" qdisc del dev "$2" root
        fi
    done
}
rss_kib() { awk '/VmRSS/ {print $2}' "/proc/$1/status" 2>/dev/null || echo 0; }

echo "seconds,serve_a_kib,serve_b_kib" >"$work/memory.csv"
start=$(date +%s)
next_blip=$((start + blip_every))
blips=0
while kill -0 "$deploying" 2>/dev/null; do
    now=$(date +%s)
    echo "$((now - start)),$(rss_kib "$pid_a"),$(rss_kib "$pid_b")" >>"$work/memory.csv"
    if [ "$now" -ge "$next_blip" ] && [ $((now - start)) -lt $((minutes * 60 - blip - 10)) ]; then
        block_zenoh add
        sleep "$blip"
        block_zenoh del
        blips=$((blips + 1))
        next_blip=$((next_blip + blip_every))
    fi
    sleep 10
done
wait "$deploying" && deploy_status=0 || deploy_status=$?

at_minute() { # seconds column -> row at or after
    awk -F, -v s="$1" -v c="$2" 'NR > 1 && $1 >= s { print $c; exit }' "$work/memory.csv"
}
last() { tail -1 "$work/memory.csv" | cut -d, -f"$1"; }
five=$((minutes >= 10 ? 300 : 60))
echo "=== 21. soak: ${minutes} min, ${blips} blips of ${blip} s, kairos deploy exited ${deploy_status} ==="
for column in 2 3; do
    name=$([ "$column" = 2 ] && echo "serve a (camera, IMU)" || echo "serve b (recorder)")
    early=$(at_minute "$five" "$column") late=$(last "$column")
    ratio=$(awk -v a="$early" -v b="$late" 'BEGIN { if (a > 0) printf "%.2f", b / a; else print "n/a" }')
    echo "$name: RSS ${early} KiB at ${five} s, ${late} KiB at the end: ${ratio}× (goal ≤ 1.10×)"
done
echo "links, as kairos deploy said them at the end:"
grep -E "link .* sent [0-9]+, received" "$work/here/deploy.log" | sed 's/^.*link /  link /' || echo "  (none said)"
echo "faults said by kairos deploy: $(grep -c ' is cut' "$work/here/deploy.log" || true) cuts, \
$(grep -c 'delivers nothing' "$work/here/deploy.log" || true) links delivering nothing while matched"
echo "the recording:"
"$kairos" inspect "$work/b/soak.mcap" | head -20 && inspect_status=0 || inspect_status=$?
echo "kairos inspect exited ${inspect_status}; everything is in $work"

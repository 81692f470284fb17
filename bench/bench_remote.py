"""What the remote level costs: decision-cycle overhead and wall time of a whole sitl mission.

1. Decision cycle. A stack (Mosquitto, MAVLink emulator, one bridge per boat) runs 1, 3 and 10
   boats. Each cycle, RemoteFleet sends every boat a goto to the node it is already on and waits
   for all the ``reached`` acks: that is the fixed price of one hop at the remote levels, with
   no sailing in it. Baseline, same run: a raw paho client publishes one QoS 1 message per boat
   to an echo client that republishes it, and waits for all the echoes, through a second
   Mosquitto of the same build (`start_broker` without secrets: anonymous, TCP_NODELAY like the
   stack's), since the stack's own broker admits no anonymous client.
2. Whole mission. ``missions/lake_greedy_sitl.yaml`` (3 boats, 925 m each) at speed-up 50 and
   200, wall time against the mission's own simulated duration (last ``time_s``); the sim twin
   ``missions/lake_greedy.yaml`` is timed too, for the planner's own share.

    python bench/bench_remote.py                 # both parts, markdown on stdout
    python bench/bench_remote.py --cycles 30 --skip-mission
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import os
import platform
import socket
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import paho.mqtt.client as mqtt
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guadal_cli.channel.broker import start_broker  # noqa: E402
from guadal_cli.fleet.remote import RemoteFleet, SitlConfig  # noqa: E402
from guadal_cli.graph import NavGraph  # noqa: E402
from guadal_cli.maps.format import load_map  # noqa: E402
from guadal_cli.mission import auto_positions, prepare  # noqa: E402
from guadal_cli.runner import MissionRunner  # noqa: E402
from guadal_cli.stack import Stack  # noqa: E402

LAKE = ROOT / "maps" / "urban_lake.json"


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def echo_round_trips(port: int, n: int, cycles: int) -> list[float]:
    """Publish n QoS 1 messages at once, wait for all n echoes; seconds per cycle."""
    got = threading.Condition()
    received: set[int] = set()

    def echo_on_message(client, userdata, m):
        client.publish("bench/out/" + m.topic.rsplit("/", 1)[1], m.payload, qos=1)

    def on_echo(client, userdata, m):
        with got:
            received.add(int(m.payload))
            got.notify_all()

    clients = []
    for topic, handler in (("bench/in/+", echo_on_message), ("bench/out/+", on_echo)):
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        subscribed = threading.Event()
        client.on_message = handler
        client.on_subscribe = lambda *a, e=subscribed: e.set()
        client.on_connect = lambda c, *a: c.socket().setsockopt(  # the socket option guadal's channel sets
            socket.IPPROTO_TCP, socket.TCP_NODELAY, 1
        )
        client.connect("127.0.0.1", port)
        client.loop_start()
        client.subscribe(topic, qos=1)
        subscribed.wait(10)
        clients.append(client)
    sender = clients[1]
    times = []
    for c in range(cycles + 3):
        ids = set(range(c * n, c * n + n))
        t0 = time.perf_counter()
        for i in ids:
            sender.publish(f"bench/in/{i % n}", str(i).encode(), qos=1)
        with got:
            got.wait_for(lambda ids=ids: ids <= received, 10)
        if c >= 3:  # warm-up
            times.append(time.perf_counter() - t0)
    for client in clients:
        client.disconnect()
        client.loop_stop()
    return times


def goto_cycles(fleet: RemoteFleet, cycles: int) -> tuple[list[float], list[float]]:
    """Seconds until every boat acknowledged (``accepted``) and until every boat ``reached``."""
    accepted, reached = [], []
    owner = fleet._owner
    for c in range(cycles + 3):
        t0 = time.perf_counter()
        owner.call(lambda: [fleet._goto(v, v.node, count_distance=False) for v in fleet.vehicles])
        owner.wait(lambda: all(v.goto.status != "sent" for v in fleet.vehicles), 30)
        t1 = time.perf_counter()
        owner.wait(lambda: all(not v.goto.open for v in fleet.vehicles), 30)
        if c >= 3:
            accepted.append(t1 - t0)
            reached.append(time.perf_counter() - t0)
    return accepted, reached


def decision_cycle(counts: list[int], cycles: int, speedup: float) -> list[dict]:
    graph = NavGraph(load_map(LAKE))
    rows = []
    for n in counts:
        start = auto_positions(graph, n)
        homes = [(float(graph.lat[i]), float(graph.lon[i])) for i in start]
        t0 = time.perf_counter()
        stack = Stack.launch(
            map_path=LAKE, vehicles=n, homes=homes, speedup=speedup, broker_kind="mosquitto", timeout=180
        )
        launch_s = time.perf_counter() - t0
        fleet = RemoteFleet(graph, n, 1e9, None, SitlConfig(**stack.planner_backend()))
        try:
            fleet.reset(start)
            accepted, cycle = goto_cycles(fleet, cycles)
            echo_broker = start_broker("mosquitto")  # no secrets: anonymous, loopback only
            try:
                base = echo_round_trips(echo_broker.port, n, cycles)
            finally:
                echo_broker.stop()
        finally:
            fleet.close()
            stack.down()
        rows.append(
            {
                "vehicles": n,
                "launch_s": launch_s,
                "acc_p50_ms": 1e3 * statistics.median(accepted),
                "p50_ms": 1e3 * statistics.median(cycle),
                "p95_ms": 1e3 * percentile(cycle, 0.95),
                "base_p50_ms": 1e3 * statistics.median(base),
                "base_p95_ms": 1e3 * percentile(base, 0.95),
            }
        )
    return rows


def run_mission(path: Path, speedup: float | None, out: Path) -> dict:
    data = yaml.safe_load(path.read_text())
    data["map"] = str(LAKE)
    if speedup is not None:
        data["backend"]["speedup"] = speedup
    mission = out / f"{path.stem}-{speedup}.yaml"
    mission.write_text(yaml.safe_dump(data))
    t0 = time.perf_counter()
    result = MissionRunner(prepare(mission), output=out / mission.stem).run()
    wall = time.perf_counter() - t0
    with open(out / mission.stem / "metrics.csv") as f:
        last = list(csv.DictReader(f))[-1]
    return {
        "mission": path.name,
        "speedup": speedup,
        "status": result.status,
        "steps": result.steps,
        "wall_s": wall,
        "sim_s": float(last["time_s"]),
        "distance": float(last["total_distance"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=50)
    parser.add_argument("--vehicles", default="1,3,10")
    parser.add_argument("--cycle-speedup", type=float, default=50.0)
    parser.add_argument("--skip-cycle", action="store_true")
    parser.add_argument("--skip-mission", action="store_true")
    args = parser.parse_args()
    print(
        f"{dt.date.today()} · {os.cpu_count()} cores · {platform.machine()} · Python {platform.python_version()}\n"
    )
    if not args.skip_cycle:
        rows = decision_cycle([int(x) for x in args.vehicles.split(",")], args.cycles, args.cycle_speedup)
        print(
            f"Decision cycle (goto to the current node → every `reached` ack), {args.cycles} cycles, "
            f"emulator speed-up {args.cycle_speedup:g}, Mosquitto:\n"
        )
        print(
            "| boats | all accepted p50 | all reached p50 | reached p95 | echo p50 | echo p95 | "
            "accepted / echo | reached / echo | stack start-up |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['vehicles']} | {r['acc_p50_ms']:.1f} ms | {r['p50_ms']:.1f} ms | {r['p95_ms']:.1f} ms | "
                f"{r['base_p50_ms']:.2f} ms | {r['base_p95_ms']:.2f} ms | {r['acc_p50_ms'] / r['base_p50_ms']:.1f}× | "
                f"{r['p50_ms'] / r['base_p50_ms']:.0f}× | {r['launch_s']:.1f} s |"
            )
        print()
    if not args.skip_mission:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            sim = run_mission(ROOT / "missions" / "lake_greedy.yaml", None, out)
            runs = [run_mission(ROOT / "missions" / "lake_greedy_sitl.yaml", k, out) for k in (50, 200)]
        print("Whole mission, 3 boats × 925 m (`missions/lake_greedy_sitl.yaml`; sim twin for reference):\n")
        print("| level | speed-up | steps | wall | simulated | wall / simulated | wall / sim-level wall |")
        print("|---|---|---|---|---|---|---|")
        print(
            f"| sim | – | {sim['steps']} | {sim['wall_s']:.1f} s | {sim['sim_s']:.0f} s | "
            f"{sim['wall_s'] / sim['sim_s']:.4f} | 1 |"
        )
        for r in runs:
            print(
                f"| sitl | {r['speedup']:g} | {r['steps']} | {r['wall_s']:.1f} s | {r['sim_s']:.0f} s | "
                f"{r['wall_s'] / r['sim_s']:.4f} (1/{r['speedup']:g} = {1 / r['speedup']:.4f}) | "
                f"{r['wall_s'] / sim['wall_s']:.1f} |"
            )


if __name__ == "__main__":
    main()

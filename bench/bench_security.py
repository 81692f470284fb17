"""What the secure command channel costs: decision-cycle time with signing + ACLs on vs off.

A stack (Mosquitto on a private port, the MAVLink emulator, one bridge per boat) is launched
twice per repetition, interleaved (off, on, off, on...) so a busy moment on a shared machine
hits both alike: once as guadal launches it (generated users, ACL file, every message signed
and checked with HMAC-SHA256, sessions), once as the baseline (anonymous broker, no ACL, no
signatures; ``Stack.launch(secure=False)``, which only benchmarks use). Each cycle, RemoteFleet
sends every boat a goto to the node it is on and waits for every ``reached`` ack.

    OPENBLAS_NUM_THREADS=1 python bench/bench_security.py              # markdown on stdout
    python bench/bench_security.py --repetitions 3 --cycles 20 --vehicles 3
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the planner's BLAS is not what is measured here
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_remote import LAKE, goto_cycles  # noqa: E402

from guadal_cli.fleet.remote import RemoteFleet, SitlConfig  # noqa: E402
from guadal_cli.graph import NavGraph  # noqa: E402
from guadal_cli.maps.format import load_map  # noqa: E402
from guadal_cli.mission import auto_positions  # noqa: E402
from guadal_cli.stack import Stack  # noqa: E402


def one_run(graph, n: int, secure: bool, cycles: int, speedup: float) -> float:
    """Median seconds of one decision cycle (all boats 'reached') on a fresh stack."""
    start = auto_positions(graph, n)
    homes = [(float(graph.lat[i]), float(graph.lon[i])) for i in start]
    stack = Stack.launch(
        map_path=LAKE,
        vehicles=n,
        homes=homes,
        speedup=speedup,
        broker_kind="mosquitto",
        timeout=180,
        secure=secure,
    )
    fleet = RemoteFleet(graph, n, 1e9, None, SitlConfig(**stack.planner_backend()))
    try:
        fleet.reset(start)
        _, reached = goto_cycles(fleet, cycles)
        assert fleet.dropped.keys() <= {"stale", "duplicate"}, dict(fleet.dropped)
    finally:
        fleet.close()
        stack.down()
    return statistics.median(reached)


def codec_cost(rounds: int = 20_000) -> tuple[float, float]:
    """Microseconds to encode and decode one goto, unsigned and signed (the CPU part alone)."""
    from guadal_cli.channel.protocol import Codec

    topic = "guadal/vehicle/0/command"
    fields = dict(session="9f1c2ab04e77d3a1", seq=7, node=171, lat=37.41812986, lon=-5.9837897)
    spent = [0.0, 0.0]
    codecs = (Codec(), Codec(b"0123456789abcdef0123456789abcdef"))
    for _ in range(10):  # interleaved blocks, as the stacks above
        for i, codec in enumerate(codecs):
            t0 = time.perf_counter()
            for _ in range(rounds // 10):
                codec.decode(topic, codec.encode(topic, "goto", **fields))
            spent[i] += time.perf_counter() - t0
    return 1e6 * spent[0] / rounds, 1e6 * spent[1] / rounds


def blas_threads() -> str:
    try:
        from threadpoolctl import threadpool_info

        found = {i.get("num_threads") for i in threadpool_info() if i.get("user_api") == "blas"}
        return ", ".join(map(str, sorted(found))) or "no BLAS loaded"
    except ImportError:
        return f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repetitions", type=int, default=5)
    parser.add_argument("--cycles", type=int, default=30)
    parser.add_argument("--vehicles", type=int, default=3)
    parser.add_argument("--speedup", type=float, default=50.0)
    args = parser.parse_args()
    graph = NavGraph(load_map(LAKE))
    import numpy  # noqa: F401  (loads the BLAS, so its thread count can be read)

    print(
        f"{dt.date.today()} · {os.cpu_count()} cores · {platform.machine()} · Python {platform.python_version()} · "
        f"BLAS threads: {blas_threads()}\n"
    )
    rows = []
    for rep in range(args.repetitions):  # off and on back to back: a busy moment hits both
        t0 = time.perf_counter()
        off = one_run(graph, args.vehicles, False, args.cycles, args.speedup)
        on = one_run(graph, args.vehicles, True, args.cycles, args.speedup)
        rows.append((off, on))
        print(f"<!-- repetition {rep + 1}: {time.perf_counter() - t0:.0f} s -->", file=sys.stderr)
    print(
        f"Decision cycle, {args.vehicles} boats, {args.cycles} cycles per run after 3 warm-up ones, "
        f"speed-up {args.speedup:g}, Mosquitto; {args.repetitions} interleaved repetitions:\n"
    )
    print("| repetition | security off p50 | security on p50 | on / off |")
    print("|---|---|---|---|")
    for i, (off, on) in enumerate(rows, 1):
        print(f"| {i} | {1e3 * off:.1f} ms | {1e3 * on:.1f} ms | {on / off:.2f}× |")
    ratios = [on / off for off, on in rows]
    print(
        f"\nMedian ratio on / off: **{statistics.median(ratios):.2f}×** (min {min(ratios):.2f}, max {max(ratios):.2f})."
    )
    plain, signed = codec_cost()
    print(
        f"\nOne goto encoded and decoded in this process: {plain:.1f} µs unsigned, {signed:.1f} µs signed "
        f"and checked ({signed / plain:.2f}×)."
    )


if __name__ == "__main__":
    main()

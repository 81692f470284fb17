"""Whole missions on lakes of 10^4 .. 10^6 nodes: CPU, wall, peak memory, cost per step.

For every lake size and every algorithm (greedy, expected_improvement, lawnmower) one mission
runs in a fresh process (so its peak RSS is its own), with one BLAS thread: 20 boats, 5 m cells,
the gp environment with its default model choice (exact while it fits in 256 MB, then local),
at most ``--steps`` steps (500 steps x 20 boats: ~10,000 samples). The lake is a disc with
islands, so paths have to go round. Scaling exponents are least-squares slopes of log CPU
against log nodes (whole mission, same steps), and of log CPU per step against log samples so
far (within the largest mission: the cost of the second half of its steps against steps
10%-50%).

``--accuracy`` instead compares the local GP with the exact one on the shipped maps: each
shipped gp mission runs (exact GP), then its samples, step by step, are fed to both models;
the table gives the max and mean absolute differences of the final mean and std at every node,
and each model's CPU time for the whole sequence.

    python bench/bench_scale.py                       # 1e4, 1e5, 1e6 nodes; prints markdown
    python bench/bench_scale.py --sizes 10000 --steps 100
    python bench/bench_scale.py --accuracy
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
ALGORITHMS = ("greedy", "expected_improvement", "lawnmower")


def make_lake(n_nodes: int, path: Path) -> None:
    """A round lake of about ``n_nodes`` water cells of 5 m, with a few islands."""
    from guadal_cli.maps.format import Map

    side = int(math.ceil(math.sqrt(n_nodes / (math.pi / 4 * 0.97))))
    rr, cc = np.mgrid[0:side, 0:side]
    centre = (side - 1) / 2
    water = (rr - centre) ** 2 + (cc - centre) ** 2 <= (side / 2) ** 2
    rng = np.random.default_rng(0)
    for _ in range(6):  # islands: ~3% of the disc
        r, c = rng.uniform(0.3, 0.7, 2) * side
        water &= (rr - r) ** 2 + (cc - c) ** 2 > (0.04 * side) ** 2
    Map(
        mask=water,
        cell_size_m=5.0,
        reference={"row": 0, "col": 0, "lat": -25.3, "lon": -57.3},
        name=f"disc-{int(water.sum())}",
    ).save(path)


def mission(map_path: Path, algorithm: str, steps: int) -> dict:
    return {
        "name": f"scale-{algorithm}",
        "seed": 1,
        "map": str(map_path),
        "environment": {
            "type": "gp",
            "ground_truth": {"type": "shekel", "peaks": 8},
            "kernel": {"type": "matern", "nu": 1.5, "length_scale": 20.0, "noise": 1e-3},
        },
        "algorithm": {"type": algorithm},
        "fleet": {"vehicles": 20, "initial_positions": "auto", "max_distance": 100_000.0, "speed": 1.0},
        "backend": {"level": "sim"},
        "max_steps": steps,
    }


def run_one(mission_path: Path, output: Path) -> dict:
    """Child process: run the mission, report CPU, wall, peak RSS and CPU at every step."""
    from guadal_cli.mission import prepare
    from guadal_cli.runner import MissionRunner

    cpu0, wall0 = time.process_time(), time.perf_counter()
    prep = prepare(mission_path)
    setup_cpu = time.process_time() - cpu0
    marks: list[tuple[int, float]] = []
    runner = MissionRunner(
        prep, output=output, on_step=lambda step, fleet: marks.append((step, time.process_time()))
    )
    result = runner.run()
    manifest = json.loads((output / "manifest.json").read_text())
    return {
        "nodes": prep.graph.n_nodes,
        "steps": result.steps,
        "samples": int(result.final_metrics["samples"]),
        "cpu": time.process_time() - cpu0,
        "setup_cpu": setup_cpu,
        "wall": time.perf_counter() - wall0,
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "marks": marks,
        "model": manifest.get("model"),
    }


def per_step_ms(marks, lo: float, hi: float) -> float:
    """CPU ms per step between two fractions of the mission's steps."""
    cpu = dict(marks)
    last = max(cpu)
    a, b = max(int(lo * last), min(cpu)), int(hi * last)
    return 1000 * (cpu[b] - cpu[a]) / max(b - a, 1)


def accuracy() -> None:
    import csv

    from threadpoolctl import threadpool_limits

    from guadal_cli.mission import prepare
    from guadal_cli.models.gp import IncrementalGP
    from guadal_cli.models.local_gp import LocalGP
    from guadal_cli.runner import MissionRunner

    threadpool_limits(1)
    print(
        "| mission | map | nodes | samples | mean: max abs err | mean: mean abs err | std: max abs err | std: mean abs err | exact CPU s | local CPU s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in ("lake_greedy", "lake_expected_improvement", "lake_lawnmower"):
            for map_name in ("urban_lake", "reservoir"):
                spec = yaml.safe_load((ROOT / "missions" / f"{name}.yaml").read_text())
                spec["map"] = str(ROOT / "maps" / f"{map_name}.json")
                path = tmp / f"{name}-{map_name}.yaml"
                path.write_text(yaml.safe_dump(spec))
                prep = prepare(path)
                out = tmp / f"run-{name}-{map_name}"
                MissionRunner(prep, output=out).run()
                steps: dict[int, list] = {}
                with open(out / "measurements.csv") as fh:
                    for row in csv.DictReader(fh):
                        steps.setdefault(int(row["step"]), []).append((int(row["node"]), float(row["value"])))
                xy, kernel = prep.graph.xy, prep.environment_config.kernel
                models = {"exact": IncrementalGP(kernel, xy), "local": LocalGP(kernel, xy)}
                cpu = {}
                for kind, model in models.items():
                    t0 = time.process_time()
                    for batch in steps.values():
                        nodes = [n for n, _ in batch]
                        model.add_many(xy[nodes], [v for _, v in batch], points=nodes)
                        _ = model.std  # read after every update, as the planners do
                    cpu[kind] = time.process_time() - t0
                exact, local = models["exact"], models["local"]
                dm, ds = np.abs(local.mean - exact.mean), np.abs(local.std - exact.std)
                print(
                    f"| {name} | {map_name} | {len(xy):,} | {exact.n_} | {dm.max():.1e} | {dm.mean():.1e} | "
                    f"{ds.max():.1e} | {ds.mean():.1e} | {cpu['exact']:.2f} | {cpu['local']:.2f} |",
                    flush=True,
                )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS))
    parser.add_argument("--save", type=Path, help="also add the results to this JSON file (runs accumulate)")
    parser.add_argument("--accuracy", action="store_true", help="local GP against exact on the shipped maps")
    parser.add_argument("--one", nargs=2, metavar=("MISSION", "OUTPUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.accuracy:
        accuracy()
        return
    if args.one:
        print(json.dumps(run_one(Path(args.one[0]), Path(args.one[1]))))
        return

    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for size in args.sizes:
            map_path = tmp / f"lake-{size}.json"
            make_lake(size, map_path)
            for algorithm in args.algorithms:
                path = tmp / f"{size}-{algorithm}.yaml"
                path.write_text(yaml.safe_dump(mission(map_path, algorithm, args.steps)))
                out = tmp / f"run-{size}-{algorithm}"
                proc = subprocess.run(
                    [sys.executable, __file__, "--one", str(path), str(out)],
                    env=env,
                    capture_output=True,
                    text=True,
                )
                if proc.returncode:
                    sys.exit(f"{size} {algorithm} failed:\n{proc.stderr}")
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                r.update(algorithm=algorithm, size=size)
                results.append(r)
                print(
                    f"# {r['nodes']} nodes {algorithm}: {r['cpu']:.1f} s CPU, {r['rss_mb']:.0f} MB",
                    file=sys.stderr,
                    flush=True,
                )

    if args.save:  # several invocations (one size at a time, say) make one table
        earlier = json.loads(args.save.read_text()) if args.save.exists() else []
        results = earlier + results
        args.save.write_text(json.dumps(results))
    algorithms = list(dict.fromkeys(r["algorithm"] for r in results))
    print(f"{os.cpu_count()} cores (shared), one BLAS thread, Python {sys.version.split()[0]}.\n")
    print(
        "| algorithm | nodes | steps | samples | model | CPU s | of which setup | wall s | peak RSS MB | CPU ms/step, 1st half | CPU ms/step, 2nd half |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        model = r["model"] or {}
        kind = model.get("type", "?") + (
            f" from sample {model['since_sample']}" if model.get("since_sample") else ""
        )
        print(
            f"| {r['algorithm']} | {r['nodes']:,} | {r['steps']} | {r['samples']:,} | {kind} | {r['cpu']:.1f} | "
            f"{r['setup_cpu']:.1f} | {r['wall']:.1f} | {r['rss_mb']:.0f} | {per_step_ms(r['marks'], 0.1, 0.5):.1f} | "
            f"{per_step_ms(r['marks'], 0.5, 1.0):.1f} |"
        )
    print("\nScaling exponents (log-log slopes):\n")
    print("| algorithm | CPU vs nodes | CPU per step vs samples so far (largest lake) |")
    print("|---|---|---|")
    for algorithm in algorithms:
        rows = [r for r in results if r["algorithm"] == algorithm]
        slope = (
            np.polyfit(np.log([r["nodes"] for r in rows]), np.log([r["cpu"] for r in rows]), 1)[0]
            if len(rows) > 1
            else math.nan
        )
        big = max(rows, key=lambda r: r["nodes"])
        early, late = per_step_ms(big["marks"], 0.1, 0.5), per_step_ms(big["marks"], 0.5, 1.0)
        # samples grow linearly with steps: the windows' mid-points hold 0.3 and 0.75 of them
        growth = math.log(late / early) / math.log(0.75 / 0.3) if early > 0 else math.nan
        print(f"| {algorithm} | {slope:.2f} | {growth:.2f} |")


if __name__ == "__main__":
    main()

"""Sweep benchmarks: parallel speed-up, the machinery's overhead, planning 10,000 combinations.

    python bench/bench_sweep.py [--missions 200] [--repeats 2]

1. Speed-up: the paper-scale lake comparison (missions/lake_greedy.yaml: 3 boats, 925 m each;
   greedy, expected improvement, lawnmower, random; seeds 1..N/4) run as a sweep with 1 and with
   2 local workers, interleaved (1, 2, 1, 2, ...) so that load from other jobs falls on both.
2. Overhead: the same missions in a bare loop in this process (prepare + run, what `guadal run`
   does minus the interpreter start) against the sweep with 1 worker, interleaved too. The
   literal `guadal run` shell loop (a process per mission) is timed on a sample for reference.
3. Planning: load + validate a 10,000-combination sweep, against validating each combination
   as `guadal validate` would (full prepare), timed on a sample and scaled to 10,000.

Every worker, and this process, runs with one BLAS thread.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # before numpy loads: the baseline gets one BLAS thread, like each worker

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guadal_cli.mission import prepare_dict  # noqa: E402
from guadal_cli.runner import MissionRunner  # noqa: E402
from guadal_cli.sweep.engine import run_sweep, to_run  # noqa: E402
from guadal_cli.sweep.executors import LocalExecutor  # noqa: E402
from guadal_cli.sweep.manifest import SweepManifest  # noqa: E402
from guadal_cli.sweep.plan import plan_sweep  # noqa: E402
from guadal_cli.sweep.spec import load_sweep  # noqa: E402
from guadal_cli.sweep.summary import summarize  # noqa: E402

ALGORITHMS = ["greedy", "expected_improvement", "lawnmower", "random"]


def write_sweep(folder: Path, seeds: int, **extra) -> Path:
    data = {
        "name": "bench",
        "base": str(ROOT / "missions" / "lake_greedy.yaml"),
        "grid": {"algorithm.type": ALGORITHMS},
        "seeds": f"1..{seeds}",
        **extra,
    }
    path = folder / f"sweep-{len(list(folder.iterdir()))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def timed_sweep(path: Path, out: Path, workers: int) -> tuple[float, dict]:
    """Wall time of what `guadal sweep` does: plan, start workers, run, write the summary."""
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    plan = plan_sweep(load_sweep(path))
    manifest = SweepManifest.open(out, plan)
    executor = LocalExecutor(workers)
    counts = run_sweep(plan, manifest, executor, to_run(plan, manifest))
    executor.close()
    summarize(out)
    elapsed = time.perf_counter() - start
    assert counts["complete"] == len(plan), counts
    return elapsed, {e["id"]: e["final_metrics"] for e in manifest.entries.values()}


def timed_bare_loop(path: Path, out: Path) -> float:
    """The same missions one after the other in this process: prepare + run, nothing else."""
    shutil.rmtree(out, ignore_errors=True)
    plan = plan_sweep(load_sweep(path))  # not timed: only to get the same mission dicts
    start = time.perf_counter()
    for combo in plan.combinations:
        prep = prepare_dict(combo.mission, plan.sweep.base_dir, "bench")
        MissionRunner(prep, output=out / combo.id).run()
    return time.perf_counter() - start


def timed_cli_loop(path: Path, out: Path, n: int) -> float:
    """`guadal run` as a shell loop would call it, one process per mission, on n missions."""
    plan = plan_sweep(load_sweep(path))
    files = []
    for combo in plan.combinations[:n]:
        f = out / f"{combo.id}.yaml"
        out.mkdir(parents=True, exist_ok=True)
        mission = dict(combo.mission, map=str(ROOT / "maps" / "urban_lake.json"))
        f.write_text(yaml.safe_dump(mission))
        files.append(f)
    start = time.perf_counter()
    for f in files:
        subprocess.run(
            [sys.executable, "-m", "guadal_cli", "run", str(f), "--output", str(out / f.stem), "--quiet"],
            check=True,
        )
    return (time.perf_counter() - start) / n


def blas_threads() -> str:
    from threadpoolctl import threadpool_info

    info = threadpool_info()
    return ", ".join(f"{i['internal_api']} {i['num_threads']}" for i in info) or "none loaded"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--missions", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--cli-sample", type=int, default=8)
    args = parser.parse_args()
    seeds = args.missions // len(ALGORITHMS)
    tmp = Path(tempfile.mkdtemp(prefix="guadal-bench-sweep-"))
    try:
        sweeps = tmp / "sweeps"
        sweeps.mkdir()
        path = write_sweep(sweeps, seeds)
        print(f"# {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
        print(f"# load average before: {os.getloadavg()[0]:.2f}")

        # warm-up: one small sweep so that caches and imports are paid before timing
        timed_sweep(write_sweep(sweeps, 1), tmp / "warm", 2)
        timed_bare_loop(write_sweep(sweeps, 1), tmp / "warm-bare")

        rows, results = [], {}
        for r in range(args.repeats):
            for kind in ("bare", 1, 2):
                load = os.getloadavg()[0]
                if kind == "bare":
                    t = timed_bare_loop(path, tmp / "bare")
                else:
                    t, results[(kind, r)] = timed_sweep(path, tmp / f"w{kind}", kind)
                rows.append((r, kind, t, load))
                print(f"repeat {r} {kind!s:>4}: {t:7.2f} s  (load average at start {load:.2f})", flush=True)
        first = results[(1, 0)]
        same = all(res == first for res in results.values())
        print(f"# BLAS threads in this process: {blas_threads()}")
        print(f"# same final metrics in every sweep run: {same}")

        print(
            "\n| repeat | bare loop, s | sweep 1 worker, s | sweep 2 workers, s | speed-up 2 vs 1 | overhead 1 worker vs bare |"
        )
        print("|---|---|---|---|---|---|")
        for r in range(args.repeats):
            t = {kind: time for rr, kind, time, _ in rows if rr == r}
            print(
                f"| {r + 1} | {t['bare']:.1f} | {t[1]:.1f} | {t[2]:.1f} | {t[1] / t[2]:.2f}× | "
                f"{(t[1] - t['bare']) / t['bare'] * 100:+.1f} % |"
            )
        per_mission = timed_cli_loop(path, tmp / "cli", args.cli_sample)
        bare_per_mission = min(t for _, kind, t, _ in rows if kind == "bare") / args.missions
        print(
            f"\n`guadal run` process per mission: {per_mission:.2f} s/mission on {args.cli_sample} missions; "
            f"bare in-process loop: {bare_per_mission:.3f} s/mission"
        )

        # 3. planning and validating 10,000 combinations
        big = write_sweep(
            sweeps,
            100,
            grid={
                "algorithm.type": ALGORITHMS,
                "environment.kernel.length_scale": [10, 15, 20, 25, 30],
                "fleet.vehicles": [1, 2, 3, 4, 5],
            },
        )
        start = time.perf_counter()
        plan = plan_sweep(load_sweep(big))
        plan_s = time.perf_counter() - start
        sample = plan.combinations[:: len(plan) // 40][:40]
        start = time.perf_counter()
        for combo in sample:
            prepare_dict(combo.mission, plan.sweep.base_dir, "bench")
        per_prepare = (time.perf_counter() - start) / len(sample)
        print(
            f"\nplan + validate {len(plan)} combinations: {plan_s:.2f} s "
            f"(distinct: {plan.distinct}); full prepare per combination: {per_prepare * 1000:.1f} ms "
            f"-> {per_prepare * len(plan):.0f} s for all; ratio {per_prepare * len(plan) / plan_s:.0f}×"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()

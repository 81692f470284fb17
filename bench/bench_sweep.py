"""Sweep benchmarks: parallel speed-up, the machinery's overhead, planning 10,000 combinations.

    python bench/bench_sweep.py [--missions 200] [--blocks 5]

1. Speed-up: the paper-scale lake comparison (missions/lake_greedy.yaml: 3 boats, 925 m each;
   greedy, expected improvement, lawnmower, random; N/4 seeds) run as sweeps with 1 and with 2
   local workers. On a shared machine the load moves by the minute, so the N missions are run in
   blocks (different seeds each), and each block is run by the bare loop, 1 worker and 2 workers
   back to back: every ratio compares runs a few seconds apart.
2. Overhead: the same blocks in a bare loop in this process (prepare + run: what `guadal run`
   does minus the interpreter start) against the sweep with 1 worker, in wall and CPU time (CPU
   time is what load from other jobs does not inflate). The summary table a sweep writes at the
   end is timed apart; the literal `guadal run` shell loop (a process per mission) on a sample.
   Then a 1-worker sweep of 4 and of 40 missions against the bare loop splits the CPU overhead
   into a fixed cost per sweep and a per-mission slope (``--only-overhead-split`` runs just that).
3. Planning: load + validate a 10,000-combination sweep, against validating each combination
   as `guadal validate` would (full prepare), timed on a sample and scaled to 10,000.

Every worker, and this process, runs with one BLAS thread.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"  # before numpy loads: the baseline gets one BLAS thread, like each worker
# The mission database is off on both sides (workers inherit this): its writer thread goes on after
# a mission returns, so its CPU lands in whichever run is going, and it has its own benchmark
# (bench_db.py). GUADAL_BENCH_DB=1 keeps it on.
if os.environ.get("GUADAL_BENCH_DB") != "1":
    os.environ["GUADAL_DB"] = "none"

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


def write_sweep(folder: Path, seeds: str, **extra) -> Path:
    data = {
        "name": "bench",
        "base": str(ROOT / "missions" / "lake_greedy.yaml"),
        "grid": {"algorithm.type": ALGORITHMS},
        "seeds": seeds,
        **extra,
    }
    path = folder / f"sweep-{len(list(folder.iterdir()))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def cpu_seconds() -> float:
    """CPU time of this process and of its ended children (the sweep's workers, once closed)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed_sweep(path: Path, out: Path, workers: int) -> tuple[float, float, float, dict]:
    """What `guadal sweep` does: wall and CPU time to plan, start workers and run; CPU of the summary."""
    shutil.rmtree(out, ignore_errors=True)
    cpu = cpu_seconds()
    start = time.perf_counter()
    sweep = load_sweep(path)
    executor = LocalExecutor(workers)  # as `guadal sweep` does: workers start while the plan is checked
    plan = plan_sweep(sweep)
    manifest = SweepManifest.open(out, plan)
    counts = run_sweep(plan, manifest, executor, to_run(plan, manifest))
    executor.close()
    elapsed, run_cpu = time.perf_counter() - start, cpu_seconds() - cpu
    assert counts["complete"] == len(plan), counts
    cpu = cpu_seconds()
    summarize(out)
    return (
        elapsed,
        run_cpu,
        cpu_seconds() - cpu,
        {e["id"]: e["final_metrics"] for e in manifest.entries.values()},
    )


def worker_start_cpu() -> float:
    """CPU time to start one worker process and import guadal in it (paid once per worker)."""
    cpu = cpu_seconds()
    executor = LocalExecutor(1)
    executor._pool.submit(int).result()
    executor.close()
    return cpu_seconds() - cpu


def timed_bare_loop(path: Path, out: Path) -> tuple[float, float]:
    """The same missions one after the other in this process: prepare + run, nothing else."""
    shutil.rmtree(out, ignore_errors=True)
    plan = plan_sweep(load_sweep(path))  # not timed: only to get the same mission dicts
    cpu = cpu_seconds()
    start = time.perf_counter()
    for combo in plan.combinations:
        prep = prepare_dict(combo.mission, plan.sweep.base_dir, "bench")
        MissionRunner(prep, output=out / combo.id).run()
    return time.perf_counter() - start, cpu_seconds() - cpu


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
            [sys.executable, "-m", "guadal_cli", "run", str(f), "--run-dir", str(out / f.stem), "--quiet"],
            check=True,
        )
    return (time.perf_counter() - start) / n


def fixed_and_marginal(sweeps: Path, tmp: Path, repeats: int = 2) -> None:
    """CPU overhead of a 1-worker sweep over the bare loop at two sizes (4 and 40 missions).

    If the overhead does not grow with the number of missions, it is a fixed cost per sweep
    (worker start-up, plugin discovery, planning) and the per-mission overhead is the slope.
    """
    print("\n| missions | bare loop CPU, s | sweep 1 worker CPU, s | overhead CPU, s |")
    print("|---|---|---|---|")
    diffs = {}
    for _ in range(repeats):
        for seeds in ("1..1", "1..10"):
            path = write_sweep(sweeps, seeds)
            _, bare = timed_bare_loop(path, tmp / "bare")
            _, cpu, _, _ = timed_sweep(path, tmp / "sw", 1)
            n = len(ALGORITHMS) * (1 if seeds == "1..1" else 10)
            diffs.setdefault(n, []).append(cpu - bare)
            print(f"| {n} | {bare:.2f} | {cpu:.2f} | {cpu - bare:+.2f} |", flush=True)
    small, large = (sum(v) / len(v) for v in diffs.values())
    print(
        f"\nper-mission overhead (slope): {(large - small) / 36 * 1000:+.1f} ms; fixed per sweep: {small:.2f} s CPU"
    )


def blas_threads() -> str:
    from threadpoolctl import threadpool_info

    info = threadpool_info()
    return ", ".join(f"{i['internal_api']} {i['num_threads']}" for i in info) or "none loaded"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--missions", type=int, default=200)
    parser.add_argument("--blocks", type=int, default=5)
    parser.add_argument("--cli-sample", type=int, default=8)
    parser.add_argument(
        "--only-overhead-split", action="store_true", help="Only the fixed/per-mission split."
    )
    args = parser.parse_args()
    per_block = args.missions // args.blocks // len(ALGORITHMS)  # seeds per block
    tmp = Path(tempfile.mkdtemp(prefix="guadal-bench-sweep-"))
    try:
        sweeps = tmp / "sweeps"
        sweeps.mkdir()
        print(f"# {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
        print(f"# load average before: {os.getloadavg()[0]:.2f}")
        print(f"# mission database: {os.environ.get('GUADAL_DB', 'on (SQLite beside the runs)')}")

        # warm-up: small runs so that caches and imports are paid before timing
        timed_sweep(write_sweep(sweeps, "1..1"), tmp / "warm", 2)
        timed_bare_loop(write_sweep(sweeps, "1..1"), tmp / "warm-bare")
        if args.only_overhead_split:
            fixed_and_marginal(sweeps, tmp)
            return

        rows, results = [], {}
        for b in range(args.blocks):
            path = write_sweep(sweeps, f"{b * per_block + 1}..{(b + 1) * per_block}")
            for kind in ("bare", 1, 2):
                load = os.getloadavg()[0]
                if kind == "bare":
                    wall, cpu = timed_bare_loop(path, tmp / "bare")
                    summary = 0.0
                else:
                    wall, cpu, summary, results[(kind, b)] = timed_sweep(path, tmp / f"w{kind}", kind)
                rows.append((b, kind, wall, cpu, summary))
                print(
                    f"block {b} {kind!s:>4}: {wall:7.2f} s wall, {cpu:7.2f} s CPU, summary {summary:.2f} s CPU "
                    f"(load {load:.2f})",
                    flush=True,
                )
        same = all(results[(1, b)] == results[(2, b)] for b in range(args.blocks))
        start_cpu = min(worker_start_cpu() for _ in range(3))
        print(f"# BLAS threads in this process: {blas_threads()}")
        print(f"# same final metrics with 1 and 2 workers: {same}")
        print(f"# load average after: {os.getloadavg()[0]:.2f}")
        print(f"# one worker's start-up (spawn + imports): {start_cpu:.2f} s CPU")

        n = per_block * len(ALGORITHMS)
        print(
            f"\n| block ({n} missions) | bare loop wall / CPU, s | sweep 1 worker wall / CPU, s "
            "| sweep 2 workers wall, s | speed-up 2 vs 1 (wall) | overhead 1 worker vs bare: wall | CPU "
            "| CPU without the worker's start-up, per mission |"
        )
        print("|---|---|---|---|---|---|---|---|")
        total = {}
        for b in range(args.blocks):
            t = {kind: (wall, cpu) for bb, kind, wall, cpu, _ in rows if bb == b}
            for kind, (wall, cpu) in t.items():
                total[kind] = (total.get(kind, (0, 0))[0] + wall, total.get(kind, (0, 0))[1] + cpu)
            per_mission = (t[1][1] - t["bare"][1] - start_cpu) / n
            print(
                f"| {b + 1} | {t['bare'][0]:.1f} / {t['bare'][1]:.1f} | {t[1][0]:.1f} / {t[1][1]:.1f} | "
                f"{t[2][0]:.1f} | {t[1][0] / t[2][0]:.2f}× | {(t[1][0] - t['bare'][0]) / t['bare'][0] * 100:+.1f} % | "
                f"{(t[1][1] - t['bare'][1]) / t['bare'][1] * 100:+.1f} % | "
                f"{per_mission * 1000:+.1f} ms ({per_mission / (t['bare'][1] / n) * 100:+.1f} %) |"
            )
        t = total
        print(
            f"| all {n * args.blocks} | {t['bare'][0]:.1f} / {t['bare'][1]:.1f} | {t[1][0]:.1f} / {t[1][1]:.1f} | "
            f"{t[2][0]:.1f} | {t[1][0] / t[2][0]:.2f}× | {(t[1][0] - t['bare'][0]) / t['bare'][0] * 100:+.1f} % | "
            f"{(t[1][1] - t['bare'][1]) / t['bare'][1] * 100:+.1f} % | |"
        )
        summaries = [s for _, kind, _, _, s in rows if kind == 1]
        print(
            f"\nsummary table of {n} runs: {sum(summaries) / len(summaries):.2f} s CPU (not in the figures above)"
        )
        fixed_and_marginal(sweeps, tmp)
        per_mission = timed_cli_loop(path, tmp / "cli", args.cli_sample)
        bare_per_mission = min(wall for _, kind, wall, _, _ in rows if kind == "bare") / n
        print(
            f"\n`guadal run` process per mission: {per_mission:.2f} s/mission on {args.cli_sample} missions; "
            f"bare in-process loop: {bare_per_mission:.3f} s/mission"
        )

        # 3. planning and validating 10,000 combinations
        big = write_sweep(
            sweeps,
            "1..100",
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

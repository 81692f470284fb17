"""Incremental GP against a full scikit-learn refit at every step.

Runs the 3-vehicle greedy mission (`missions/lake_greedy.yaml`) on both shipped maps twice:
with guadal's incremental GP, and with a baseline environment that refits scikit-learn's
GaussianProcessRegressor (same kernel, optimizer off, alpha = noise variance) on all samples at
every update. Both runs are timed whole (planning, fleet, the run directory's CSVs written and
flushed every step included) and for the model updates alone. During the baseline run an
incremental GP is fed the same samples, and the largest absolute difference of the two
posteriors (mean and std at every node, after every update) is reported; the time that
comparison takes is not counted in the baseline's mission. The mission database is off on both
sides (``output.database: none``): its writer is a background thread whose work would be
counted in whichever run happens to be going when it delivers.

Times are CPU seconds of this process, and everything runs with one BLAS thread (as guadal's
model updates do by default): on a busy machine wall time measures the neighbours, CPU time
the work, so the ratio holds there too. Each map's pair of runs is repeated (interleaved: incremental,
refit, incremental, ...) and the median of each is reported.

    python bench/bench_gp.py            # prints a markdown table
    python bench/bench_gp.py --repeat 5 --maps urban_lake
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from sklearn.gaussian_process import GaussianProcessRegressor
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from guadal_cli.envs.gp import GPEnvironment  # noqa: E402
from guadal_cli.mission import prepare  # noqa: E402
from guadal_cli.models.gp import IncrementalGP, sklearn_kernel  # noqa: E402
from guadal_cli.runner import MissionRunner  # noqa: E402


class TimedGP(GPEnvironment):
    """guadal's own environment, with the time spent updating the model summed up."""

    update_seconds = 0.0

    def update(self, measurements):
        t0 = time.process_time()
        super().update(measurements)
        self.update_seconds += time.process_time() - t0


class SklearnRefitGP(GPEnvironment):
    """The baseline: refit a scikit-learn GP on every sample so far, predict at every node."""

    update_seconds = 0.0
    shadow_seconds = 0.0  # the comparison's own cost, taken out of the mission's time
    max_mean_diff = 0.0
    max_std_diff = 0.0

    def reset(self, seed):
        super().reset(seed)
        self._X, self._y = [], []
        self._mean = np.full(self.graph.n_nodes, self.config.prior_mean)
        self._std = np.full(self.graph.n_nodes, np.sqrt(self.config.kernel.variance))
        self.shadow = IncrementalGP(self.config.kernel, self.graph.xy, self.config.prior_mean)

    def update(self, measurements):
        t0 = time.process_time()
        for m in measurements:
            self._X.append(self.graph.xy[m.node])
            self._y.append(m.value)
        kernel = self.config.kernel
        gpr = GaussianProcessRegressor(
            kernel=sklearn_kernel(kernel), alpha=kernel.noise, optimizer=None, normalize_y=False
        )
        gpr.fit(np.array(self._X), np.array(self._y) - self.config.prior_mean)
        mean, self._std = gpr.predict(self.graph.xy, return_std=True)
        self._mean = mean + self.config.prior_mean
        t1 = time.process_time()
        self.update_seconds += t1 - t0
        # not the baseline's work: the incremental model on the same samples, compared node by node
        for m in measurements:
            self.shadow.add(self.graph.xy[m.node], m.value)
        self.max_mean_diff = max(self.max_mean_diff, float(np.abs(self.shadow.mean - self._mean).max()))
        self.max_std_diff = max(self.max_std_diff, float(np.abs(self.shadow.std - self._std).max()))
        self.shadow_seconds += time.process_time() - t1

    def observation_fields(self):
        return {"mean": self._mean, "std": self._std}

    def metrics(self):
        rmse = float(np.sqrt(np.mean((self._mean - self.ground_truth) ** 2)))
        return {"rmse": rmse, "mean_std": float(self._std.mean()), "max_std": float(self._std.max())}


def run(mission_path: Path, env_cls, workdir: Path, tag: str):
    prep = prepare(mission_path)
    env = env_cls(prep.environment_config, prep.graph, base_dir=prep.base_dir)
    env.reset(prep.environment_seed)
    prep.environment = env
    t0 = time.process_time()
    result = MissionRunner(prep, output=workdir / tag).run()
    cpu = time.process_time() - t0 - getattr(env, "shadow_seconds", 0.0)
    plan = (workdir / tag / "trajectory.csv").read_text()
    return cpu, env, result, plan


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--maps", nargs="+", default=["urban_lake", "reservoir"], help="shipped map names")
    args = parser.parse_args()
    threadpool_limits(1)  # the baseline too: one BLAS thread for everything
    base = yaml.safe_load((ROOT / "missions" / "lake_greedy.yaml").read_text())
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for map_name in args.maps:
            mission = dict(base, name=f"bench_{map_name}", map=str(ROOT / "maps" / f"{map_name}.json"))
            mission["output"] = dict(base["output"], database="none")
            path = tmp / f"{map_name}.yaml"
            path.write_text(yaml.safe_dump(mission))
            run(path, TimedGP, tmp, f"{map_name}-warm-up")  # one-time costs (imports, metadata) paid here
            inc, ref = [], []
            for i in range(args.repeat):
                inc.append(run(path, TimedGP, tmp, f"{map_name}-incremental-{i}"))
                ref.append(run(path, SklearnRefitGP, tmp, f"{map_name}-sklearn-{i}"))
            cpu_inc = float(np.median([r[0] for r in inc]))
            cpu_ref = float(np.median([r[0] for r in ref]))
            upd_inc = float(np.median([r[1].update_seconds for r in inc]))
            upd_ref = float(np.median([r[1].update_seconds for r in ref]))
            _, env_inc, res, plan_inc = inc[0]
            _, env_ref, _, plan_ref = ref[0]
            rows.append(
                (
                    map_name,
                    env_inc.graph.n_nodes,
                    res.final_metrics["samples"],
                    res.steps,
                    cpu_ref,
                    cpu_inc,
                    cpu_ref / cpu_inc,
                    upd_ref / upd_inc,
                    env_ref.max_mean_diff,
                    env_ref.max_std_diff,
                    plan_inc == plan_ref,
                )
            )
    print(
        f"Measured {dt.date.today().isoformat()} on {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"one BLAS thread, median of {args.repeat} interleaved runs.\n"
    )
    print(
        "| map | nodes | samples | steps | sklearn refit, CPU s | incremental, CPU s | mission speed-up | model-update speed-up | max abs diff mean | max abs diff std | same trajectory |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.2f} | {r[5]:.3f} | {r[6]:.1f}x | {r[7]:.1f}x | {r[8]:.1e} | {r[9]:.1e} | {'yes' if r[10] else 'no'} |"
        )


if __name__ == "__main__":
    main()

"""Incremental GP against a full scikit-learn refit at every step.

Runs the 3-vehicle greedy mission (`missions/lake_greedy.yaml`) on both shipped maps twice:
with guadal's incremental GP, and with a baseline environment that refits scikit-learn's
GaussianProcessRegressor (same kernel, optimizer off, alpha = noise variance) on all samples at
every update. Both runs are timed whole (planning, fleet, recording included) and for the model
updates alone. During the baseline run an untimed incremental GP is fed the same samples, and
the largest absolute difference of the two posteriors (mean and std at every node, after every
update) is reported.

    python bench/bench_gp.py            # prints a markdown table
"""

from __future__ import annotations

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
        t0 = time.perf_counter()
        super().update(measurements)
        self.update_seconds += time.perf_counter() - t0


class SklearnRefitGP(GPEnvironment):
    """The baseline: refit a scikit-learn GP on every sample so far, predict at every node."""

    update_seconds = 0.0
    max_mean_diff = 0.0
    max_std_diff = 0.0

    def reset(self, seed):
        super().reset(seed)
        self._X, self._y = [], []
        self._mean = np.full(self.graph.n_nodes, self.config.prior_mean)
        self._std = np.full(self.graph.n_nodes, np.sqrt(self.config.kernel.variance))
        self.shadow = IncrementalGP(self.config.kernel, self.graph.xy, self.config.prior_mean)

    def update(self, measurements):
        t0 = time.perf_counter()
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
        self.update_seconds += time.perf_counter() - t0
        # untimed: the incremental model on the same samples, compared node by node
        for m in measurements:
            self.shadow.add(self.graph.xy[m.node], m.value)
        self.max_mean_diff = max(self.max_mean_diff, float(np.abs(self.shadow.mean - self._mean).max()))
        self.max_std_diff = max(self.max_std_diff, float(np.abs(self.shadow.std - self._std).max()))

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
    t0 = time.perf_counter()
    result = MissionRunner(prep, output=workdir / tag).run()
    wall = time.perf_counter() - t0
    plan = (workdir / tag / "trajectory.csv").read_text()
    return wall, env, result, plan


def main() -> None:
    base = yaml.safe_load((ROOT / "missions" / "lake_greedy.yaml").read_text())
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for map_name in ("urban_lake", "reservoir"):
            mission = dict(base, name=f"bench_{map_name}", map=str(ROOT / "maps" / f"{map_name}.json"))
            path = tmp / f"{map_name}.yaml"
            path.write_text(yaml.safe_dump(mission))
            run(path, TimedGP, tmp, f"{map_name}-warm-up")  # one-time costs (imports, metadata) paid here
            wall_inc, env_inc, res, plan_inc = run(path, TimedGP, tmp, f"{map_name}-incremental")
            wall_ref, env_ref, _, plan_ref = run(path, SklearnRefitGP, tmp, f"{map_name}-sklearn")
            rows.append(
                (
                    map_name,
                    env_inc.graph.n_nodes,
                    res.final_metrics["samples"],
                    res.steps,
                    wall_ref,
                    wall_inc,
                    wall_ref / wall_inc,
                    env_ref.update_seconds / env_inc.update_seconds,
                    env_ref.max_mean_diff,
                    env_ref.max_std_diff,
                    plan_inc == plan_ref,
                )
            )
    print(
        f"Measured {dt.date.today().isoformat()} on {os.cpu_count()} cores, Python {platform.python_version()}.\n"
    )
    print(
        "| map | nodes | samples | steps | sklearn refit, s | incremental, s | mission speed-up | model-update speed-up | max abs diff mean | max abs diff std | same trajectory |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.2f} | {r[5]:.2f} | {r[6]:.1f}x | {r[7]:.1f}x | {r[8]:.1e} | {r[9]:.1e} | {'yes' if r[10] else 'no'} |"
        )


if __name__ == "__main__":
    main()

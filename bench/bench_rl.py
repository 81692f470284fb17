"""RL environment throughput: agent-steps per second of the PettingZoo env against ``guadal run``.

The paper-scale mission (`missions/lake_greedy.yaml`: 3 boats, 925 m each, exact GP on 351
nodes) is played to its end by one cheap hand-written policy (each boat scores the std of the
cell each action leads to; ``std_ahead`` below), twice per repeat:

- through ``MissionParallelEnv`` (reset, then ``step`` until no agent is left);
- through ``guadal run``'s runner (``MissionRunner`` with ``algorithm: {type: policy, model:
  bench_rl:std_ahead}``), which writes its run directory (CSV files, no database) as usual.

Both play the same episode (the trajectories are compared). Agent-steps are decisions times the
vehicles acting in them. The env's time per step is split into the model update (the GP), the
Episode's rules (its step less the model update: hops, conflicts, budgets, coverage), the
observation building (images and action masks, guadal_cli.rl.observation), the policy, the
metrics the reward is computed from, and the rest: the environment's own translation.

The env is also played with ``credit="difference"`` (each boat paid what its own samples added:
the world copied before every step and the step's updates replayed without each boat's samples),
unsplit, to give that credit's cost against the team credit's.

Times are CPU seconds of this process with one BLAS thread (threadpoolctl), the median of
``--repeat`` interleaved runs: on a shared machine wall time measures the neighbours.

    python bench/bench_rl.py              # prints a markdown table
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from threadpoolctl import threadpool_info, threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from guadal_cli.mission import prepare_dict  # noqa: E402
from guadal_cli.rl import MissionParallelEnv  # noqa: E402
from guadal_cli.rl.observation import OFFSETS  # noqa: E402
from guadal_cli.runner import MissionRunner  # noqa: E402


def std_ahead(observations: np.ndarray) -> np.ndarray:
    """Each action's score: the std channel (3) at the cell it leads to; staying scores -1."""
    n, _, rows, cols = observations.shape
    where = observations[:, 0].reshape(n, -1).argmax(axis=1)
    r, c = where // cols, where % cols
    padded = np.pad(observations[:, 3], ((0, 0), (1, 1), (1, 1)))
    scores = np.stack([padded[np.arange(n), r + 1 + dr, c + 1 + dc] for dr, dc in OFFSETS], axis=1)
    scores[:, 0] = -1.0
    return scores


class Clock:
    """CPU seconds spent inside wrapped functions, by label."""

    def __init__(self):
        self.spent: dict[str, float] = {}

    def wrap(self, label: str, fn):
        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.spent[label] = self.spent.get(label, 0.0) + time.process_time() - t0

        return timed


def mission(seed: int) -> dict:
    data = yaml.safe_load((ROOT / "missions" / "lake_greedy.yaml").read_text())
    data.update(
        seed=seed,
        algorithm={"type": "policy", "model": "bench_rl:std_ahead"},
        output={"directory": tempfile.gettempdir(), "database": "none"},
    )
    return data


def run_env(seed: int, credit: str = "team"):
    env = MissionParallelEnv(mission(seed), base_dir=ROOT / "missions", credit=credit)
    clock = Clock()
    if credit == "team":  # (difference credit copies the environment: its wrapped methods would
        # go on calling the original's, so that run is timed whole)
        gp = env.episode.environment
        gp.update = clock.wrap("model update", gp.update)
        env.builder.images = clock.wrap("observations", env.builder.images)
        env.builder.action_masks = clock.wrap("observations", env.builder.action_masks)
        gp.metrics = clock.wrap("metrics for the reward", gp.metrics)
        env.episode.step = clock.wrap("episode step", env.episode.step)
    policy = clock.wrap("policy", std_ahead)
    t0 = time.process_time()
    obs, infos = env.reset(seed=seed)
    clock.spent.clear()  # the first sample's update belongs to reset, as in the runner
    t0 = time.process_time()
    agent_steps = decisions = 0
    path = []
    while env.agents:
        agents = list(obs)
        scores = policy(np.stack([obs[a] for a in agents]))
        actions = {
            a: int(np.argmax(np.where(infos[a]["action_mask"] > 0, s, -np.inf)))
            for a, s in zip(agents, scores)
        }
        obs, _, _, _, infos = env.step(actions)
        agent_steps += len(actions)
        decisions += 1
        path.append(dict(env.episode.fleet.positions))
    total = time.process_time() - t0
    return total, agent_steps, decisions, clock.spent, path


def run_runner(seed: int):
    prep = prepare_dict(mission(seed), ROOT / "missions")
    with tempfile.TemporaryDirectory() as tmp:
        runner = MissionRunner(prep, output=Path(tmp) / "run")
        positions = []
        runner.on_step = lambda step, fleet: positions.append(dict(fleet.positions))
        t0 = time.process_time()
        result = runner.run()
        total = time.process_time() - t0
    return total, result.steps, positions[1:]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    threadpool_limits(1)
    blas = sorted(
        {(i["internal_api"], i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"}
    )
    load = os.getloadavg()
    run_env(args.seed), run_runner(args.seed)  # warm-up: imports, caches, kernels
    env_times, runner_times, difference_times, parts = [], [], [], []
    for _ in range(args.repeat):
        env_total, agent_steps, decisions, spent, env_path = run_env(args.seed)
        runner_total, runner_steps, runner_path = run_runner(args.seed)
        difference_total, _, _, _, difference_path = run_env(args.seed, credit="difference")
        env_times.append(env_total)
        runner_times.append(runner_total)
        difference_times.append(difference_total)
        parts.append(spent)
    assert difference_path == env_path  # the credit changes the rewards, not the episode
    same = env_path == runner_path[: len(env_path)] and len(runner_path) == len(env_path)
    env_s, runner_s = statistics.median(env_times), statistics.median(runner_times)
    labels = ("model update", "episode step", "observations", "policy", "metrics for the reward")
    split = {k: statistics.median(p.get(k, 0.0) for p in parts) for k in labels}
    split["Episode's rules (hops, conflicts, budgets, coverage)"] = (
        split.pop("episode step") - split["model update"]
    )
    split["the env's own translation (actions, rewards, dicts)"] = env_s - sum(split.values())
    print(
        f"Measured {dt.date.today().isoformat()} on {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"BLAS threads {blas}, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} before, "
        f"{os.getloadavg()[0]:.1f} after; median of {args.repeat} interleaved runs, CPU seconds.\n"
    )
    print("| driven by | decisions | agent-steps | CPU s | agent-steps/s | µs per decision |")
    print("|---|---|---|---|---|---|")
    print(
        f"| MissionParallelEnv | {decisions} | {agent_steps} | {env_s:.3f} | {agent_steps / env_s:,.0f} | "
        f"{1e6 * env_s / decisions:,.0f} |"
    )
    print(
        f"| guadal run (MissionRunner, CSVs) | {runner_steps} | {agent_steps} | {runner_s:.3f} | "
        f"{agent_steps / runner_s:,.0f} | {1e6 * runner_s / runner_steps:,.0f} |"
    )
    difference_s = statistics.median(difference_times)
    print(
        f"| MissionParallelEnv, credit=difference | {decisions} | {agent_steps} | {difference_s:.3f} | "
        f"{agent_steps / difference_s:,.0f} | {1e6 * difference_s / decisions:,.0f} |"
    )
    print(
        f"\nenv / runner speed: {runner_s / env_s:.2f}x; same trajectory: {'yes' if same else 'no'}; "
        f"difference credit costs {difference_s / env_s:.2f}x the team credit's time\n"
    )
    print("| part of an env step | µs per decision | share |")
    print("|---|---|---|")
    for k, v in split.items():
        print(f"| {k} | {1e6 * v / decisions:,.0f} | {100 * v / env_s:.0f}% |")


if __name__ == "__main__":
    main()

"""Train a small policy on the paper-scale lake with the cross-entropy method, export it to ONNX.

    python examples/rl/train.py                       # about five minutes on one CPU core
    python examples/rl/train.py --minutes 1 --out /tmp/policy.onnx

The mission is ``missions/lake_greedy.yaml`` (3 boats, 925 m each, GP model); the environment is
guadal's PettingZoo ``MissionParallelEnv`` with its default reward for ``gp`` (the fall of the
model's mean std at every step), so an episode's return is how much uncertainty the fleet removed.
The policy (``patch_policy.py``: 21 box features per direction, 4 hidden units, 93 weights) is
deterministic: the best valid action by score, exactly as the ``policy`` planner plays it.

The cross-entropy method needs only numpy: sample weight vectors around a Gaussian, play one
episode each (all on the same world in a generation), keep the best quarter, refit the Gaussian.
Writes the ONNX file, and ``.json`` beside it with the learning curve.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import onnx
from threadpoolctl import threadpool_limits

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

import patch_policy  # noqa: E402

from guadal_cli.rl import MissionParallelEnv  # noqa: E402


def episode_return(env: MissionParallelEnv, params: np.ndarray, hidden: int, seed: int, matrix) -> float:
    """The fleet's return (sum of the shared reward) playing ``params`` greedily on world ``seed``."""
    obs, infos = env.reset(seed=seed)
    total = 0.0
    while env.agents:
        agents = list(obs)
        scores = patch_policy.scores(params, np.stack([obs[a] for a in agents]), hidden, matrix)
        actions = {}
        for a, s in zip(agents, scores):
            s = np.where(infos[a]["action_mask"] > 0, s, -np.inf)
            actions[a] = int(np.argmax(s))
        obs, rewards, _, _, infos = env.step(actions)
        total += next(iter(rewards.values()), 0.0)
    return total


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission", default=str(ROOT / "missions" / "lake_greedy.yaml"))
    parser.add_argument("--out", default=str(HERE / "lake_policy.onnx"))
    parser.add_argument("--minutes", type=float, default=5.0, help="stop after this long")
    parser.add_argument("--generations", type=int, default=30)
    parser.add_argument("--population", type=int, default=24)
    parser.add_argument("--hidden", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--figure", help="also draw the learning curve to this PNG")
    args = parser.parse_args(argv)

    env = MissionParallelEnv(args.mission)
    channels = env.builder.shape[0]
    size = patch_policy.n_params(channels, args.hidden)
    matrix = patch_policy.box_matrix()
    rng = np.random.default_rng(args.seed)
    mean, std = np.zeros(size), np.ones(size)
    elite_n = max(2, args.population // 4)
    curve, best, best_params = [], -np.inf, mean
    start = time.monotonic()
    for generation in range(args.generations):
        world = int(rng.integers(2**31))
        candidates = mean + std * rng.standard_normal((args.population, size))
        candidates[0] = mean  # the current mean is always evaluated too
        returns = np.array([episode_return(env, c, args.hidden, world, matrix) for c in candidates])
        elite = candidates[np.argsort(returns)[-elite_n:]]
        mean, std = elite.mean(axis=0), elite.std(axis=0) + 0.02
        if returns.max() > best:
            best, best_params = float(returns.max()), candidates[int(np.argmax(returns))]
        curve.append({"generation": generation, "best": float(returns.max()), "mean": float(returns.mean())})
        elapsed = time.monotonic() - start
        print(
            f"generation {generation}: best {returns.max():.4f}  mean {returns.mean():.4f}  ({elapsed:.0f} s)"
        )
        if elapsed > args.minutes * 60:
            break
    # the final policy: the elite mean or the best candidate seen, whichever does better on fresh worlds
    check = [int(s) for s in rng.integers(2**31, size=3)]
    finalists = {"elite mean": mean, "best candidate": best_params}
    scores = {
        k: np.mean([episode_return(env, p, args.hidden, s, matrix) for s in check])
        for k, p in finalists.items()
    }
    chosen = max(scores, key=scores.get)
    params = finalists[chosen]
    print(f"exporting the {chosen} (return {scores[chosen]:.4f} on 3 fresh worlds)")
    metadata = {
        "mode": env.builder.mode,
        "fields": list(env.builder.fields),
        "layout": "image",
        "trained_on": Path(args.mission).name,
        "method": "cross-entropy method",
        "reward": env.reward_fn.name,
    }
    model = patch_policy.to_onnx(params, env.builder.shape, args.hidden, metadata)
    onnx.checker.check_model(model)
    onnx.save(model, args.out)
    Path(args.out).with_suffix(".json").write_text(
        json.dumps({"curve": curve, "hidden": args.hidden, "params": [float(x) for x in params]}, indent=1)
        + "\n"
    )
    print(f"wrote {args.out}")
    if args.figure:
        draw_curve(curve, args.population, args.figure)


def draw_curve(curve: list[dict], population: int, out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3), dpi=100)
    generations = [c["generation"] for c in curve]
    ax.plot(generations, [c["best"] for c in curve], label="best of generation")
    ax.plot(generations, [c["mean"] for c in curve], label="generation mean")
    ax.set_xlabel(f"generation ({population} episodes each)")
    ax.set_ylabel("return: mean std removed")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(out)


if __name__ == "__main__":
    with threadpool_limits(1):  # one core: the model updates run single-threaded too
        main()

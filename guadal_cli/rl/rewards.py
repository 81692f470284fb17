"""Rewards: the change of one task metric over a step, signed so that progress is positive.

Each environment has a default; any named reward works with any environment that reports its
metric. A callable ``reward(before, after) -> float`` over the two metric dicts works too.

==============  ===================  ====  =====================================
name            metric               sign  default for
==============  ===================  ====  =====================================
``uncertainty``  ``mean_std``         -     ``gp`` (the model's mean std falls)
``rmse``         ``rmse``             -     (gp with a ground truth)
``items``        ``items_collected``  +     ``trash``
``iou``          ``iou``              +     ``oil_spill``
``coverage``     ``detection_coverage`` +   (oil_spill)
==============  ===================  ====  =====================================

A metric that is NaN before or after (no ground truth, no slick yet) gives 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..errors import GuadalError

#: name -> (metric, sign)
REWARDS = {
    "uncertainty": ("mean_std", -1.0),
    "rmse": ("rmse", -1.0),
    "items": ("items_collected", 1.0),
    "iou": ("iou", 1.0),
    "coverage": ("detection_coverage", 1.0),
}
#: environment type -> its default reward
DEFAULTS = {"gp": "uncertainty", "trash": "items", "oil_spill": "iou"}


@dataclass(frozen=True)
class RewardConfig:
    """A resolved reward: ``scale * sign * (after[metric] - before[metric])``, or a callable's."""

    name: str
    metric: str | None = None
    sign: float = 1.0
    scale: float = 1.0
    function: Callable[[dict, dict], float] | None = None

    def __call__(self, before: dict, after: dict) -> float:
        if self.function is not None:
            value = float(self.function(before, after))
        else:
            value = self.sign * (float(after[self.metric]) - float(before[self.metric]))
        return self.scale * value if math.isfinite(value) else 0.0


def resolve_reward(
    reward, environment_type: str, metric_names: Sequence[str], scale: float = 1.0
) -> RewardConfig:
    """The reward named (or the environment's default when ``reward`` is None), checked against
    the metrics the environment reports."""
    if callable(reward):
        return RewardConfig(getattr(reward, "__name__", "callable"), scale=scale, function=reward)
    if reward is None:
        reward = DEFAULTS.get(environment_type) or next(
            (name for name, (metric, _) in REWARDS.items() if metric in metric_names), None
        )
        if reward is None:
            raise GuadalError(
                f"environment '{environment_type}' has no default reward; name one of "
                f"{', '.join(REWARDS)} or pass a function reward(before, after).",
                field="reward",
            )
    if reward not in REWARDS:
        raise GuadalError(f"unknown reward '{reward}'; known: {', '.join(REWARDS)}.", field="reward")
    metric, sign = REWARDS[reward]
    if metric not in metric_names:
        raise GuadalError(
            f"reward '{reward}' reads metric '{metric}', which environment '{environment_type}' does not "
            f"report (it reports: {', '.join(metric_names)}).",
            field="reward",
        )
    return RewardConfig(reward, metric, sign, scale)

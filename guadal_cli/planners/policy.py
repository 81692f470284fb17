"""``policy``: a trained policy (an ONNX file or ``module:function``) as a planner.

It builds the observation a policy was trained on with :mod:`guadal_cli.rl.observation` (the
module the training environments use), masks the actions that lead off the water or beyond the
budget, and takes the best one per vehicle: the highest score (ties go to the lowest action), or
with ``sample: true`` a draw from the scores' softmax, seeded by the mission. It reads only the
planner's observation, so it plays unchanged at ``sim``, ``sitl`` and ``real``.

The policy is loaded and called once on a blank observation when the mission is validated, so a
missing file, a wrong input shape or a missing onnxruntime is one sentence from
``guadal validate``, not an error halfway through a mission.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr

from ..envs.base import Observation
from ..errors import GuadalError
from ..rl.observation import ObservationBuilder, default_fields
from ..rl.policy import Policy, load_policy, resolve_source
from .base import SEQUENTIAL, TARGET, Planner


class PolicyConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    model: str = Field(
        min_length=1,
        description="The trained policy: an .onnx file (relative to the mission file) or 'module:function'.",
    )
    layout: Literal["image", "vector"] = Field(
        default="image",
        description="Observation layout a 'module:function' policy takes (ONNX: from its input).",
    )
    fields: tuple[str, str] | None = Field(
        default=None,
        description="The two model fields shown to the policy; default: the environment's (gp: mean, std).",
    )
    sample: bool = Field(
        default=False, description="Draw from the softmax of the scores (seeded) instead of taking the best."
    )
    _max_distance: float | None = PrivateAttr(default=None)


class PolicyPlanner(Planner):
    Config = PolicyConfig
    modes = (SEQUENTIAL, TARGET)

    @classmethod
    def for_mission(cls, config: PolicyConfig, *, mission, graph, mode, base_dir, provides) -> PolicyConfig:
        try:
            policy = load_policy(resolve_source(config.model, Path(base_dir)), config.layout)
        except GuadalError as exc:
            raise exc.within("model") from None
        meta = policy.metadata
        trained_mode = meta.get("mode")
        if trained_mode and trained_mode != mode:
            raise GuadalError(
                f"the policy was trained in {trained_mode} mode; set algorithm.mode: {trained_mode}.",
                field="mode",
            )
        fields = config.fields or tuple(meta.get("fields") or ()) or default_fields(provides)
        if len(fields) != 2 or not set(fields) <= set(provides):
            raise GuadalError(
                f"the policy reads fields {', '.join(fields)}, but the environment provides "
                f"{', '.join(sorted(provides)) or 'none'}.",
                field="fields",
            )
        resolved = config.model_copy(update={"model": policy.source, "fields": tuple(fields)})
        resolved._max_distance = float(mission.fleet.max_distance)
        builder = ObservationBuilder(
            graph, mission.fleet.vehicles, resolved._max_distance, mode, resolved.fields
        )
        _check_shapes(policy, builder, mission.fleet.vehicles)
        return resolved

    def reset(self, graph, n_vehicles: int, mode: str, seed: int) -> None:
        super().reset(graph, n_vehicles, mode, seed)
        cfg = self.config
        self.policy_: Policy = load_policy(resolve_source(cfg.model, Path.cwd()), cfg.layout)
        self.builder_: ObservationBuilder | None = None

    def _builder(self, observation: Observation) -> ObservationBuilder:
        if self.builder_ is None:
            budget = self.config._max_distance or max(observation.remaining.values())
            fields = self.config.fields or tuple(self.policy_.metadata.get("fields") or ()) or None
            self.builder_ = ObservationBuilder(self.graph_, self.n_vehicles_, budget, self.mode_, fields)
        return self.builder_

    def next_targets(self, observation: Observation) -> dict[int, int]:
        builder = self._builder(observation)
        vehicles = [v for v in sorted(observation.positions) if not observation.done.get(v)]
        if not vehicles:
            return {}
        images = builder.images(observation, vehicles)
        batch = images if self.policy_.layout == "image" else builder.vectors(images)
        scores = np.asarray(self.policy_(batch), dtype=np.float64)
        if scores.shape != (len(vehicles), builder.n_actions):
            raise GuadalError(
                f"the policy '{self.config.model}' returned scores of shape {scores.shape} for "
                f"{len(vehicles)} vehicles; expected ({len(vehicles)}, {builder.n_actions})."
            )
        masks = builder.action_masks(observation, vehicles).astype(bool)
        actions = {v: self._choose(s, m) for v, s, m in zip(vehicles, scores, masks)}
        targets, _ = builder.targets(observation, actions)
        return targets

    def _choose(self, scores: np.ndarray, mask: np.ndarray) -> int:
        scores = np.where(mask & np.isfinite(scores), scores, -np.inf)
        if not np.isfinite(scores).any():
            return int(np.argmax(mask))  # every score unusable: the first valid action (stay)
        if not self.config.sample:
            return int(np.argmax(scores))
        p = np.exp(scores - scores.max())
        return int(self.rng_.choice(len(p), p=p / p.sum()))


def _check_shapes(policy: Policy, builder: ObservationBuilder, n_vehicles: int) -> None:
    """The policy's input matches the mission's grid, and it answers a blank batch in shape."""
    expected = builder.shape if policy.layout == "image" else (builder.vector_size,)
    what = "(channels, rows, cols)" if policy.layout == "image" else "(size,)"
    if policy.input_shape is not None and any(
        want is not None and want != have for want, have in zip(policy.input_shape, expected)
    ):
        raise GuadalError(
            f"the policy '{Path(policy.source).name}' takes input {what} = {policy.input_shape}, but this "
            f"mission's map and observation give {expected}; train it on this map.",
            field="model",
        )
    try:
        scores = np.asarray(policy(np.zeros((n_vehicles, *expected), dtype=np.float32)))
    except GuadalError:
        raise
    except Exception as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise GuadalError(
            f"the policy failed on a blank {expected} observation ({type(exc).__name__}: {first}).",
            field="model",
        ) from exc
    if scores.shape != (n_vehicles, builder.n_actions):
        raise GuadalError(
            f"the policy returns scores of shape {scores.shape} for {n_vehicles} vehicles; a "
            f"{builder.mode}-mode policy returns ({n_vehicles}, {builder.n_actions}).",
            field="model",
        )

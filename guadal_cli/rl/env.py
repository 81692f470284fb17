"""PettingZoo and Gymnasium environments over a mission, driving :class:`~guadal_cli.episode.Episode`.

The mission's own rules (hops, shared-node conflicts, budgets, stop reasons) run in the Episode,
as in ``guadal run``; these classes only translate. Observations and actions are those of
:mod:`guadal_cli.rl.observation` (the ``policy`` planner uses the same), rewards those of
:mod:`guadal_cli.rl.rewards`.

- :class:`MissionParallelEnv` (PettingZoo ``ParallelEnv``): one agent per vehicle,
  ``boat_0`` ... Every live agent acts at every step; an agent whose vehicle cannot move any
  more (budget spent) terminates and leaves ``agents``; the episode ends for all when the
  Episode stops. With ``credit="team"`` (default) all agents share the fleet's reward (the
  team's progress this step); with ``credit="difference"`` each gets its difference reward: the
  fleet's reward less what it would have been without that agent's samples of the step.
- :class:`MissionEnv` (Gymnasium, ``gymnasium.make("guadal/Mission-v0", mission=...)``): the
  whole fleet as one agent, a ``MultiDiscrete`` action (one entry per vehicle).

**Invalid actions never raise.** The valid actions are in ``info["action_mask"]`` (and in the
observation with ``layout="dict"``); a vehicle given an invalid one (off the water, beyond its
budget, out of range, or refused by the Episode's rules) stays where it is and its agent gets
``-invalid_penalty`` on top of its reward.

**Seeds.** ``reset(seed=s)`` runs the mission with seed ``s`` (its ground truth and sensor
noise): the same seed gives the same observations and rewards. ``reset()`` without a seed
draws the next seed from a generator started at the mission's seed, so successive episodes see
different worlds, reproducibly.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path

import numpy as np

from ..errors import GuadalError
from .observation import LAYOUTS, ObservationBuilder
from .rewards import resolve_reward

try:
    import gymnasium
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as exc:  # pragma: no cover - the rl extra is part of the test extra
    raise ImportError(
        "guadal's RL environments need gymnasium and pettingzoo; install them with: pip install 'guadal[rl]'"
    ) from exc

#: vehicle v is agent "boat_v"
AGENT_PREFIX = "boat_"
#: how the fleet's reward is shared out (``credit=``): see :class:`MissionParallelEnv`
CREDITS = ("team", "difference")


def _prepared(mission, base_dir):
    """A prepared mission from a path, a dict (paths relative to ``base_dir``) or a Prepared."""
    from ..mission import Prepared, prepare_dict, read_mission_file

    if isinstance(mission, Prepared):
        return mission
    if isinstance(mission, dict):
        return prepare_dict(dict(mission), base_dir or Path.cwd(), check_output=False)
    if isinstance(mission, (str, Path)):
        path = Path(mission)
        return prepare_dict(read_mission_file(path), path.resolve().parent, path, check_output=False)
    raise GuadalError(
        f"mission must be a mission file's path, a mission dict or a prepared mission, not {type(mission).__name__}."
    )


class MissionParallelEnv(ParallelEnv):
    """A mission as a PettingZoo parallel environment (see the module docstring).

    ``layout``: ``image`` (C, rows, cols), ``vector`` (the water nodes of every channel but water)
    or ``dict`` (``{"observation": image, "action_mask": int8}``). ``reward``: a name from
    :data:`~guadal_cli.rl.rewards.REWARDS`, a function ``(before, after) -> float`` of the metric
    dicts, or None for the environment's default. ``fields``: the two model fields shown.

    ``credit``: ``team`` gives every agent the fleet's reward. ``difference`` gives each its
    difference reward, ``R(all samples) - R(all but its own)`` over the step: the world is copied
    before the step and the step's model updates replayed on the copy without the agent's
    samples, so an agent is paid for what it added, not for its teammates' work (an agent that
    took no sample gets 0). It costs a copy of the environment and a replayed update per
    sampling agent per step.
    """

    metadata = {
        "name": "guadal_mission_v0",
        "render_modes": ["rgb_array"],
        "render_fps": 4,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        mission,
        *,
        base_dir=None,
        layout: str = "image",
        reward=None,
        reward_scale: float = 1.0,
        invalid_penalty: float = 0.01,
        credit: str = "team",
        fields: tuple[str, str] | None = None,
        render_mode: str | None = None,
    ):
        from ..episode import Episode

        if credit not in CREDITS:
            raise GuadalError(f"credit must be one of {', '.join(CREDITS)}, not '{credit}'.", field="credit")
        if layout not in LAYOUTS:
            raise GuadalError(f"layout must be one of {', '.join(LAYOUTS)}, not '{layout}'.", field="layout")
        if render_mode not in (None, "rgb_array"):
            raise GuadalError(f"render_mode must be None or 'rgb_array', not '{render_mode}'.")
        self.prep = _prepared(mission, base_dir)
        prep = self.prep
        self.episode = Episode(prep, invalid_targets="stay")
        self.n_vehicles = prep.mission.fleet.vehicles
        self.builder = ObservationBuilder(
            prep.graph,
            self.n_vehicles,
            prep.mission.fleet.max_distance,
            prep.mode,
            tuple(fields) if fields else None,
        )
        if self.builder.fields is None:
            from .observation import default_fields

            self.builder.fields = default_fields(prep.environment_cls.provides)
        self.reward_fn = resolve_reward(
            reward, prep.mission.environment.type, prep.environment_cls.metric_names, reward_scale
        )
        self.layout = layout
        self.invalid_penalty = float(invalid_penalty)
        self.credit = credit
        self.render_mode = render_mode
        self.possible_agents = [f"{AGENT_PREFIX}{v}" for v in range(self.n_vehicles)]
        self.agents: list[str] = []
        self._seeds = np.random.default_rng(prep.mission.seed)
        self._observation = None

    # --- spaces ----------------------------------------------------------------------------
    @functools.cache  # noqa: B019 - one env, a handful of agents
    def observation_space(self, agent: str) -> spaces.Space:
        b = self.builder
        if self.layout == "vector":
            return spaces.Box(0.0, 1.0, (b.vector_size,), np.float32)
        image = spaces.Box(0.0, 1.0, b.shape, np.float32)
        if self.layout == "image":
            return image
        return spaces.Dict({"observation": image, "action_mask": spaces.Box(0, 1, (b.n_actions,), np.int8)})

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(self.builder.n_actions)

    @staticmethod
    def vehicle(agent: str) -> int:
        return int(agent[len(AGENT_PREFIX) :])

    # --- the loop --------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._seeds = np.random.default_rng(seed)
            episode_seed = int(seed)
        else:
            episode_seed = int(self._seeds.integers(2**31))
        self._observation = self.episode.reset(seed=episode_seed)
        self.agents = [a for a in self.possible_agents if not self._observation.done.get(self.vehicle(a))]
        self._metrics = self.episode.environment.metrics()
        self._masks = self._masks_of(self.agents)
        return self._observe(self.agents), self._infos(self.agents)

    def step(self, actions: dict):
        obs = self._observation
        live = [a for a in self.agents if a in actions]
        chosen = {self.vehicle(a): _as_action(actions[a]) for a in live}
        masks = np.stack([self._masks[v] for v in chosen]) if chosen else None
        targets, invalid = self.builder.targets(obs, chosen, masks)
        log = _EnvironmentLog(self.episode) if self.credit == "difference" else None
        try:
            obs, measured, terminated, truncated, info = self.episode.step(targets)
        finally:
            if log is not None:
                log.detach()
        # the Episode's refusals (under None: the whole decision), though the env sends only valid ones
        invalid.update({v: why for v, why in info.get("invalid", {}).items() if v is not None})
        self._observation = obs
        metrics = self.episode.environment.metrics()
        shared = self.reward_fn(self._metrics, metrics)
        own = {}
        if log is not None:
            sampled = {m.vehicle for m in measured}
            for a in self.agents:
                v = self.vehicle(a)
                without = log.replay_without(v) if v in sampled else metrics
                own[v] = shared - self.reward_fn(self._metrics, without)
        self._metrics = metrics
        self.last_reward, self.last_invalid = shared, invalid  # the fleet's, before penalties
        rewards = {
            a: own.get(self.vehicle(a), shared)
            - (self.invalid_penalty if self.vehicle(a) in invalid else 0.0)
            for a in self.agents
        }
        terminations = {a: bool(terminated or obs.done.get(self.vehicle(a))) for a in self.agents}
        truncations = {a: bool(truncated) for a in self.agents}
        self._masks = self._masks_of(self.agents)
        infos = self._infos(self.agents, info, invalid)
        for a in self.agents:
            infos[a]["team_reward"] = shared
        observations = self._observe(self.agents)
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos

    def _observe(self, agents: list[str]) -> dict:
        vehicles = [self.vehicle(a) for a in agents]
        if not vehicles:
            return {}
        images = self.builder.images(self._observation, vehicles)
        if self.layout == "vector":
            values = self.builder.vectors(images)
        elif self.layout == "dict":
            values = [{"observation": img, "action_mask": self._masks[v]} for img, v in zip(images, vehicles)]
        else:
            values = images
        return dict(zip(agents, values))

    def _masks_of(self, agents: list[str]) -> dict[int, np.ndarray]:
        """Each agent's action mask in the current state (by vehicle), computed once per step."""
        vehicles = [self.vehicle(a) for a in agents]
        if not vehicles:
            return {}
        return dict(zip(vehicles, self.builder.action_masks(self._observation, vehicles)))

    def _infos(self, agents: list[str], info: dict | None = None, invalid: dict | None = None) -> dict:
        out = {}
        for a in agents:
            v = self.vehicle(a)
            out[a] = {"action_mask": self._masks[v]}
            if info is not None:
                out[a]["stop_reason"] = info.get("stop_reason", "")
            if invalid and v in invalid:
                out[a]["invalid"] = invalid[v]
        return out

    def action_masks(self) -> dict:
        """The valid actions of every live agent (what ``info["action_mask"]`` holds)."""
        return {a: self._masks[self.vehicle(a)] for a in self.agents}

    def state(self) -> np.ndarray:
        """Every vehicle's image stacked: the global state, for centralised critics."""
        return self.builder.images(self._observation)

    def render(self):
        if self.render_mode != "rgb_array" or self._observation is None:
            return None
        return render_rgb(self.builder, self._observation)

    def close(self) -> None:
        self.episode.close()


class _EnvironmentLog:
    """One step of an Episode's environment, copied before and its calls kept, for difference
    rewards: the step replayed on a fresh copy of the world without one vehicle's samples.

    The Episode drives ``advance`` (an evolving world's clock) and ``update`` (samples into the
    model); both are recorded in order and passed on. Sensing is not replayed: the other
    vehicles' samples keep their values. The graph is shared, not copied (it never changes).
    """

    def __init__(self, episode):
        self._episode = episode
        self.environment = episode.environment
        self._before = self._copy(self.environment)
        self.calls: list[tuple[str, object]] = []
        episode.environment = self

    def _copy(self, environment):
        return copy.deepcopy(environment, {id(environment.graph): environment.graph})

    def advance(self, time_s: float) -> None:
        self.calls.append(("advance", time_s))
        self.environment.advance(time_s)

    def update(self, measurements) -> None:
        measurements = list(measurements)
        self.calls.append(("update", measurements))
        self.environment.update(measurements)

    def __getattr__(self, name):  # everything else is the environment's own
        return getattr(self.environment, name)

    def detach(self) -> None:
        self._episode.environment = self.environment

    def replay_without(self, vehicle: int) -> dict:
        """The metrics the step would have ended with had ``vehicle`` taken no sample."""
        world = self._copy(self._before)
        for name, argument in self.calls:
            if name == "advance":
                world.advance(argument)
            else:
                world.update([m for m in argument if m.vehicle != vehicle])
        return world.metrics()


def _as_action(value) -> int:
    """An action as an int; anything that is not one whole number reads -1 (an invalid action)."""
    try:
        array = np.asarray(value)
        if array.size != 1 or array.dtype.kind not in "biuf":
            return -1
        number = array.reshape(-1)[0]
        return int(number) if float(number).is_integer() else -1
    except (TypeError, ValueError, OverflowError):
        return -1


def render_rgb(builder: ObservationBuilder, observation, cell: int = 8) -> np.ndarray:
    """The lake as an RGB array: land grey, water shaded by the second field (gp: std, dark =
    certain), visited cells tinted green, vehicles red."""
    image = builder.images(observation, [0])[0] if observation.positions else None
    h, w = builder.height, builder.width
    rgb = np.full((h, w, 3), 120, dtype=np.uint8)
    water = builder.water.reshape(h, w) > 0
    field = image[3] if image is not None else np.zeros((h, w))
    rgb[water] = np.stack([30 + 60 * field[water], 60 + 100 * field[water], 120 + 135 * field[water]], -1)
    rgb[(image[4] > 0) & water] = (rgb[(image[4] > 0) & water] * 0.6 + np.array([0, 102, 0])).astype(np.uint8)
    for node in observation.positions.values():
        rgb[builder.graph.rows[node], builder.graph.cols[node]] = (220, 30, 30)
    return np.kron(rgb, np.ones((cell, cell, 1), dtype=np.uint8))


class MissionEnv(gymnasium.Env):
    """The whole fleet as one Gymnasium agent: a ``MultiDiscrete`` action, one entry per vehicle.

    Observations stack every vehicle's (``(vehicles, ...)``); the reward is the fleet's, less
    ``invalid_penalty`` per vehicle given an invalid action; the episode terminates when the
    Episode stops. ``info["action_mask"]`` is ``(vehicles, n_actions)`` (a finished vehicle:
    only its first action, which it ignores). Keyword arguments as :class:`MissionParallelEnv`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, mission, render_mode: str | None = None, **kwargs):
        if kwargs.get("credit", "team") != "team":
            raise GuadalError(
                "credit shares the reward out among PettingZoo's agents; the Gymnasium env has one "
                "agent, the fleet, and its reward is the fleet's: leave credit out or use "
                "MissionParallelEnv.",
                field="credit",
            )
        self.parallel = MissionParallelEnv(mission, render_mode=render_mode, **kwargs)
        p = self.parallel
        self.render_mode = render_mode
        n, b = p.n_vehicles, p.builder
        if p.layout == "vector":
            self.observation_space = spaces.Box(0.0, 1.0, (n, b.vector_size), np.float32)
        else:
            image = spaces.Box(0.0, 1.0, (n, *b.shape), np.float32)
            self.observation_space = (
                image
                if p.layout == "image"
                else spaces.Dict(
                    {"observation": image, "action_mask": spaces.Box(0, 1, (n, b.n_actions), np.int8)}
                )
            )
        self.action_space = spaces.MultiDiscrete([b.n_actions] * n)

    def _obs_and_info(self, stop_reason: str | None = None, invalid: dict | None = None):
        p = self.parallel
        observation = p._observation
        images = p.builder.images(observation)
        masks = np.zeros((p.n_vehicles, p.builder.n_actions), dtype=np.int8)
        live = {p.vehicle(a) for a in p.agents}
        for v in range(p.n_vehicles):
            if v in live:
                masks[v] = p._masks[v]
            else:  # a finished boat: only its "stay" action, which it ignores anyway
                masks[v, 0 if p.builder.mode == "sequential" else observation.positions[v]] = 1
        if p.layout == "vector":
            obs = p.builder.vectors(images)
        elif p.layout == "dict":
            obs = {"observation": images, "action_mask": masks}
        else:
            obs = images
        out = {"action_mask": masks}
        if stop_reason is not None:
            out.update(stop_reason=stop_reason, invalid=dict(invalid or {}))
        return obs, out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.parallel.reset(seed=seed, options=options)
        return self._obs_and_info()

    def step(self, action):
        p = self.parallel
        action = np.asarray(action).reshape(-1)
        actions = {a: int(action[p.vehicle(a)]) if p.vehicle(a) < len(action) else -1 for a in p.agents}
        _, _, terms, truncs, infos = p.step(actions)
        reward = float(p.last_reward - p.invalid_penalty * len(p.last_invalid))
        stop = next((i.get("stop_reason", "") for i in infos.values()), "")
        truncated = any(truncs.values())
        terminated = not p.agents and not truncated
        obs, info = self._obs_and_info(stop, p.last_invalid)
        return obs, reward, terminated, truncated, info

    def render(self):
        return self.parallel.render()

    def close(self):
        self.parallel.close()

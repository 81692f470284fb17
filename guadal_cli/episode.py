"""The mission loop as a value: ``reset`` places the fleet, ``step`` carries out one decision.

An :class:`Episode` owns every rule between a planner's decision and the fleet: targets checked,
hops along shortest water paths (``target`` mode) or to a neighbour (``sequential`` mode),
shared-node conflicts (the lower id goes first; the others wait, then detour, then give up),
budgets, the model updated when the mode says so, and the reasons a mission stops. The CLI
runner, the RL environments, sweeps and resume all drive it, so none re-implements the rules::

    ep = Episode(prep)
    obs = ep.reset()
    while not ep.stop_reason:
        obs, measurements, terminated, truncated, info = ep.step(planner.next_targets(obs))

It writes nothing, installs no signal handler and holds no planner: the caller decides where
steps go (``on_hop``) and what may interrupt them (``before_hop``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from .envs.base import Observation
from .errors import GuadalError
from .fleet.base import Fleet, Measurement
from .mission import Prepared, mission_seeds
from .planners.base import SEQUENTIAL

#: hops a vehicle may wait for a blocked node before it looks for another way round
WAIT_BEFORE_REROUTE = 2
#: hops after which a blocked target is given up
WAIT_BEFORE_GIVING_UP = 6
#: decisions in a row that move nobody before the episode ends
IDLE_DECISIONS_BEFORE_STOP = 3

#: how :meth:`Episode.step` treats a target it cannot follow
INVALID_TARGETS = ("raise", "stay")


class CoverageTracker:
    """Fraction of nodes within a radius of at least one sample."""

    def __init__(self, graph, radius_m: float):
        self.graph = graph
        self.radius = radius_m
        self.covered = np.zeros(graph.n_nodes, dtype=bool)
        self._seen: set[int] = set()
        self._value: float | None = 0.0

    def add(self, node: int) -> None:
        if node not in self._seen:
            self._seen.add(node)
            self.covered[self.graph.nodes_within(node, self.radius)] = True
            self._value = None

    @property
    def value(self) -> float:
        if self._value is None:  # covered nodes / nodes: what covered.mean() gives, to the bit
            self._value = np.count_nonzero(self.covered) / self.covered.size
        return self._value


class Episode:
    """One mission on one fleet, advanced one planner decision at a time.

    ``fleet`` defaults to the one the mission's backend builds (a ``LocalFleet`` at ``sim``);
    the episode closes only a fleet it built (:meth:`close`). ``on_hop(ep, fleet, measurements)``
    runs after every hop (one graph edge, one step), ``before_hop(ep, fleet)`` before each, where
    :meth:`hold` may keep a vehicle in place, and ``on_decision(ep, fleet, targets)`` once per
    decision that sends a vehicle somewhere, with the targets it will follow. ``invalid_targets``
    is ``"raise"`` (a bad target is a :class:`GuadalError`) or ``"stay"`` (that vehicle stays;
    the reason is in ``info``).
    """

    def __init__(
        self,
        prep: Prepared,
        fleet: Fleet | None = None,
        *,
        on_hop: Callable[[Episode, Fleet, list[Measurement]], None] | None = None,
        before_hop: Callable[[Episode, Fleet], None] | None = None,
        on_decision: Callable[[Episode, Fleet, dict[int, int]], None] | None = None,
        invalid_targets: str = "raise",
    ):
        if invalid_targets not in INVALID_TARGETS:
            raise GuadalError(
                f"invalid_targets must be one of {', '.join(INVALID_TARGETS)}, not {invalid_targets!r}."
            )
        mission = prep.mission
        self.prep = prep
        self.graph = prep.graph
        self.environment = prep.environment
        self.mode = prep.mode
        self.n_vehicles = mission.fleet.vehicles
        self.max_steps = mission.max_steps
        self.allow_shared = mission.fleet.allow_shared_nodes
        self.on_hop = on_hop
        self.before_hop = before_hop
        self.on_decision = on_decision
        self.invalid_targets = invalid_targets
        self._owns_fleet = fleet is None
        if fleet is None:
            backend = prep.backend_cls(prep.backend_config)
            fleet = backend.make_fleet(
                graph=self.graph, fleet_config=mission.fleet, sensor=self.environment.sense, mission=prep
            )
        self.fleet = fleet
        self._clear(mission.seed)

    def _clear(self, seed: int) -> None:
        self.seed = seed
        self.environment_seed, self.planner_seed = mission_seeds(seed)
        self.step_count = 0
        self.samples = 0
        self.visits = np.zeros(self.graph.n_nodes, dtype=int)
        self._coverage = CoverageTracker(self.graph, self.prep.mission.output.coverage_radius)
        self.done = {v: False for v in range(self.n_vehicles)}
        self.stop_reason = ""
        self.truncated = False
        self.last_measurements: list[Measurement] = []
        self._idle = 0
        self._paths: dict[int, list[int]] = {}
        self._fields: tuple | None = None  # (fields, task, visits) of the current state

    # --- state ---------------------------------------------------------------------------------
    @property
    def coverage(self) -> float:
        """Fraction of nodes within ``output.coverage_radius`` of a sample."""
        return self._coverage.value

    @property
    def covered(self) -> np.ndarray:
        """Per node: within ``output.coverage_radius`` of a sample (read it, do not change it)."""
        return self._coverage.covered

    @property
    def terminated(self) -> bool:
        return bool(self.stop_reason) and not self.truncated

    def observation(self) -> Observation:
        """What a planner may look at now. Model fields are built once per state, however often
        this is called between two hops."""
        fleet = self.fleet
        if self._fields is None:
            self._fields = (
                self.environment.observation_fields(),
                self.environment.task_state(),
                self.visits.copy(),
            )
        fields, task, visits = self._fields
        lost = fleet.lost  # out of the mission (a boat that did not answer when a run resumed, ...)
        return Observation(
            step=self.step_count,
            time_s=fleet.mission_time,
            graph=self.graph,
            positions=dict(fleet.positions),
            remaining=fleet.remaining(),
            done={v: d or v in lost for v, d in self.done.items()},
            visits=visits,
            fields=fields,
            task=task,
        )

    def hold(self, vehicle: int) -> None:
        """Keep ``vehicle`` where it is for the rest of the current decision (an operator's hold)."""
        if vehicle in self._paths:
            self._paths[vehicle] = []

    def close(self) -> None:
        """Close the fleet if this episode built it (a fleet passed in belongs to the caller)."""
        if self._owns_fleet:
            self.fleet.close()

    def __enter__(self) -> Episode:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- reset and step --------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> Observation:
        """Start again: the world drawn from ``seed`` (a mission seed; None: the mission's own),
        the fleet at its initial nodes, the first measurement taken and folded into the model.

        ``planner_seed`` then holds the seed a planner should be reset with for this world.
        """
        self._clear(self.prep.mission.seed if seed is None else int(seed))
        self.environment.reset(self.environment_seed)
        self.fleet.reset(self.prep.initial_nodes)
        first = self.fleet.take_measurement()
        self.environment.update(first)
        self._count(first)
        self.last_measurements = first
        return self.observation()

    def step(self, targets: Mapping[int, int]) -> tuple[Observation, list[Measurement], bool, bool, dict]:
        """Carry out one planner decision ``{vehicle: node}``; a vehicle left out stays idle.

        Sequential mode: each target is a neighbour, one hop. Target mode: each vehicle walks
        the shortest water path to its target, measuring at every node; the model is updated
        once all have arrived. Returns ``(observation, measurements, terminated, truncated,
        info)``; ``info`` holds ``stop_reason``, ``invalid`` (vehicle -> sentence, with
        ``invalid_targets="stay"``), ``hops`` (steps taken), ``moved`` (vehicles that moved) and
        ``targets`` (the targets followed). After the episode ended, a step does nothing.
        """
        measurements: list[Measurement] = []
        info: dict = {"stop_reason": self.stop_reason, "invalid": {}, "hops": 0, "moved": [], "targets": {}}
        if self.stop_reason:
            return self.observation(), measurements, self.terminated, self.truncated, info
        fleet = self.fleet
        positions = fleet.positions
        clean = self._check_targets(targets, positions, info["invalid"])
        lost = fleet.lost
        targets = {v: t for v, t in clean.items() if not self.done[v] and v not in lost and t != positions[v]}
        info["targets"] = targets
        if targets and self.on_decision is not None:
            self.on_decision(self, fleet, targets)
        step_before = self.step_count
        if self.mode == SEQUENTIAL:
            self._paths = {v: [t] for v, t in targets.items()}  # neighbours: no path search
        else:
            self._paths = {v: self.graph.shortest_path(positions[v], t)[1:] for v, t in targets.items()}
        paths = self._paths
        pending: list[Measurement] = []
        waits: dict[int, int] = {}
        moved_any: set[int] = set()
        while any(paths.values()) and self.step_count < self.max_steps:
            if self.before_hop is not None:
                self.before_hop(self, fleet)
            hops = self._next_hops(paths, positions, waits)
            if not hops:
                if not any(paths.values()):
                    break
                continue  # only waiting vehicles this round: their counters advanced
            reached = {v: False for v in hops}
            while not all(reached.values()):
                reached, done = fleet.move(hops)
                reached = {v: reached.get(v, False) or done.get(v, False) for v in hops}
            self.done = done
            positions = fleet.positions
            moved = [v for v, node in hops.items() if positions[v] == node]
            for v in hops:
                if v in moved:
                    paths[v].pop(0)
                    waits.pop(v, None)
                else:
                    paths[v] = []  # the vehicle could not make the hop (budget, failsafe)
            moved_any.update(moved)
            self.step_count += 1
            self.environment.advance(fleet.mission_time)
            hop_measurements = fleet.take_measurement(moved)
            if self.mode == SEQUENTIAL:
                self.environment.update(hop_measurements)
            else:
                pending.extend(hop_measurements)
                if not any(paths.values()):
                    self.environment.update(pending)
                    pending = []
            self._count(hop_measurements)
            measurements.extend(hop_measurements)
            self.last_measurements = hop_measurements
            if self.on_hop is not None:
                self.on_hop(self, fleet, hop_measurements)
        if pending:
            self.environment.update(pending)
            self._fields = None
        self._paths = {}
        self._idle = self._idle + 1 if self.step_count == step_before else 0
        self._check_stop()
        info.update(stop_reason=self.stop_reason, hops=self.step_count - step_before, moved=sorted(moved_any))
        return self.observation(), measurements, self.terminated, self.truncated, info

    def _count(self, measurements: list[Measurement]) -> None:
        """Samples, visits and coverage of one hop's measurements."""
        for m in measurements:
            self._coverage.add(m.node)
            self.visits[m.node] += 1
        self.samples += len(measurements)
        self._fields = None

    def _check_stop(self) -> None:
        if self.step_count >= self.max_steps:
            self.stop_reason, self.truncated = "max_steps reached", True
        elif all(self.done.values()):
            lost = self.fleet.lost
            if len(lost) == self.n_vehicles:
                self.stop_reason = "every vehicle was lost: " + " ".join(lost.values())
            else:
                self.stop_reason = "every vehicle spent its budget"
        elif self._idle >= IDLE_DECISIONS_BEFORE_STOP:
            self.stop_reason = f"the algorithm's last {self._idle} decisions moved no vehicle"

    # --- the rules -------------------------------------------------------------------------------
    def _check_targets(self, targets, positions: dict[int, int], invalid: dict) -> dict[int, int]:
        """The targets as ``{int: int}``; a bad one raises, or with ``invalid_targets="stay"``
        is left out with its reason in ``invalid`` (under None when ``targets`` is no mapping)."""
        if not isinstance(targets, Mapping):
            problem = (
                f"algorithm '{self.prep.mission.algorithm.type}' returned {type(targets).__name__}; "
                "targets are a mapping {vehicle: node}."
            )
            if self.invalid_targets == "raise":
                raise GuadalError(problem)
            invalid[None] = problem  # every vehicle stays
            return {}
        clean = {}
        for v, node in targets.items():
            problem = self._target_problem(v, node, positions)
            if problem is None:
                clean[int(v)] = int(node)
            elif self.invalid_targets == "raise":
                raise GuadalError(problem)
            else:
                invalid[v] = problem
        return clean

    def _target_problem(self, v, node, positions: dict[int, int]) -> str | None:
        name = self.prep.mission.algorithm.type
        n = self.n_vehicles
        if not (isinstance(v, (int, np.integer)) and 0 <= int(v) < n):
            return f"algorithm '{name}' named vehicle {v!r}; vehicles are 0..{n - 1}."
        if not (isinstance(node, (int, np.integer)) and 0 <= int(node) < self.graph.n_nodes):
            return (
                f"algorithm '{name}' sent vehicle {v} to {node!r}, which is not a node id "
                f"(0..{self.graph.n_nodes - 1})."
            )
        v, node = int(v), int(node)
        here = positions[v]
        if self.mode == SEQUENTIAL and node != here and node not in self.graph.neighbors(here):
            return (
                f"algorithm '{name}' sent vehicle {v} from node {here} to node {node} in sequential mode, "
                "where targets must be neighbours."
            )
        if not self.graph.same_component([here, node]):
            return f"algorithm '{name}' sent vehicle {v} to node {node}, which cannot be reached over water."
        return None

    def _next_hops(
        self, paths: dict[int, list[int]], positions: dict[int, int], waits: dict[int, int]
    ) -> dict[int, int]:
        """One edge per vehicle with a path, resolving conflicts: the lower id goes first."""
        remaining = self.fleet.remaining()
        for v in list(paths):
            if paths[v] and self.graph.edge_length(positions[v], paths[v][0]) > remaining[v] + 1e-9:
                paths[v] = []  # the budget does not reach the next node
        moving = {v: p[0] for v, p in paths.items() if p}
        if self.allow_shared:
            return moving
        n = self.n_vehicles
        while True:
            dest = {v: moving.get(v, positions[v]) for v in range(n)}
            blocked = None
            for v in sorted(moving):
                others = [u for u in range(n) if u != v and dest[u] == dest[v]]
                if others:
                    blocked = v if any(u < v or u not in moving for u in others) else None
                if blocked is not None:
                    break
            if blocked is None:
                return moving
            del moving[blocked]
            waits[blocked] = waits.get(blocked, 0) + 1
            self._after_block(blocked, paths, positions, waits)

    def _after_block(self, v: int, paths, positions, waits) -> None:
        if waits[v] >= WAIT_BEFORE_GIVING_UP:
            paths[v] = []
        elif waits[v] >= WAIT_BEFORE_REROUTE and paths[v]:
            others = {positions[u] for u in range(self.n_vehicles) if u != v}
            detour = self.graph.shortest_path(positions[v], paths[v][-1], avoid=others)
            if len(detour) > 1:
                paths[v] = detour[1:]

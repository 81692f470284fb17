"""The mission loop: planner -> fleet -> measurements -> environment -> run directory.

The runner drives every fleet one hop (one graph edge) at a time. In ``target`` mode it walks
each vehicle along the shortest water path to its target, measuring at every node, and updates
the model when all have arrived; in ``sequential`` mode targets are neighbours and the model is
updated after every hop. Because hops, collision rules and budgets live here, a local and a
remote fleet see exactly the same sequence of nodes.
"""

from __future__ import annotations

import datetime as _dt
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import plugins
from .controls import FleetInbox, MissionAborted, OperatorControls
from .envs.base import Observation
from .errors import GuadalError
from .fleet.base import Fleet, Measurement
from .fleet.status import StatusSampler
from .mission import Prepared
from .planners.base import SEQUENTIAL
from .records import RunRecorder, file_sha256
from .resume import ReplayFleet, read_record

#: live viewers get the model's maps at most this often (wall clock; the CSVs do not depend on it)
_SHARE_FIELDS_EVERY_S = 1.0
#: steps a vehicle may wait for a blocked node before it looks for another way round
_WAIT_BEFORE_REROUTE = 2
#: steps after which a blocked target is given up
_WAIT_BEFORE_GIVING_UP = 6
#: decisions in a row that move nobody (targets blocked for good) before the mission ends
_IDLE_DECISIONS_BEFORE_STOP = 3


@dataclass
class RunResult:
    directory: Path
    status: str
    steps: int
    final_metrics: dict


class CoverageTracker:
    """Fraction of nodes within a radius of at least one sample."""

    def __init__(self, graph, radius_m: float):
        self.graph = graph
        self.radius = radius_m
        self.covered = np.zeros(graph.n_nodes, dtype=bool)
        self._seen: set[int] = set()

    def add(self, node: int) -> None:
        if node not in self._seen:
            self._seen.add(node)
            self.covered[self.graph.nodes_within(node, self.radius)] = True

    @property
    def value(self) -> float:
        return float(self.covered.mean())


def metric_columns(n_vehicles: int, env_metrics) -> list[str]:
    return (
        ["step", "time_s"]
        + [f"distance_v{i}" for i in range(n_vehicles)]
        + ["total_distance", "samples", "coverage"]
        + list(env_metrics)
    )


def default_run_dir(prep: Prepared) -> Path:
    parent = Path(prep.mission.output.directory)
    if not parent.is_absolute():
        parent = (prep.base_dir / parent).resolve()
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    candidate = parent / f"{prep.mission.name}-seed{prep.mission.seed}-{stamp}"
    i = 1
    while candidate.exists():
        i += 1
        candidate = parent / f"{prep.mission.name}-seed{prep.mission.seed}-{stamp}-{i}"
    return candidate


class MissionRunner:
    """Composes the plugins of a prepared mission and runs it into a run directory."""

    def __init__(
        self,
        prep: Prepared,
        output: Path | None = None,
        on_step: Callable[[int, Fleet], None] | None = None,
        resume: bool = False,
        database: str | None = None,
    ):
        """``resume``: ``output`` is an interrupted run of this mission; replay it and go on."""
        from .db.engine import resolve_url

        self.prep = prep
        self.resume = resume
        self.mission = prep.mission
        self.graph = prep.graph
        self.output = Path(output) if output else default_run_dir(prep)
        self.on_step = on_step or (lambda step, fleet: None)
        self.database = resolve_url(database, prep.mission.output.database, runs_dir=self.output.parent)
        self.environment = prep.environment
        self.planner = prep.algorithm_cls(prep.algorithm_config)
        self.planner.reset(self.graph, self.mission.fleet.vehicles, prep.mode, prep.planner_seed)
        self.backend = prep.backend_cls(prep.backend_config)
        self.n = self.mission.fleet.vehicles
        self.allow_shared = self.mission.fleet.allow_shared_nodes
        self.coverage = CoverageTracker(self.graph, self.mission.output.coverage_radius)
        self.visits = np.zeros(self.graph.n_nodes, dtype=int)
        self.samples = 0
        self.step = 0
        self.stop_reason = ""
        self._share_fields_at = 0.0
        self.status = StatusSampler()

    # --- bookkeeping -----------------------------------------------------------------------
    def _manifest(self) -> dict:
        from .db.engine import redact

        prep = self.prep
        gt = getattr(prep.environment_config, "ground_truth", None)
        plugin_info = {
            "environment": plugins.describe("environment", self.mission.environment.type),
            "algorithm": plugins.describe("algorithm", self.mission.algorithm.type),
            "backend": plugins.describe("backend", self.mission.backend.level),
        }
        if isinstance(gt, dict) and "type" in gt:
            plugin_info["ground_truth"] = plugins.describe("ground_truth", gt["type"])
        return {
            "name": self.mission.name,
            "seed": self.mission.seed,
            "level": self.mission.backend.level,
            "mode": prep.mode,
            "vehicles": self.n,
            "mission_file": str(prep.path),
            "mission_dir": str(prep.base_dir),
            "map": {
                "path": str(prep.map.source),
                "name": prep.map.name,
                **prep.map.summary(),
                "sha256": file_sha256(prep.map.source) if prep.map.source else None,
            },
            "plugins": plugin_info,
            "database": redact(self.database),
        }

    def _record(self, fleet: Fleet, measurements: list[Measurement]) -> None:
        for m in measurements:
            self.coverage.add(m.node)
            self.visits[m.node] += 1
        self.samples += len(measurements)
        dist = fleet.distances
        row = {"step": self.step, "time_s": fleet.mission_time}
        row.update({f"distance_v{v}": dist[v] for v in range(self.n)})
        row.update(total_distance=sum(dist.values()), samples=self.samples, coverage=self.coverage.value)
        row.update(self.environment.metrics())
        g = self.graph
        traj = [
            (
                self.step,
                v,
                node,
                g.rows[node],
                g.cols[node],
                g.lat[node],
                g.lon[node],
                dist[v],
                "plan",
                fleet.mission_time,
            )
            for v, node in sorted(fleet.positions.items())
        ]
        meas = [(self.step, m.vehicle, m.node, m.lat, m.lon, m.value, m.time_s) for m in measurements]
        self._record_status(fleet)
        self.recorder.write_step(self.step, row, traj, meas)
        track = fleet.track_rows()
        if track:
            self.recorder.write_track(
                self.step,
                [
                    (self.step, r["vehicle"], "", "", "", r["lat"], r["lon"], "", "gps", r["time_s"])
                    for r in track
                ],
            )
        self.last_metrics = row
        if self.recorder.sinks and time.monotonic() >= self._share_fields_at:
            self._share_fields_at = time.monotonic() + _SHARE_FIELDS_EVERY_S
            self.recorder.share_fields(self.step, self.environment.observation_fields())
        self.on_step(self.step, fleet)

    def _record_status(self, fleet: Fleet) -> None:
        """The boats' state, when due: after every hop, and while a remote fleet waits for one."""
        self.recorder.write_vehicles(self.step, self.status.rows(self.step, fleet))

    def _record_targets(self, targets: dict[int, int], fleet: Fleet) -> None:
        """One decision: where each vehicle is sent, labelled with the step of its first hop (a lost
        vehicle is sent nowhere, whatever the planner said for it)."""
        g, step, lost = self.graph, self.step + 1, fleet.lost
        rows = [
            (step, v, t, g.lat[t], g.lon[t], fleet.mission_time)
            for v, t in sorted(targets.items())
            if v not in lost
        ]
        self.recorder.write_targets(step, rows)

    def _observation(self, fleet: Fleet, done: dict[int, bool]) -> Observation:
        return Observation(
            step=self.step,
            time_s=fleet.mission_time,
            graph=self.graph,
            positions=dict(fleet.positions),
            remaining=fleet.remaining(),
            done=dict(done),
            visits=self.visits.copy(),
            fields=self.environment.observation_fields(),
            task=self.environment.task_state(),
        )

    # --- planning checks -------------------------------------------------------------------
    def _check_targets(self, targets: dict, positions: dict) -> dict[int, int]:
        name = self.mission.algorithm.type
        clean = {}
        for v, node in targets.items():
            if not (isinstance(v, (int, np.integer)) and 0 <= int(v) < self.n):
                raise GuadalError(f"algorithm '{name}' named vehicle {v!r}; vehicles are 0..{self.n - 1}.")
            if not (isinstance(node, (int, np.integer)) and 0 <= int(node) < self.graph.n_nodes):
                raise GuadalError(
                    f"algorithm '{name}' sent vehicle {v} to {node!r}, which is not a node id (0..{self.graph.n_nodes - 1})."
                )
            v, node = int(v), int(node)
            if (
                self.prep.mode == SEQUENTIAL
                and node != positions[v]
                and node not in self.graph.neighbors(positions[v])
            ):
                raise GuadalError(
                    f"algorithm '{name}' sent vehicle {v} from node {positions[v]} to node {node} in sequential mode, "
                    "where targets must be neighbours."
                )
            if not self.graph.same_component([positions[v], node]):
                raise GuadalError(
                    f"algorithm '{name}' sent vehicle {v} to node {node}, which cannot be reached over water."
                )
            clean[v] = node
        return clean

    def _next_hops(
        self, paths: dict[int, list[int]], positions: dict[int, int], waits: dict[int, int], fleet: Fleet
    ) -> dict[int, int]:
        """One edge per vehicle with a path, resolving conflicts: the lower id goes first."""
        remaining = fleet.remaining()
        for v in list(paths):
            if paths[v] and self.graph.edge_length(positions[v], paths[v][0]) > remaining[v] + 1e-9:
                paths[v] = []  # the budget does not reach the next node
        moving = {v: p[0] for v, p in paths.items() if p}
        if self.allow_shared:
            return moving
        while True:
            dest = {v: moving.get(v, positions[v]) for v in range(self.n)}
            blocked = None
            for v in sorted(moving):
                others = [u for u in range(self.n) if u != v and dest[u] == dest[v]]
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
        if waits[v] >= _WAIT_BEFORE_GIVING_UP:
            paths[v] = []
        elif waits[v] >= _WAIT_BEFORE_REROUTE and paths[v]:
            others = {positions[u] for u in range(self.n) if u != v}
            detour = self.graph.shortest_path(positions[v], paths[v][-1], avoid=others)
            if len(detour) > 1:
                paths[v] = detour[1:]

    # --- the loop ----------------------------------------------------------------------------
    def run(self) -> RunResult:
        from .db.writer import DatabaseWriter

        prep = self.prep
        columns = metric_columns(self.n, self.environment.metric_names)
        if self.resume:  # the database catches up with 'guadal db sync RUN' afterwards
            self.recorder = RunRecorder.reopen(self.output, columns)
        else:
            self.recorder = RunRecorder(
                self.output,
                prep.resolved_dict(),
                self._manifest(),
                columns,
                sinks=[DatabaseWriter(self.database)] if self.database else [],
            )
        previous_term = signal.getsignal(signal.SIGTERM)

        def _on_term(signum, frame):
            raise KeyboardInterrupt  # SIGTERM stops a run exactly as Ctrl-C does

        try:
            signal.signal(signal.SIGTERM, _on_term)
        except ValueError:  # not the main thread
            previous_term = None
        fleet = None
        status, error = "failed", None
        try:
            fleet = self.backend.make_fleet(
                graph=self.graph, fleet_config=self.mission.fleet, sensor=self.environment.sense, mission=prep
            )
            fleet.while_waiting = lambda: self._record_status(fleet)  # the fleet as run (replayed or not)
            if self.recorder.replay_until >= 0:
                record = read_record(self.output, self.recorder.replay_until)
                fleet = ReplayFleet(
                    fleet, record, self.graph, self.mission.fleet, self.environment.sense, str(self.output)
                )
            fleet.reset(prep.initial_nodes)
            self.operator = OperatorControls(
                self._control_inboxes(fleet), self.recorder.record_event, self.n, hold=fleet.hold
            )
            first = fleet.take_measurement()
            self.environment.update(first)
            self._record(fleet, first)
            self._mission_loop(fleet)
            status = "complete"
            if fleet.lost and len(fleet.lost) == self.n:  # no vehicle left: not a finished mission
                status = "aborted"
                self.stop_reason = "every vehicle was lost: " + " ".join(fleet.lost.values())
        except MissionAborted as exc:
            status, error = "interrupted", str(exc)
        except KeyboardInterrupt:
            status, error = "interrupted", "stopped by the user (interrupt or terminate signal)"
            raise
        except GuadalError as exc:
            error = str(exc)
            raise
        except Exception as exc:
            error = f"{type(exc).__name__}: {exc}"
            raise
        finally:
            fleet_health = {}
            if fleet is not None:
                fleet_health = fleet.health()
                fleet.close()
            self.recorder.write_fields(
                self.graph, self.environment.ground_truth, self.environment.observation_fields()
            )
            self.recorder.finish(
                status,
                error,
                extra={
                    "stop_reason": self.stop_reason,
                    "fleet": fleet_health,
                    "final_metrics": getattr(self, "last_metrics", None),
                    "model": self.environment.model_description(),
                },
            )
            if previous_term is not None:
                signal.signal(signal.SIGTERM, previous_term)
        return RunResult(self.output, status, self.step, self.last_metrics)

    def _control_inboxes(self, fleet: Fleet) -> list:
        """Where operators' requests come from: the run's database (the web console), when it has
        one, and the fleet's own control topic at remote levels."""
        inboxes: list = [FleetInbox(fleet)]
        if self.database:
            from .db.controls import ControlInbox
            from .db.engine import make_engine

            inboxes.append(ControlInbox(make_engine(self.database), self.recorder.manifest["run_id"]))
        return inboxes

    def _mission_loop(self, fleet: Fleet) -> None:
        done = {v: False for v in range(self.n)}
        idle_decisions = 0
        while True:
            if self.step >= self.mission.max_steps:
                self.stop_reason = "max_steps reached"
                return
            if self.planner.done:
                self.stop_reason = "the algorithm finished"
                return
            if all(done.values()):
                self.stop_reason = "every vehicle spent its budget"
                return
            if idle_decisions >= _IDLE_DECISIONS_BEFORE_STOP:
                self.stop_reason = f"the algorithm's last {idle_decisions} decisions moved no vehicle"
                return
            self.operator.check(fleet.mission_time, [v for v in done if not done[v]])
            positions = dict(fleet.positions)
            targets = self._check_targets(
                self.planner.next_targets(self._observation(fleet, done)), positions
            )
            targets = {v: t for v, t in targets.items() if not done[v] and t != positions[v]}
            if not targets:
                self.stop_reason = "the algorithm sent no more targets"
                return
            self._record_targets(targets, fleet)
            step_before = self.step
            paths = {v: self.graph.shortest_path(positions[v], t)[1:] for v, t in targets.items()}
            pending: list[Measurement] = []
            waits: dict[int, int] = {}
            while any(paths.values()) and self.step < self.mission.max_steps:
                self.operator.check(fleet.mission_time, [v for v in done if not done[v]])
                for v in self.operator.held:
                    paths[v] = []  # a held boat stays at its node; the planner decides again for it later
                hops = self._next_hops(paths, positions, waits, fleet)
                if not hops:
                    if not any(paths.values()):
                        break
                    continue  # only waiting vehicles this round: their counters advanced
                reached = {v: False for v in hops}
                while not all(reached.values()):
                    reached, done = fleet.move(hops)
                    reached = {v: reached.get(v, False) or done.get(v, False) for v in hops}
                positions = dict(fleet.positions)
                moved = [v for v, node in hops.items() if positions[v] == node]
                for v in hops:
                    if v in moved:
                        paths[v].pop(0)
                        waits.pop(v, None)
                    else:
                        paths[v] = []  # the vehicle could not make the hop (budget, failsafe)
                self.step += 1
                self.environment.advance(fleet.mission_time)
                measurements = fleet.take_measurement(moved)
                if self.prep.mode == SEQUENTIAL:
                    self.environment.update(measurements)
                else:
                    pending.extend(measurements)
                    if not any(paths.values()):
                        self.environment.update(pending)
                        pending = []
                self._record(fleet, measurements)
            if pending:
                self.environment.update(pending)
            idle_decisions = idle_decisions + 1 if self.step == step_before else 0

"""A mission into a run directory: planner -> Episode -> recorder, with signals, resume and controls.

The rules of the mission loop (hops, conflicts, budgets, modes, stop reasons) live in
:class:`~guadal_cli.episode.Episode`; the runner asks the planner for each decision, records
every hop the episode reports, lets operators pause, hold or abort between hops, and turns
interrupts into a run directory that ``guadal resume`` can continue.
"""

from __future__ import annotations

import datetime as _dt
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from . import plugins
from .controls import FleetInbox, MissionAborted, OperatorControls
from .episode import Episode
from .errors import GuadalError
from .fleet.base import Fleet, Measurement
from .fleet.status import StatusSampler
from .mission import Prepared
from .records import RunRecorder, file_sha256
from .resume import ReplayFleet, read_record

#: live viewers get the model's maps at most this often (wall clock; the CSVs do not depend on it)
_SHARE_FIELDS_EVERY_S = 1.0


@dataclass
class RunResult:
    directory: Path
    status: str
    steps: int
    final_metrics: dict


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


class _StopSignals:
    """SIGTERM stops a run exactly as Ctrl-C does, and neither may land before the loop's ``try``.

    A stop that came between the run directory's first byte (a manifest saying ``running``) and
    the ``try`` that records interruptions would leave that run ``running`` for good. So both
    signals are held back while the directory is made (:meth:`hold`) and raised as
    ``KeyboardInterrupt`` once inside the ``try`` (:meth:`release`). Off the main thread signals
    cannot be handled, and nothing is changed.
    """

    def __init__(self):
        self._held = False
        self._pending = False
        self._previous: dict = {}

    def _on_signal(self, signum, frame):
        if self._held:
            self._pending = True
            return
        raise KeyboardInterrupt

    def hold(self) -> None:
        try:
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._on_signal)
        except ValueError:  # not the main thread
            return
        self._held = True

    def release(self) -> None:
        """From here on SIGTERM raises ``KeyboardInterrupt``, Ctrl-C as before; one held back
        raises now."""
        if not self._held:
            return
        self._held = False
        signal.signal(signal.SIGINT, self._previous[signal.SIGINT])
        if self._pending:
            self._pending = False
            raise KeyboardInterrupt

    def restore(self) -> None:
        """The process's own handlers back (a stop still held back is dropped with them)."""
        self._held = False
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()


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
        self.episode: Episode | None = None
        self.stop_reason = ""
        self._share_fields_at = 0.0
        self.status = StatusSampler()
        self._distance_columns = [f"distance_v{v}" for v in range(self.n)]

    @property
    def step(self) -> int:
        """Steps (hops) recorded so far."""
        return self.episode.step_count if self.episode is not None else 0

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

    def _record(self, ep: Episode, fleet: Fleet, measurements: list[Measurement]) -> None:
        """One step into the run directory (and the database): the episode has counted it."""
        dist = fleet.distances
        row = {"step": self.step, "time_s": fleet.mission_time}
        row.update(zip(self._distance_columns, [dist[v] for v in range(self.n)]))
        row.update(total_distance=sum(dist.values()), samples=ep.samples, coverage=ep.coverage)
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

    def _record_targets(self, ep: Episode, fleet: Fleet, targets: dict[int, int]) -> None:
        """One decision: where each vehicle is sent, labelled with the step of its first hop."""
        g, step = self.graph, self.step + 1
        rows = [(step, v, t, g.lat[t], g.lon[t], fleet.mission_time) for v, t in sorted(targets.items())]
        self.recorder.write_targets(step, rows)

    # --- the loop ----------------------------------------------------------------------------
    def run(self) -> RunResult:
        from .db.writer import DatabaseWriter

        prep = self.prep
        columns = metric_columns(self.n, self.environment.metric_names)
        sinks = [DatabaseWriter(self.database)] if self.database else []
        stops = _StopSignals()
        stops.hold()
        try:
            if self.resume:  # the database is brought back in line with the cut files, then goes on live
                self.recorder = RunRecorder.reopen(self.output, columns, sinks=sinks)
            else:
                self.recorder = RunRecorder(
                    self.output, prep.resolved_dict(), self._manifest(), columns, sinks=sinks
                )
        except BaseException:
            stops.restore()
            raise
        fleet = None
        status, error = "failed", None
        try:
            stops.release()  # a stop held back meanwhile lands here, and is recorded
            fleet = self.backend.make_fleet(
                graph=self.graph, fleet_config=self.mission.fleet, sensor=self.environment.sense, mission=prep
            )
            fleet.while_waiting = lambda: self._record_status(fleet)  # the fleet as run (replayed or not)
            if self.recorder.replay_until >= 0:
                record = read_record(self.output, self.recorder.replay_until)
                fleet = ReplayFleet(
                    fleet, record, self.graph, self.mission.fleet, self.environment.sense, str(self.output)
                )
            self.operator = OperatorControls(
                self._control_inboxes(fleet), self.recorder.record_event, self.n, hold=fleet.hold
            )
            self.episode = Episode(
                prep,
                fleet,
                on_hop=self._record,
                before_hop=self._between_hops,
                on_decision=self._record_targets,
            )
            self.episode.reset()
            self._record(self.episode, fleet, self.episode.last_measurements)
            self._mission_loop(self.episode)
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
            stops.restore()
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

    def _between_hops(self, ep: Episode, fleet: Fleet) -> None:
        """Operators' requests take effect at the next node; a held boat stays where it is."""
        self.operator.check(fleet.mission_time, [v for v, done in ep.done.items() if not done])
        for v in self.operator.held:
            ep.hold(v)  # the planner decides again for it later

    def _mission_loop(self, ep: Episode) -> None:
        """Decisions until the episode or the planner says stop; each hop is recorded by ``on_hop``."""
        while not ep.truncated:  # max_steps first, then the planner, then the episode's reasons
            if self.planner.done:
                self.stop_reason = "the algorithm finished"
                return
            if ep.stop_reason:
                break
            self.operator.check(ep.fleet.mission_time, [v for v, done in ep.done.items() if not done])
            *_, info = ep.step(self.planner.next_targets(ep.observation()))
            if not info["targets"]:
                self.stop_reason = "the algorithm sent no more targets"
                return
        self.stop_reason = ep.stop_reason

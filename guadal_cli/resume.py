"""Resuming an interrupted run: replay its record through the mission loop, then go on live.

Nothing of the mission loop is copied here. The runner runs the mission from its first step as
usual, with the same seed; only the fleet differs: a :class:`ReplayFleet` answers from the run's
CSVs for every step already recorded, so the planner sees the same observations and makes the
same decisions (its state, generator included, is re-created by living them again) and the
environment's model is rebuilt from the recorded measurements. When the record runs out, the
real fleet takes over where the record left the vehicles.

The record is the truth; a *shadow* :class:`~guadal_cli.fleet.local.LocalFleet` walks the same
hops beside it. Where the shadow agrees with the record (always, at ``sim``) its exact numbers
are used, so a resumed ``sim`` run is byte-identical to an uninterrupted one; where a remote
vehicle did something else (a failed hop) the record wins. Synthetic measurements are drawn
again from the environment's sensor, which keeps its generator in step and checks that the
world is the one the run saw.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .errors import GuadalError
from .fleet.base import Fleet, Measurement, Sensor
from .fleet.local import LocalFleet
from .graph import NavGraph
from .mission import Prepared, prepare_dict, read_mission_file
from .records import CSV_FILES, LOCK_NAME, fmt, read_manifest


@dataclass
class RecordedStep:
    """One step of a run directory: where every vehicle stood, and the samples taken."""

    positions: dict[int, int] = field(default_factory=dict)
    distances: dict[int, str] = field(default_factory=dict)  # as written (10 significant digits)
    time_s: str = "0"
    measurements: list[dict] = field(default_factory=list)


def read_record(directory: Path, last_step: int) -> list[RecordedStep]:
    """Steps ``0..last_step`` of a run directory's trajectory and measurements."""
    steps = [RecordedStep() for _ in range(last_step + 1)]
    with open(Path(directory) / "trajectory.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            step = int(row["step"])
            if row["source"] != "plan" or step > last_step:
                continue
            v = int(row["vehicle"])
            steps[step].positions[v] = int(row["node"])
            steps[step].distances[v] = row["distance"]
            steps[step].time_s = row["time_s"]
    with open(Path(directory) / "measurements.csv", newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            if int(row["step"]) <= last_step:
                steps[int(row["step"])].measurements.append(row)
    for i, step in enumerate(steps):
        if not step.positions:
            raise GuadalError(f"cannot resume '{directory}': trajectory.csv has no row for step {i}.")
    return steps


class ReplayFleet(Fleet):
    """Serves recorded steps to the runner, then hands over to the ``live`` fleet."""

    def __init__(
        self,
        live: Fleet,
        record: Sequence[RecordedStep],
        graph: NavGraph,
        fleet_config,
        sensor: Sensor | None,
        where: str,
    ):
        self.live = live
        self.record = list(record)
        self.where = where
        self.n_vehicles = fleet_config.vehicles
        self._max_distance = float(fleet_config.max_distance)
        self.synthetic = sensor is not None and live.synthetic_measurements
        self.shadow = LocalFleet(
            graph,
            fleet_config.vehicles,
            fleet_config.max_distance,
            fleet_config.speed,
            sensor if self.synthetic else (lambda v, n: float("nan")),
        )
        self.step = 0
        self.is_live = False
        # at remote levels a vehicle may have failed a hop the shadow made: the record wins there
        self.record_wins = not isinstance(live, LocalFleet)

    # --- the record, checked ---------------------------------------------------------------
    def _diverged(self, what: str) -> GuadalError:
        return GuadalError(
            f"cannot resume {self.where}: step {self.step} replays differently from the record ({what}); "
            "the mission, its map or its plugins changed since the run began."
        )

    def _agree(self) -> None:
        """Make the shadow stand where the record says, keeping its exact numbers where they agree."""
        rec = self.record[self.step]
        for vehicle in self.shadow.vehicles:
            node = rec.positions.get(vehicle.id)
            if node is None:
                raise self._diverged(f"no trajectory row for vehicle {vehicle.id}")
            if vehicle.node != node and not self.record_wins:
                raise self._diverged(f"vehicle {vehicle.id} is at node {node}, not {vehicle.node}")
            vehicle.node = node
            if fmt(vehicle.distance) != rec.distances[vehicle.id]:
                vehicle.distance = float(rec.distances[vehicle.id])
        if fmt(self.shadow.mission_time) != rec.time_s:
            self.shadow._time = float(rec.time_s)

    # --- the Fleet contract ------------------------------------------------------------------
    @property
    def replaying(self) -> bool:
        return not self.is_live

    @property
    def positions(self) -> dict[int, int]:
        return self.live.positions if self.is_live else self.shadow.positions

    @property
    def distances(self) -> dict[int, float]:
        return self.live.distances if self.is_live else self.shadow.distances

    @property
    def mission_time(self) -> float:
        return self.live.mission_time if self.is_live else self.shadow.mission_time

    def reset(self, initial_nodes: Sequence[int]) -> None:
        self.shadow.reset(initial_nodes)
        self.step = 0
        self._agree()

    def move(self, targets: Mapping[int, int]) -> tuple[dict[int, bool], dict[int, bool]]:
        if self.is_live:
            return self.live.move(targets)
        self.shadow.move(targets)
        self.step += 1
        self._agree()
        return {v: True for v in targets}, self.shadow.stuck()

    def take_measurement(self, vehicles: Sequence[int] | None = None) -> list[Measurement]:
        if self.is_live:
            return self.live.take_measurement(vehicles)
        recorded = {int(r["vehicle"]): r for r in self.record[self.step].measurements}
        ids = list(range(self.n_vehicles) if vehicles is None else vehicles)
        drawn = {m.vehicle: m for m in self.shadow.take_measurement(ids)} if self.synthetic else {}
        out = []
        for vid in ids:
            row = recorded.get(vid)
            if row is None:
                continue  # that vehicle measured nothing (a remote fault): nor does its replay
            value = float(row["value"])
            if self.synthetic:
                if fmt(drawn[vid].value) != row["value"]:
                    raise self._diverged(
                        f"vehicle {vid} measures {fmt(drawn[vid].value)} where the run measured {row['value']}"
                    )
                value = drawn[vid].value
            time_s = self.shadow.mission_time if fmt(self.shadow.mission_time) == row["time_s"] else None
            out.append(
                Measurement(
                    vehicle=vid,
                    node=int(row["node"]),
                    value=value,
                    lat=float(row["lat"]),
                    lon=float(row["lon"]),
                    time_s=float(row["time_s"]) if time_s is None else time_s,
                )
            )
        if self.step + 1 >= len(self.record):
            self._go_live()  # before the next decision: it is made on where the boats really are
        return out

    def _go_live(self) -> None:
        """The record is spent: the real fleet takes over (at remote levels, each boat from where
        its GPS puts it, and without the boats that do not answer)."""
        self.live.restore(self.shadow.positions, self.shadow.distances, self.shadow.mission_time)
        self.is_live = True

    def remaining(self) -> dict[int, float]:
        return self.live.remaining() if self.is_live else self.shadow.remaining()

    @property
    def lost(self) -> dict[int, str]:
        return self.live.lost if self.is_live else {}

    def pending_controls(self) -> list[dict]:
        return self.live.pending_controls() if self.is_live else []

    def hold(self, vehicles: list[int] | None = None) -> None:
        if self.is_live:  # replayed steps move nothing: there is nothing to stop yet
            self.live.hold(vehicles)

    def vehicle_status(self) -> dict[int, dict]:
        return self.live.vehicle_status() if self.is_live else self.shadow.vehicle_status()

    def health(self) -> dict:
        return self.live.health()

    def track_rows(self) -> list[dict]:
        return self.live.track_rows() if self.is_live else []

    def close(self) -> None:
        self.live.close()


def prepare_resume(directory: Path) -> Prepared:
    """The mission of an interrupted run, as it was resolved when the run began."""
    directory = Path(directory)
    manifest = read_manifest(directory)
    if manifest.get("status") == "complete":
        raise GuadalError(f"run '{directory}' is complete; there is nothing to resume.")
    _check_run_files(directory)
    resolved = directory / "mission.resolved.yaml"
    mission_dir = manifest.get("mission_dir") or str(Path(str(manifest.get("mission_file", ""))).parent)
    prep = prepare_dict(read_mission_file(resolved), Path(mission_dir), resolved, check_output=False)
    prep.resume_nodes = last_positions(directory, prep.mission.fleet.vehicles)
    return prep


#: what every run directory holds from its first moment: without them there is no record to go on from
_REQUIRED_FILES = ("mission.resolved.yaml", "metrics.csv", "trajectory.csv", "measurements.csv")


def _check_run_files(directory: Path) -> None:
    """One sentence for a run directory whose files were removed or replaced by folders."""
    for name in dict.fromkeys((*_REQUIRED_FILES, *CSV_FILES, "fields.csv", LOCK_NAME)):
        path = directory / name
        if path.exists() and not path.is_file():
            raise GuadalError(f"run directory '{directory}': '{name}' is not a file; it cannot be resumed.")
        if name in _REQUIRED_FILES and not path.exists():
            raise GuadalError(
                f"run directory '{directory}' has no {name}, which every run writes first; it cannot be resumed."
            )


def last_positions(directory: Path, vehicles: int) -> list[int] | None:
    """Each vehicle's node at the run's last complete step (its last metrics row), or None if
    the run recorded no complete step. Read only: ``resume`` cuts the files itself."""
    try:
        data = (Path(directory) / "metrics.csv").read_bytes()
    except OSError:
        return None
    lines = data[: data.rfind(b"\n") + 1].splitlines()[1:]
    try:
        last = int(lines[-1].split(b",")[0])
    except (IndexError, ValueError):
        return None
    nodes: dict[int, int] = {}
    # errors="replace": a torn last line may end inside a character; it is not of step ``last``
    with open(Path(directory) / "trajectory.csv", newline="", encoding="utf-8", errors="replace") as fh:
        for row in csv.DictReader(fh):
            if row.get("source") == "plan" and row.get("step") == str(last):
                nodes[int(row["vehicle"])] = int(row["node"])
    return [nodes[v] for v in range(vehicles)] if len(nodes) == vehicles else None

"""What the console reads from the mission database, shaped for the browser.

Every table a mission grows has a monotonic ``id``; a page's live stream keeps one
:class:`Cursor` (the last id it has of each table) and asks :meth:`ConsoleReader.changes` for
what is newer, a few times a second. Calls block: the server runs them in a worker thread.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, fields
from functools import lru_cache
from pathlib import Path

import numpy as np
from sqlalchemy import func, select

from ..db import queries
from ..db.models import FieldSnapshot, Map, TrajectoryPoint
from ..errors import GuadalError

#: the newest runs the list shows (and streams); older ones stay reachable by their page
LIST_LIMIT = 500
#: filters the list offers; the API takes every filter of ``guadal db runs``
LIST_FILTERS = ("map", "algorithm", "level", "status")


@dataclass
class Cursor:
    """The last row id a page has of each growing table, and the run's last seen state."""

    steps: int = 0
    trajectory: int = 0
    measurements: int = 0
    events: int = 0
    fields: int = 0  # the newest field snapshot sent
    vehicles: int = 0
    targets: int = 0
    run: str = ""  # the run's last update time: its status, step count or fields changed

    def text(self) -> str:
        return ".".join(str(getattr(self, f.name)) for f in fields(self) if f.name != "run")

    @classmethod
    def parse(cls, text: str | None) -> Cursor:
        """A cursor from a stream's Last-Event-ID; anything unreadable starts from the beginning."""
        try:
            ids = [int(part) for part in (text or "").split(".")]
        except ValueError:
            return cls()
        return cls(*ids) if len(ids) == 7 and min(ids) >= 0 else cls()


def _finite(value):
    return value if isinstance(value, (int, float)) and math.isfinite(value) else None


SUMMARY_KEYS = (
    "id",
    "name",
    "status",
    "level",
    "algorithm",
    "environment",
    "map",
    "vehicles",
    "steps",
    "seed",
    "started_at",
    "ended_at",
    "stop_reason",
    "error",
)


def _seconds_since(stamp: str | None) -> float:
    """Seconds from a stored (naive UTC) ISO time to now; 0 for none, or one in the future."""
    if not stamp:
        return 0.0
    then = _dt.datetime.fromisoformat(stamp).replace(tzinfo=_dt.timezone.utc)
    return max(0.0, (_dt.datetime.now(_dt.timezone.utc) - then).total_seconds())


def run_summary(run: dict) -> dict:
    return {key: run.get(key) for key in SUMMARY_KEYS}


@lru_cache(maxsize=16)
def _grid_from_map_file(path: str, sha256: str) -> tuple[float, list] | None:
    """Node positions (row-major water cells, as the planner numbers them) from the map file."""
    import hashlib

    from ..maps.format import load_map

    file = Path(path)
    try:
        if hashlib.sha256(file.read_bytes()).hexdigest() != sha256:
            return None  # the file changed since the run: its cells may not be the run's nodes
        map_ = load_map(file)
    except (OSError, GuadalError):
        return None
    rows, cols = np.nonzero(map_.mask)
    nodes = [
        [round(float(a), 8), round(float(b), 8)] for a, b in zip(map_.lat[rows, cols], map_.lon[rows, cols])
    ]
    return float(map_.cell_size_m), nodes


class ConsoleReader:
    """Read-only queries of one database for the console, through ``guadal_cli.db.queries``."""

    def __init__(self, engine):
        self.engine = engine

    # --- the list ---------------------------------------------------------------------------
    def runs(self, filters: dict[str, str] | None = None) -> list[dict]:
        """Runs newest first, optionally filtered as ``guadal db runs`` filters them."""
        filters = dict(filters or {})
        unknown = sorted(set(filters) - set(queries.RUN_FILTERS))
        if unknown:
            raise GuadalError(
                f"unknown run filter '{unknown[0]}'; filters are {', '.join(queries.RUN_FILTERS)}."
            )
        return [run_summary(r) for r in queries.list_runs(self.engine, **filters, limit=LIST_LIMIT)]

    def runs_version(self) -> tuple:
        """Changes whenever a run is added or updated: the list stream resends only then."""
        ids = queries.latest_ids(self.engine)
        return ids["runs"], ids["runs_updated_at"]

    # --- one run ----------------------------------------------------------------------------
    def _run(self, run_id: int) -> dict:
        try:
            return queries.get_run(self.engine, run_id)
        except GuadalError as exc:
            raise LookupError(run_id) from exc

    def run(self, run_id: int) -> dict:
        """A run's summary, its mission, and its map as node positions for drawing."""
        run = self._run(run_id)
        with self.engine.connect() as conn:
            map_ = conn.execute(select(Map).where(Map.id == run["map_id"])).first() if run["map_id"] else None
            grid = _grid_from_map_file(map_.path, map_.sha256) if map_ is not None and map_.path else None
            if grid is None:
                grid = self._grid_from_rows(conn, run_id, map_)
        fleet = (run["mission"] or {}).get("fleet") or {}
        return {
            "run": run_summary(run),
            "mission": run["mission"] or {},
            "metric_columns": run["metric_columns"] or [],
            "max_distance": fleet.get("max_distance"),
            "grid": {"cell_size_m": grid[0], "nodes": grid[1]},
        }

    def _grid_from_rows(self, conn, run_id: int, map_) -> tuple[float, list]:
        """Without the map file: the nodes the run's own rows place (final fields, then the plan)."""
        nodes = {r["node"]: [r["lat"], r["lon"]] for r in queries.fields(self.engine, run_id)}
        if not nodes:
            stmt = (
                select(TrajectoryPoint.node, TrajectoryPoint.lat, TrajectoryPoint.lon)
                .where(TrajectoryPoint.run_id == run_id, TrajectoryPoint.source == "plan")
                .distinct()
            )
            nodes = {node: [lat, lon] for node, lat, lon in conn.execute(stmt) if node is not None}
        size = max(int((map_.water_nodes if map_ is not None else 0) or 0), max(nodes, default=-1) + 1)
        cell = float((map_.cell_size_m if map_ is not None else None) or 5.0)
        return cell, [nodes.get(i) for i in range(size)]

    def changes(self, run_id: int, cursor: Cursor) -> tuple[dict, Cursor]:
        """Rows of the run newer than ``cursor`` (empty dict if nothing changed) and the new cursor."""
        ids = queries.latest_ids(self.engine, run_id)
        if not ids["runs"]:
            raise LookupError(run_id)
        with self.engine.connect() as conn:
            snapshot = conn.execute(
                select(func.max(FieldSnapshot.id)).where(FieldSnapshot.run_id == run_id)
            ).scalar()
        stamp = str(ids["runs_updated_at"])
        new = Cursor(
            ids["steps"],
            ids["trajectory"],
            ids["measurements"],
            ids["events"],
            snapshot or 0,
            ids["vehicles"],
            ids["targets"],
            stamp,
        )
        if new == cursor:
            return {}, cursor
        out: dict = {}
        if new.fields > cursor.fields:
            out["fields"] = [self._snapshot(new.fields)]
        if stamp != cursor.run:
            run = self._run(run_id)
            out["run"] = run_summary(run)
            if run["field_columns"]:  # the final maps, once the run has written them
                out["fields"] = [_fields(queries.fields(self.engine, run_id), run["steps"])]
        if new.steps > cursor.steps:
            out["steps"] = [
                {
                    "step": r["step"],
                    "time_s": r["time_s"],
                    "total_distance": r["total_distance"],
                    "metrics": {k: _finite(v) for k, v in (r["metrics"] or {}).items()},
                }
                for r in queries.steps(self.engine, run_id, cursor.steps)
                if r["id"] <= new.steps
            ]
        if new.trajectory > cursor.trajectory:
            out["track"] = [
                {k: r[k] for k in ("step", "vehicle", "node", "lat", "lon", "source", "time_s")}
                for r in queries.trajectory(self.engine, run_id, cursor.trajectory)
                if r["id"] <= new.trajectory
                and _finite(r["lat"]) is not None
                and _finite(r["lon"]) is not None
            ]
        if new.measurements > cursor.measurements:
            out["measurements"] = [
                {
                    **{k: r[k] for k in ("step", "vehicle", "node", "lat", "lon", "time_s")},
                    "value": _finite(r["value"]),
                }
                for r in queries.measurements(self.engine, run_id, cursor.measurements)
                if r["id"] <= new.measurements
            ]
        if new.vehicles > cursor.vehicles:
            out["vehicles"] = [
                {
                    **{k: r[k] for k in ("step", "vehicle", "mode", "armed", "fault")},
                    **{k: _finite(r[k]) for k in ("time_s", "remaining", "battery", "link_age_s")},
                }
                for r in queries.vehicle_status(self.engine, run_id, cursor.vehicles)
                if r["id"] <= new.vehicles
            ]
            # how long ago the newest of them reached the database, by this server's clock: a page
            # opened long after the boats went quiet must not show their last link age as fresh
            out["vehicles_age_s"] = _seconds_since(ids["runs_updated_at"])
        if new.targets > cursor.targets:
            out["targets"] = [
                {k: r[k] for k in ("step", "vehicle", "node", "lat", "lon", "time_s")}
                for r in queries.targets(self.engine, run_id, cursor.targets)
                if r["id"] <= new.targets
            ]
        if new.events > cursor.events:
            out["events"] = [
                {
                    "kind": r["kind"],
                    "vehicle": r["vehicle"],
                    "time_s": r["time_s"],
                    "detail": r["message"],
                    **{
                        k: r["detail"].get(k)
                        for k in ("action", "who", "at")
                        if isinstance(r["detail"], dict)
                    },
                }
                for r in queries.events(self.engine, run_id, cursor.events)
                if r["id"] <= new.events
            ]
        return out, new

    def _snapshot(self, snapshot_id: int) -> dict:
        """One live snapshot of the model's maps (only the newest is sent: they are large)."""
        with self.engine.connect() as conn:
            step, values = conn.execute(
                select(FieldSnapshot.step, FieldSnapshot.values).where(FieldSnapshot.id == snapshot_id)
            ).one()
        return {"step": step, "values": {n: [_finite(v) for v in vs] for n, vs in values.items()}}


def _fields(rows: list[dict], step: int) -> dict:
    """The run's per-node maps as one snapshot: {name: [value per node]}."""
    size = max((r["node"] for r in rows), default=-1) + 1
    values: dict[str, list] = {}
    for r in rows:
        for name, value in (r["values"] or {}).items():
            values.setdefault(name, [None] * size)[r["node"]] = _finite(value)
    return {"step": step, "values": values}

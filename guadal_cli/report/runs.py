"""Finding, reading and grouping run directories for ``guadal report``.

A report reads only what ``guadal run`` wrote (see ``records.py``): the manifest says how the
run ended, the CSVs hold the numbers, the resolved mission holds every field a user may group
by. CSVs are read lazily, so a table of a hundred runs does not load a hundred trajectories.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import yaml

from ..errors import GuadalError
from ..records import RUN_FORMAT, read_manifest, read_resolved_mission

#: columns every metrics.csv has before the environment's own task metrics
GENERAL_METRICS = ("step", "time_s", "total_distance", "samples", "coverage")
#: what a manifest's status becomes in tables; "running" left behind means the run never ended
STATUS_LABELS = {
    "complete": "complete",
    "interrupted": "interrupted",
    "failed": "failed",
    "running": "unfinished",
}


def read_columns(path: Path) -> dict[str, list[str]]:
    """A CSV as {column: [cells]}; an absent or empty file gives no columns."""
    if not path.is_file():
        return {}
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            return {}
        cols: dict[str, list[str]] = {name: [] for name in header}
        for row in reader:
            if len(row) != len(header):
                continue  # a row cut short by a crash mid-write
            for name, cell in zip(header, row):
                cols[name].append(cell)
    return cols


def as_floats(cells: list[str]) -> np.ndarray:
    """Numbers from CSV cells; blanks (and anything unreadable) become NaN."""
    out = np.full(len(cells), np.nan)
    for i, cell in enumerate(cells):
        try:
            out[i] = float(cell)
        except ValueError:
            pass
    return out


def mission_field(mission: dict, dotted: str):
    """The value at ``a.b.c`` in the resolved mission, or None where the path does not exist."""
    value = mission
    for part in dotted.split("."):
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            return None
    return value


@dataclass
class Run:
    """One run directory, read on demand."""

    path: Path
    manifest: dict
    mission: dict
    name: str = ""

    @property
    def status(self) -> str:
        return STATUS_LABELS.get(str(self.manifest.get("status")), str(self.manifest.get("status")))

    @property
    def complete(self) -> bool:
        return self.status == "complete"

    @property
    def seed(self):
        return self.manifest.get("seed", mission_field(self.mission, "seed"))

    @property
    def algorithm(self) -> str:
        return str(mission_field(self.mission, "algorithm.type") or "?")

    @property
    def environment(self) -> str:
        return str(mission_field(self.mission, "environment.type") or "?")

    @property
    def level(self) -> str:
        return str(self.manifest.get("level", mission_field(self.mission, "backend.level") or "?"))

    @property
    def map_key(self) -> tuple:
        """What makes two runs' maps the same map for comparison purposes."""
        m = self.manifest.get("map", {})
        return (m.get("name"), tuple(m.get("shape") or ()), m.get("water_nodes"))

    @property
    def map_name(self) -> str:
        return str(self.manifest.get("map", {}).get("name") or Path(self.map_path or "?").stem)

    @property
    def map_path(self) -> str | None:
        return self.manifest.get("map", {}).get("path") or mission_field(self.mission, "map.path")

    @cached_property
    def metrics(self) -> dict[str, np.ndarray]:
        return {k: as_floats(v) for k, v in read_columns(self.path / "metrics.csv").items()}

    @property
    def metric_columns(self) -> list[str]:
        return list(self.metrics) or list(self.manifest.get("metric_columns") or [])

    @property
    def task_metrics(self) -> list[str]:
        """The environment's own columns: everything after the general ones and per-vehicle distances."""
        return [c for c in self.metric_columns if c not in GENERAL_METRICS and not c.startswith("distance_v")]

    def final(self, column: str) -> float:
        """Last recorded value of a metrics.csv column (NaN if never recorded)."""
        values = self.metrics.get(column)
        return float(values[-1]) if values is not None and len(values) else math.nan

    @property
    def steps(self) -> int:
        values = self.metrics.get("step")
        return int(values[-1]) if values is not None and len(values) else 0

    @cached_property
    def trajectory(self) -> dict[str, list[str]]:
        return read_columns(self.path / "trajectory.csv")

    @cached_property
    def measurements(self) -> dict[str, np.ndarray]:
        return {k: as_floats(v) for k, v in read_columns(self.path / "measurements.csv").items()}

    @cached_property
    def fields(self) -> dict[str, np.ndarray]:
        return {k: as_floats(v) for k, v in read_columns(self.path / "fields.csv").items()}

    @cached_property
    def _tracks(self) -> dict[str, dict[int, dict[str, np.ndarray]]]:
        t = self.trajectory
        out: dict[str, dict[int, dict[str, np.ndarray]]] = {}
        if not t:
            return out
        columns = {name: as_floats(cells) for name, cells in t.items() if name != "source"}
        sources = np.asarray(t.get("source", []), dtype=object)
        vehicles = columns["vehicle"]
        for source in sorted(set(sources)):
            for v in sorted({int(x) for x in vehicles[(sources == source) & ~np.isnan(vehicles)]}):
                rows = (sources == source) & (vehicles == v)
                out.setdefault(source, {})[v] = {name: values[rows] for name, values in columns.items()}
        return out

    def track(self, source: str) -> dict[int, dict[str, np.ndarray]]:
        """Per vehicle, the rows of one source (``plan`` or ``gps``) as arrays, in file order."""
        return self._tracks.get(source, {})

    @property
    def has_gps(self) -> bool:
        return "gps" in self.trajectory.get("source", [])


def _read_run(directory: Path) -> Run:
    return Run(path=directory, manifest=read_manifest(directory), mission=read_resolved_mission(directory))


def find_runs(paths: list[Path]) -> list[Run]:
    """Run directories named directly or found below the given folders, each read once."""
    found: list[Path] = []
    for path in paths:
        path = Path(path)
        if not path.exists():
            raise GuadalError(f"'{path}' does not exist; give run directories or folders that contain them.")
        if (path / "manifest.json").is_file():
            found.append(path)
        elif path.is_dir():
            found.extend(sorted(p.parent for p in path.rglob("manifest.json")))
    unique = list(dict.fromkeys(p.resolve() for p in found))
    if not unique:
        shown = ", ".join(f"'{p}'" for p in paths) or "nothing"
        raise GuadalError(
            f"no run directories found in {shown}: a run directory is what 'guadal run' writes (it holds manifest.json)."
        )
    runs = [_read_run(p) for p in unique]
    _name_runs(runs)
    return runs


def _name_runs(runs: list[Run]) -> None:
    """Short unique names: the directory name, with parents added only where two collide."""
    depth = 1
    while True:
        names = ["/".join(r.path.parts[-depth:]) for r in runs]
        if len(set(names)) == len(names) or depth > 8:
            break
        depth += 1
    for run, name in zip(runs, names):
        run.name = name


def file_stem(name: str) -> str:
    """A run name made safe for file names."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "run"


@dataclass
class Group:
    key: tuple
    runs: list[Run] = field(default_factory=list)

    @property
    def label(self) -> str:
        return ", ".join(str(k) for k in self.key)

    @property
    def counted(self) -> list[Run]:
        """Runs that enter means and bands: the complete ones, or all when none completed."""
        done = [r for r in self.runs if r.complete]
        return done or list(self.runs)

    @property
    def status(self) -> str:
        """'complete', or what the group holds, e.g. '2 complete, 1 interrupted (left out)'."""
        counts = Counter(r.status for r in self.runs)
        if set(counts) == {"complete"}:
            return "complete"
        parts = [f"{n} {s}" for s, n in sorted(counts.items(), key=lambda kv: kv[0] != "complete")]
        text = ", ".join(parts)
        return f"{text} (left out)" if counts.get("complete") else f"{text} (no complete run)"


def _key_text(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, (dict, list)):
        return json.dumps(value, sort_keys=True)
    return str(value)


#: group fields that are not mission paths: what a run was made on and at which level
RUN_FIELDS = ("map", "level")


def map_labels(runs: list[Run]) -> dict[int, str]:
    """Per run (by id), its map's name; maps that share a name get their size added to tell them apart."""
    keys_by_name: dict[str, set] = {}
    for r in runs:
        keys_by_name.setdefault(r.map_name, set()).add(r.map_key)
    labels = {}
    for r in runs:
        name = r.map_name
        if len(keys_by_name[name]) > 1:
            _, shape, nodes = r.map_key
            name = f"{name} ({'x'.join(str(n) for n in shape)}, {nodes} nodes)"
        labels[id(r)] = name
    return labels


def group_runs(runs: list[Run], fields: list[str]) -> list[Group]:
    """Runs grouped by ``map``, ``level`` or dotted mission fields, in order of first appearance."""
    for name in fields:
        if name not in RUN_FIELDS and all(mission_field(r.mission, name) is None for r in runs):
            raise GuadalError(
                f"field '{name}' is in none of the runs' missions; give 'map', 'level' or dotted paths into "
                "mission.resolved.yaml such as algorithm.type, fleet.vehicles or environment.type.",
                field="group_by",
            )
    maps = map_labels(runs)
    groups: dict[tuple, Group] = {}
    for run in runs:
        key = tuple(
            maps[id(run)]
            if f == "map"
            else run.level
            if f == "level"
            else _key_text(mission_field(run.mission, f))
            for f in fields
        )
        groups.setdefault(key, Group(key)).runs.append(run)
    return list(groups.values())


def mixed_map_warning(groups: list[Group]) -> str | None:
    """One sentence when a group averages runs made on different maps (only an explicit --group-by does)."""
    mixed = [g for g in groups if len({r.map_key for r in g.runs}) > 1]
    if not mixed:
        return None
    listed = "; ".join(f"'{g.label}' ({', '.join(sorted(set(map_labels(g.runs).values())))})" for g in mixed)
    return (
        f"{len(mixed)} group{'s' if len(mixed) > 1 else ''} average runs made on different maps, as --group-by "
        f"asked: {listed}; their metrics are not directly comparable (add 'map' to --group-by to split them)."
    )


def status_warning(runs: list[Run]) -> str | None:
    odd = [r for r in runs if not r.complete]
    if not odd:
        return None
    listed = ", ".join(f"{r.name} ({r.status})" for r in odd)
    return (
        f"{len(odd)} of {len(runs)} runs did not complete: {listed}; group means leave them out where the "
        "group has complete runs ('unfinished' = the manifest still says running: killed, or still going)."
    )

"""Run directories: written as the mission goes, so a crash or Ctrl-C loses nothing.

Layout (format ``guadal-run`` version 1, described for users in ``docs/run-directory.md``)::

    mission.resolved.yaml   the mission as run: defaults filled in, positions as node ids
    manifest.json           seed, versions, plugins, map, wall-clock times, status
    metrics.csv             one row per step (one hop of the fleet)
    trajectory.csv          one row per vehicle per step (source=plan); GPS fixes (source=gps)
    measurements.csv        one row per sample
    fields.csv              per node at the end: ground truth (if any) and the model's fields

``manifest.json`` says ``"status": "running"`` from the first byte; it becomes ``complete``,
``interrupted`` or ``failed`` at the end. A directory still saying ``running`` after its
process is gone was killed. Wall-clock times live only in the manifest so that the CSVs of
the same mission and seed are identical byte for byte at ``sim`` level.
"""

from __future__ import annotations

import csv
import datetime as _dt
import hashlib
import json
import os
import platform
from collections.abc import Iterable, Sequence
from pathlib import Path

import yaml

from . import __version__
from .errors import GuadalError

RUN_FORMAT = "guadal-run"
RUN_VERSION = 1
TRAJECTORY_COLUMNS = ["step", "vehicle", "node", "row", "col", "lat", "lon", "distance", "source", "time_s"]
MEASUREMENT_COLUMNS = ["step", "vehicle", "node", "lat", "lon", "value", "time_s"]


def fmt(value) -> str:
    """Stable text for CSV cells: integers as is, floats with 10 significant digits."""
    if isinstance(value, float):  # most cells, numpy floats included: checked first
        return format(value, ".10g")
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (int, str)):
        return str(value)
    return format(float(value), ".10g")


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class _CsvStream:
    """An append-only CSV that flushes every row batch."""

    def __init__(self, path: Path, columns: Sequence[str]):
        self.columns = list(columns)
        self._fh = open(path, "w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh, lineterminator="\n")
        self._writer.writerow(self.columns)
        self._fh.flush()

    def write(self, rows: Iterable[Sequence]) -> None:
        for row in rows:
            # floats (numpy's included) inline: they are most cells, and a call each adds up
            self._writer.writerow([format(v, ".10g") if isinstance(v, float) else fmt(v) for v in row])
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


class RunRecorder:
    """Creates a run directory and appends to it step by step."""

    def __init__(
        self, directory: Path, resolved_mission: dict, manifest: dict, metric_columns: Sequence[str]
    ):
        directory = Path(directory)
        if directory.exists() and any(directory.iterdir()):
            raise GuadalError(
                f"output directory '{directory}' already exists and is not empty; choose another with --output."
            )
        directory.mkdir(parents=True, exist_ok=True)
        self.directory = directory
        self.manifest = {
            "format": RUN_FORMAT,
            "version": RUN_VERSION,
            **manifest,
            "guadal_version": __version__,
            "python": platform.python_version(),
            "host_cpus": os.cpu_count(),
            "status": "running",
            "started_at": now_iso(),
            "ended_at": None,
            "steps": 0,
            "error": None,
            "metric_columns": list(metric_columns),
        }
        (directory / "mission.resolved.yaml").write_text(yaml.safe_dump(resolved_mission, sort_keys=False))
        self._write_manifest()
        self.metrics = _CsvStream(directory / "metrics.csv", metric_columns)
        self.trajectory = _CsvStream(directory / "trajectory.csv", TRAJECTORY_COLUMNS)
        self.measurements = _CsvStream(directory / "measurements.csv", MEASUREMENT_COLUMNS)

    def _write_manifest(self) -> None:
        tmp = self.directory / "manifest.json.partial"
        tmp.write_text(json.dumps(self.manifest, indent=2) + "\n")
        tmp.replace(self.directory / "manifest.json")

    def write_step(self, step: int, metrics: dict, trajectory_rows: list, measurement_rows: list) -> None:
        self.trajectory.write(trajectory_rows)
        self.measurements.write(measurement_rows)
        self.metrics.write([[metrics[c] for c in self.metrics.columns]])
        self.manifest["steps"] = step

    def write_track(self, rows: list) -> None:
        self.trajectory.write(rows)

    def write_fields(self, graph, ground_truth, fields: dict) -> None:
        """Final per-node maps (truth, mean, std, ...) for reports and plots."""
        names = (["ground_truth"] if ground_truth is not None else []) + sorted(fields)
        columns = ["node", "row", "col", "lat", "lon", *names]
        stream = _CsvStream(self.directory / "fields.csv", columns)
        arrays = ([ground_truth] if ground_truth is not None else []) + [fields[k] for k in sorted(fields)]
        stream.write(
            [i, graph.rows[i], graph.cols[i], graph.lat[i], graph.lon[i], *(a[i] for a in arrays)]
            for i in range(graph.n_nodes)
        )
        stream.close()

    def finish(self, status: str, error: str | None = None, extra: dict | None = None) -> None:
        for stream in (self.metrics, self.trajectory, self.measurements):
            stream.close()
        self.manifest.update(status=status, ended_at=now_iso(), error=error, **(extra or {}))
        self._write_manifest()

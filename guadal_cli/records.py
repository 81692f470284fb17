"""Run directories: written as the mission goes, so a crash or Ctrl-C loses nothing.

Layout (format ``guadal-run`` version 1, described for users in ``docs/run-directory.md``)::

    mission.resolved.yaml   the mission as run: defaults filled in, positions as node ids
    manifest.json           seed, versions, plugins, map, wall-clock times, status
    metrics.csv             one row per step (one hop of the fleet)
    trajectory.csv          one row per vehicle per step (source=plan); GPS fixes (source=gps)
    measurements.csv        one row per sample
    fields.csv              per node at the end: ground truth (if any) and the model's fields

``manifest.json`` says ``"status": "running"`` from the first byte; it becomes ``complete``,
``interrupted`` or ``failed`` at the end. While running it is rewritten (atomically) every few
seconds with the progress so far: steps, mission time and distances. A directory still saying
``running`` after its process is gone was killed. Wall-clock times live only in the manifest so
that the CSVs of the same mission and seed are identical byte for byte at ``sim`` level.

The writing process holds an exclusive lock on ``run.lock`` for as long as it writes, and the
kernel drops it however the process ends (even ``kill -9``): that is how ``guadal resume`` tells
a run that was killed from one that is still going. :meth:`RunRecorder.reopen` cuts the CSVs
back to their last complete step and goes on appending from there.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import hashlib
import json
import os
import platform
import time
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from . import __version__
from .errors import GuadalError, explain_validation_error

#: wall seconds between rewrites of a running manifest's progress
PROGRESS_EVERY_S = 3.0
RUN_FORMAT = "guadal-run"
RUN_VERSION = 1
TRAJECTORY_COLUMNS = ["step", "vehicle", "node", "row", "col", "lat", "lon", "distance", "source", "time_s"]
MEASUREMENT_COLUMNS = ["step", "vehicle", "node", "lat", "lon", "value", "time_s"]
#: vehicles.csv: each vehicle's state for operators (``guadal_cli.fleet.status`` says when a row is due)
VEHICLE_COLUMNS = [
    "step",
    "vehicle",
    "time_s",
    "remaining",
    "mode",
    "armed",
    "battery",
    "link_age_s",
    "fault",
]
#: targets.csv: the node each vehicle was sent to at a planner decision (step = its first hop's)
TARGET_COLUMNS = ["step", "vehicle", "node", "lat", "lon", "time_s"]


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


def _cell(value) -> str:
    """``fmt``, quoted as the csv module quotes (minimal, excel dialect): text holding a comma,
    a quote or a line break."""
    if isinstance(value, float):
        return format(value, ".10g")
    if isinstance(value, str):
        if "," in value or '"' in value or "\n" in value or "\r" in value:
            return '"' + value.replace('"', '""') + '"'
        return value
    return fmt(value)


def _line(row: Sequence) -> str:
    """One CSV line; floats (numpy's included) and ints inline: they are most cells."""
    return (
        ",".join(
            [
                format(v, ".10g") if isinstance(v, float) else str(v) if type(v) is int else _cell(v)
                for v in row
            ]
        )
        + "\n"
    )


def mission_yaml(mission: dict) -> str:
    """A resolved mission as ``mission.resolved.yaml`` holds it: keys in the mission's order,
    written by libyaml where PyYAML has it (the same text, several times faster)."""
    return yaml.dump(mission, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), sort_keys=False)


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def progress(metrics: dict) -> dict:
    """What a running manifest says of the mission so far, from the step's metrics row."""
    distances = {k[len("distance_v") :]: v for k, v in metrics.items() if k.startswith("distance_v")}
    return {
        "steps": metrics["step"],
        "mission_time_s": round(float(metrics["time_s"]), 3),
        "total_distance_m": round(float(metrics["total_distance"]), 3),
        "distance_m": {v: round(float(d), 3) for v, d in distances.items()},
    }


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class RecordSink:
    """Receives the run as the recorder writes it, each part right after it is on disk.

    The run directory stays the ground truth: a sink (the database writer, ``guadal_cli.db``)
    must neither raise into the mission nor make it wait. ``first_row`` is the 0-based index of
    the first row in its CSV file, which makes a key that repeats harmlessly.
    """

    def started(self, directory: Path, manifest: dict, mission: dict) -> None: ...

    def resumed(self, directory: Path, manifest: dict, mission: dict) -> None:
        """A run goes on after an interruption (``RunRecorder.reopen``): its files were cut back
        to ``manifest["resumes"][-1]["after_step"]`` and rows are appended after them."""

    def appended(self, table: str, first_row: int, rows: list, columns: list | None = None) -> None: ...

    def finished(self, manifest: dict) -> None: ...


class _CsvStream:
    """An append-only CSV that flushes every row batch (``append``: go on after existing rows).

    Rows are formatted here, not by the csv module: one string and one write per batch
    (the mission appends a few short rows to several files at every hop, and per-row calls add
    up). The text is what ``csv.writer`` writes, as a test checks.
    """

    def __init__(self, path: Path, columns: Sequence[str], append: bool = False):
        self.columns = list(columns)
        self._fh = open(path, "a" if append else "w", newline="", encoding="utf-8")
        if not append:
            self._fh.write(_line(self.columns))
        self._fh.flush()
        # rows so far, header aside (appending: the file was cut back to whole lines)
        self.rows_written = max(Path(path).read_bytes().count(b"\n") - 1, 0) if append else 0

    def write(self, rows: Iterable[Sequence]) -> None:
        rows = rows if isinstance(rows, list) else list(rows)
        if rows:
            self._fh.write("".join(map(_line, rows)))
            self.rows_written += len(rows)
        self._fh.flush()

    def write_columns(self, first: Sequence[int], *columns: Sequence) -> None:
        """Whole columns at once: an integer id column, then numeric ones.

        One ``str.format`` per row instead of one call per cell: the per-node fields of a
        million-node lake are written in seconds. Cells come out as ``fmt`` writes them.
        """
        line = ",".join(["{}"] + ["{:.10g}"] * len(columns)) + "\n"
        for start in range(0, len(first), 65536):  # in slices: bounded memory for the text
            part = slice(start, start + 65536)
            cells = [np.asarray(first[part]).tolist()] + [
                np.asarray(c[part], float).tolist() for c in columns
            ]
            self._fh.write("".join(map(line.format, *cells)))
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


LOCK_NAME = "run.lock"
CSV_FILES = {
    "metrics.csv": None,
    "trajectory.csv": TRAJECTORY_COLUMNS,
    "measurements.csv": MEASUREMENT_COLUMNS,
    "vehicles.csv": VEHICLE_COLUMNS,
    "targets.csv": TARGET_COLUMNS,
}


def _hold_lock(directory: Path):
    """The exclusive writer's lock of a run directory (released by the kernel when we die)."""
    fh = open(directory / LOCK_NAME, "a")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.close()
        raise GuadalError(
            f"run directory '{directory}' is being written by another guadal process right now; "
            "wait for it to end or stop it first."
        ) from None
    return fh


class _Checked(BaseModel):
    # strict: a count written as text is as wrong as one written as a list; extra keys allowed:
    # later versions may add some, these are the ones read
    model_config = ConfigDict(extra="allow", strict=True)


class _MapSummary(_Checked):
    path: str | None = None
    name: str | None = None
    sha256: str | None = None
    shape: list[int | None] | None = None
    lat_bounds: list[float | None] | None = None
    lon_bounds: list[float | None] | None = None
    water_nodes: int | None = None
    cell_size_m: float | None = None


class _Plugin(_Checked):
    name: str | None = None


class _Resume(_Checked):
    after_step: int = -1
    kept_rows: dict[str, int] | None = None


class ManifestContract(_Checked):
    """The keys of ``manifest.json`` that guadal reads back (resume, ``db sync``, reports, sweeps),
    with their types: a damaged or hand-edited manifest is refused in one sentence here rather
    than met as a wrong type deep inside one of them."""

    format: str
    name: str | None = None
    run_id: str | None = None
    seed: int | None = None
    level: str | None = None
    mode: str | None = None
    vehicles: int | None = Field(default=None, ge=0)
    status: str | None = None
    steps: int | None = Field(default=None, ge=0)
    mission_file: str | None = None
    mission_dir: str | None = None
    started_at: str | None = None
    ended_at: str | None = None
    error: str | None = None
    stop_reason: str | None = None
    # absent in a manifest only if it was written before they existed; never null
    map: _MapSummary = Field(default_factory=_MapSummary)
    plugins: dict[str, _Plugin] = Field(default_factory=dict)
    metric_columns: list[str] = Field(default_factory=list)
    resumes: list[_Resume] = Field(default_factory=list)
    events: list[dict] = Field(default_factory=list)
    fleet: dict = Field(default_factory=dict)
    progress: dict | None = None  # None until the first progress is written
    final_metrics: dict | None = None  # None: the run ended before its first step
    model: dict | None = None


def read_manifest(directory: Path) -> dict:
    """A run directory's manifest (checked against :class:`ManifestContract`), or one sentence
    saying why it is not one."""
    path = Path(directory) / "manifest.json"
    if not path.is_file():
        raise GuadalError(f"'{directory}' is not a run directory: it holds no manifest.json.")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not UTF-8, not JSON, huge numbers
        raise GuadalError(f"run directory '{directory}' has an unreadable manifest.json ({exc}).") from None
    if not isinstance(manifest, dict) or manifest.get("format") != RUN_FORMAT:
        raise GuadalError(f"'{path}' is not a guadal run manifest: 'format' must be '{RUN_FORMAT}'.")
    try:
        ManifestContract.model_validate(manifest)
    except ValidationError as exc:
        raise GuadalError(
            f"'{path}' is damaged: " + explain_validation_error(exc, ManifestContract, prefix="manifest")
        ) from None
    return manifest


#: sections of a resolved mission that readers of a run directory look inside
_MISSION_SECTIONS = ("map", "environment", "algorithm", "fleet", "backend", "output")


def read_resolved_mission(directory: Path) -> dict:
    """A run's ``mission.resolved.yaml`` ({} where it has none), or one sentence on what is wrong.

    Readers of finished runs (``db sync``, reports) look inside its sections; ``guadal resume``
    checks it whole, as a mission.
    """
    from .mission import read_mission_file  # here: importing it costs ~0.4 s the recorder need not pay

    path = Path(directory) / "mission.resolved.yaml"
    if not path.is_file() or path.stat().st_size == 0:
        return {}  # as before: a run without one (or with an empty one) is read without it
    mission = read_mission_file(path)  # size, depth, numbers: checked as any mission file is
    sections_ok = all(
        isinstance(mission.get(k) or {}, (dict, str))
        if k == "map"
        else isinstance(mission.get(k) or {}, dict)
        for k in _MISSION_SECTIONS
    )
    if not sections_ok or not isinstance((mission.get("fleet") or {}).get("initial_positions") or [], list):
        raise GuadalError(
            f"'{path}' is damaged: it must be a mission whose "
            f"{', '.join(_MISSION_SECTIONS[1:])} are mappings and fleet.initial_positions a list."
        )
    return mission


def write_manifest(directory: Path, manifest: dict) -> None:
    """Replace a run's manifest atomically: a reader (or a crash) sees the old one or the new one."""
    tmp = Path(directory) / "manifest.json.partial"
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    tmp.replace(Path(directory) / "manifest.json")


def _step_of(line: bytes, n_columns: int) -> int | None:
    """The step of one complete CSV row, or None for a torn or foreign line."""
    if not line.endswith(b"\n"):
        return None
    cells = line.rstrip(b"\n").split(b",")
    if len(cells) != n_columns:
        return None
    try:
        return int(cells[0])
    except ValueError:
        return None


def cut_to_last_step(directory: Path, metric_columns: Sequence[str]) -> int:
    """Cut the CSVs of an interrupted run back to its last complete step, and return that step.

    A step is complete when its metrics row is (it is written last). Anything after it, a torn
    last line included, is what the interrupted process was writing; it is dropped and written
    again on resume. Returns -1 when not even step 0 was recorded (the CSVs keep their header).
    """
    columns = {**CSV_FILES, "metrics.csv": list(metric_columns)}
    last = -1
    for name in columns:  # metrics.csv first: it says which step is the last complete one
        path = Path(directory) / name
        header = (",".join(columns[name]) + "\n").encode()
        data = path.read_bytes() if path.is_file() else b""
        if not data.startswith(header):
            path.write_bytes(header)
            continue
        keep = len(header)
        for line in data[len(header) :].splitlines(keepends=True):
            step = _step_of(line, len(columns[name]))
            if step is None or (name != "metrics.csv" and step > last):
                break
            if name == "metrics.csv":
                last = step
            keep += len(line)
        if keep < len(data):
            with open(path, "r+b") as fh:
                fh.truncate(keep)
    return last


class RunRecorder:
    """Creates a run directory and appends to it step by step.

    Steps up to ``replay_until`` are already on disk (a resumed run replays them): writing them
    again is skipped, so a resumed run's CSVs are those of an uninterrupted one.
    """

    def __init__(
        self,
        directory: Path,
        resolved_mission: dict,
        manifest: dict,
        metric_columns: Sequence[str],
        progress_every_s: float = PROGRESS_EVERY_S,
        sinks: Sequence[RecordSink] = (),
    ):
        directory = Path(directory)
        if directory.exists() and any(directory.iterdir()):
            raise GuadalError(
                f"output directory '{directory}' already exists and is not empty; choose another with --run-dir."
            )
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise GuadalError(
                f"cannot create the run directory '{directory}': {exc.strerror or exc}."
            ) from exc
        self.directory = directory
        self._lock = _hold_lock(directory)
        self.replay_until = -1
        self.sinks = list(sinks)
        self.manifest = {
            "format": RUN_FORMAT,
            "version": RUN_VERSION,
            "run_id": uuid.uuid4().hex,  # the run's key in a database
            **manifest,
            "guadal_version": __version__,
            "python": platform.python_version(),
            "host_cpus": os.cpu_count(),
            "status": "running",
            "started_at": now_iso(),
            "ended_at": None,
            "steps": 0,
            "progress": None,
            "error": None,
            "metric_columns": list(metric_columns),
            "resumes": [],
        }
        for sink in self.sinks:  # before the manifest: an interrupt then finds nothing half-started
            sink.started(directory, dict(self.manifest), resolved_mission)
        (directory / "mission.resolved.yaml").write_text(mission_yaml(resolved_mission))
        self.progress_every_s = progress_every_s
        self._write_manifest()
        self._progress_written = time.monotonic()
        self._open_streams(append=False)

    @classmethod
    def reopen(
        cls, directory: Path, metric_columns: Sequence[str], sinks: Sequence[RecordSink] = ()
    ) -> RunRecorder:
        """Go on writing an interrupted run; its manifest records this resume."""
        self = cls.__new__(cls)
        self.directory = Path(directory)
        self.sinks = list(sinks)
        self._lock = _hold_lock(self.directory)
        self.manifest = read_manifest(self.directory)
        if self.manifest.get("metric_columns") != list(metric_columns):
            raise GuadalError(
                f"cannot resume '{directory}': its metrics.csv columns are not those this mission writes "
                "(the mission or its plugins changed since the run began)."
            )
        self.progress_every_s = PROGRESS_EVERY_S
        self._progress_written = time.monotonic()
        self.replay_until = cut_to_last_step(self.directory, metric_columns)
        (self.directory / "fields.csv").unlink(missing_ok=True)  # written anew when the run ends
        self.manifest.setdefault("resumes", []).append(
            {
                "after_step": self.replay_until,
                "previous_status": self.manifest.get("status"),
                "previous_error": self.manifest.get("error"),
                "started_at": now_iso(),
            }
        )
        self.manifest.update(status="running", ended_at=None, error=None, steps=max(self.replay_until, 0))
        self._open_streams(append=True)
        # what the cut kept of each row file: a database mirror drops what it holds beyond that
        self.manifest["resumes"][-1]["kept_rows"] = {
            table: stream.rows_written for table, stream in self._streams()
        }
        self._write_manifest()
        if self.sinks:
            resolved = read_resolved_mission(self.directory)
            for sink in self.sinks:
                sink.resumed(self.directory, dict(self.manifest), resolved)
        return self

    def _streams(self) -> list[tuple[str, _CsvStream]]:
        """The row files by the name their rows go to the sinks under."""
        return [
            ("metrics", self.metrics),
            ("trajectory", self.trajectory),
            ("measurements", self.measurements),
            ("vehicles", self.vehicles),
            ("targets", self.targets),
        ]

    def _open_streams(self, append: bool) -> None:
        d = self.directory
        self.metrics = _CsvStream(d / "metrics.csv", self.manifest["metric_columns"], append)
        self.trajectory = _CsvStream(d / "trajectory.csv", TRAJECTORY_COLUMNS, append)
        self.measurements = _CsvStream(d / "measurements.csv", MEASUREMENT_COLUMNS, append)
        self.vehicles = _CsvStream(d / "vehicles.csv", VEHICLE_COLUMNS, append)
        self.targets = _CsvStream(d / "targets.csv", TARGET_COLUMNS, append)

    #: the metrics row of the last step written, not yet in the manifest's progress
    _progress_of: dict | None = None

    def _write_manifest(self, updated_at: str | None = None) -> None:
        if self._progress_of is not None:
            self.manifest["progress"] = progress(self._progress_of)
            self._progress_of = None
        if updated_at is not None:
            self.manifest["progress"]["updated_at"] = updated_at
        write_manifest(self.directory, self.manifest)

    def write_step(self, step: int, metrics: dict, trajectory_rows: list, measurement_rows: list) -> None:
        self.manifest["steps"] = step
        if step <= self.replay_until:
            return  # on disk already
        self._append("trajectory", self.trajectory, trajectory_rows)
        self._append("measurements", self.measurements, measurement_rows)
        self._append("metrics", self.metrics, [[metrics[c] for c in self.metrics.columns]])
        self._progress_of = metrics  # made into the manifest's progress when it is next written
        now = time.monotonic()
        if now - self._progress_written >= self.progress_every_s:
            self._write_manifest(updated_at=now_iso())
            self._progress_written = now

    def write_track(self, step: int, rows: Iterable[Sequence]) -> None:
        if step > self.replay_until:
            self._append("trajectory", self.trajectory, list(rows))

    def write_vehicles(self, step: int, rows: list) -> None:
        """Vehicle state rows (``VEHICLE_COLUMNS``) of a step: written before the step's metrics row,
        so a complete step always has them."""
        if step > self.replay_until and rows:
            self._append("vehicles", self.vehicles, rows)

    def write_targets(self, step: int, rows: list) -> None:
        """One planner decision (``TARGET_COLUMNS``), labelled with the step of its first hop."""
        if step > self.replay_until and rows:
            self._append("targets", self.targets, rows)

    def _append(self, table: str, stream: _CsvStream, rows: list, columns: list | None = None) -> None:
        first = stream.rows_written
        stream.write(rows)
        for sink in self.sinks:
            sink.appended(table, first, rows, columns)

    def write_fields(self, graph, ground_truth, fields: dict) -> None:
        """Final per-node maps (truth, mean, std, ...) for reports and plots."""
        names = (["ground_truth"] if ground_truth is not None else []) + sorted(fields)
        columns = ["node", "row", "col", "lat", "lon", *names]
        stream = _CsvStream(self.directory / "fields.csv", columns)
        arrays = ([ground_truth] if ground_truth is not None else []) + [fields[k] for k in sorted(fields)]
        stream.write_columns(np.arange(graph.n_nodes), graph.rows, graph.cols, graph.lat, graph.lon, *arrays)
        if self.sinks:  # the database gets the same cells as rows
            rows = [
                [i, graph.rows[i], graph.cols[i], graph.lat[i], graph.lon[i], *(a[i] for a in arrays)]
                for i in range(graph.n_nodes)
            ]
            for sink in self.sinks:
                sink.appended("fields", 0, rows, columns)
        stream.close()

    def share_fields(self, step: int, fields: dict) -> None:
        """The model's maps now, for live viewers: to the sinks only (the directory keeps the final ones)."""
        row = [step, {name: values.tolist() for name, values in fields.items()}]
        for sink in self.sinks:
            sink.appended("field_snapshots", step, [row])

    def record_event(self, kind: str, vehicle: int | None, time_s: float, message: str, detail: dict) -> None:
        """A fleet event (an operator's control, ...): in the manifest now, and passed on to the sinks."""
        events = self.manifest.setdefault("events", [])
        entry = {"kind": kind, "vehicle": vehicle, "time_s": time_s, "message": message, **detail}
        events.append(entry)
        self._write_manifest()
        for sink in self.sinks:
            sink.appended("events", len(events) - 1, [[kind, vehicle, time_s, message, entry]])

    def finish(self, status: str, error: str | None = None, extra: dict | None = None) -> None:
        for _, stream in self._streams():
            stream.close()
        self.manifest.update(status=status, ended_at=now_iso(), error=error, **(extra or {}))
        self._write_manifest()
        self._lock.close()
        for sink in self.sinks:
            sink.finished(dict(self.manifest))

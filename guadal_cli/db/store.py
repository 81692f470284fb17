"""Putting a run into the database: the one place that turns run-directory rows into table rows.

The live writer, the spool replay and ``guadal db import``/``sync`` all go through
:func:`save_run` and :func:`save_rows`. Inserts skip rows whose idempotent key is already
there, so any of them may repeat what another did.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path

from sqlalchemy import delete, func, select, text, update

from ..records import MEASUREMENT_COLUMNS, TARGET_COLUMNS, TRAJECTORY_COLUMNS, VEHICLE_COLUMNS
from .models import ROW_TABLES, Map, Run, Vehicle

FIELD_KEYS = ["node", "row", "col", "lat", "lon"]
EVENT_COLUMNS = ["kind", "vehicle", "time_s", "message", "detail"]
#: PostgreSQL channel told the run uid after every commit (the web console listens on it)
NOTIFY_CHANNEL = "guadal_rows"


def cell(value):
    """A value as its CSV cell reads back: floats rounded to the CSV's 10 significant digits."""
    if isinstance(value, float):
        return float(format(value, ".10g"))
    if isinstance(value, str):
        return value or None  # an empty cell (a GPS fix has no node) is NULL
    if value is None:
        return None
    if isinstance(value, (dict, list)):
        return value  # an event's JSON detail is stored as it is
    if isinstance(value, numbers.Integral):  # bool and numpy integers too
        return int(value)
    return float(format(float(value), ".10g"))


def parse_cell(text_value: str):
    """A CSV cell back to a value: '' is None, then int, float, or the text itself."""
    if text_value == "":
        return None
    try:
        return int(text_value)
    except ValueError:
        pass
    try:
        return float(text_value)
    except ValueError:
        return text_value


def _json_safe(value):
    """JSON columns cannot hold NaN or infinity: they are kept as the text the CSV shows ('nan', 'inf')."""
    if isinstance(value, float) and not math.isfinite(value):
        return format(value, ".10g")
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


def from_json_safe(value):
    """The inverse of :func:`_json_safe`, for a manifest read back from the database."""
    if isinstance(value, str) and value in ("nan", "inf", "-inf"):
        return float(value)
    if isinstance(value, dict):
        return {k: from_json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json_safe(v) for v in value]
    return value


def run_uid(manifest: dict, directory: Path | None) -> str:
    """The run's key: manifest ``run_id``; for runs older than it, a hash of what names the run."""
    if manifest.get("run_id"):
        return str(manifest["run_id"])
    named = "|".join(
        str(x)
        for x in (
            manifest.get("name"),
            manifest.get("seed"),
            manifest.get("started_at"),
            directory.name if directory else "",
        )
    )
    return "legacy-" + hashlib.sha256(named.encode()).hexdigest()[:32]


def _time(value) -> _dt.datetime | None:
    if not value:
        return None
    try:
        parsed = _dt.datetime.fromisoformat(str(value))
    except ValueError:
        return None
    if parsed.tzinfo is not None:  # stored as naive UTC: SQLite keeps no zone, PostgreSQL's is UTC
        parsed = parsed.astimezone(_dt.timezone.utc)
    return parsed.replace(tzinfo=None)


def map_key(manifest: dict, base: Path | None = None) -> str:
    """The map's identity: the SHA-256 of its file, or of its summary if the file is gone."""
    info = manifest.get("map") or {}
    if info.get("sha256"):
        return info["sha256"]
    path = Path(info["path"]) if info.get("path") else None
    if path is not None and not path.is_absolute() and base is not None:
        path = base / path
    if path is not None and path.is_file():
        return hashlib.sha256(path.read_bytes()).hexdigest()
    summary = {k: v for k, v in info.items() if k != "path"}
    return hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest()


def sensor_name(mission: dict) -> str:
    """What produced the samples: the environment's synthetic sensor or the boats' own probes."""
    backend = mission.get("backend") or {}
    if backend.get("measurements") == "vehicle":
        return "vehicle"
    return f"synthetic:{(mission.get('environment') or {}).get('type', 'unknown')}"


def manifest_events(manifest: dict) -> list[list]:
    """Fleet events the manifest records (faults, dropped messages, resumes, how the run ended)."""
    rows = []
    for entry in manifest.get("events") or []:  # written by features that log events as they go
        if isinstance(entry, dict):
            rows.append(
                [
                    str(entry.get("kind", "event")),
                    entry.get("vehicle"),
                    entry.get("time_s"),
                    entry.get("message"),
                    entry,
                ]
            )
    fleet = manifest.get("fleet") or {}
    for problem in fleet.get("problems") or []:
        rows.append(["fault", None, None, str(problem), None])
    dropped = fleet.get("dropped_messages") or {}
    if dropped:
        rows.append(
            ["dropped_messages", None, None, f"{sum(dropped.values())} MQTT messages ignored", dropped]
        )
    if manifest.get("status") in ("failed", "interrupted"):
        rows.append([manifest["status"], None, None, manifest.get("error"), None])
    return rows


# --- writing ------------------------------------------------------------------------------
def _insert(conn, table):
    if conn.dialect.name == "postgresql":
        from sqlalchemy.dialects.postgresql import insert
    else:
        from sqlalchemy.dialects.sqlite import insert
    return insert(table)


@dataclass
class RunRef:
    """What row conversion needs to know about a run already in the database."""

    id: int
    uid: str
    map_id: int | None
    started_at: _dt.datetime | None
    metric_columns: list = field(default_factory=list)
    sensors: dict = field(default_factory=dict)


def _save_map(conn, manifest: dict, base: Path | None) -> int | None:
    info = manifest.get("map")
    if not info:
        return None
    sha = map_key(manifest, base)
    shape = info.get("shape") or [None, None]
    lat = info.get("lat_bounds") or [None, None]
    lon = info.get("lon_bounds") or [None, None]
    values = dict(
        sha256=sha,
        name=info.get("name"),
        path=info.get("path"),
        rows=shape[0],
        cols=shape[1],
        water_nodes=info.get("water_nodes"),
        cell_size_m=info.get("cell_size_m"),
        lat_min=lat[0],
        lat_max=lat[1],
        lon_min=lon[0],
        lon_max=lon[1],
        summary=info,
    )
    conn.execute(
        _insert(conn, Map.__table__).values(**values).on_conflict_do_nothing(index_elements=["sha256"])
    )
    return conn.execute(select(Map.id).where(Map.sha256 == sha)).scalar_one()


def save_run(conn, manifest: dict, mission: dict, directory: str | None, base: Path | None = None) -> RunRef:
    """Insert or update the run (and its map and vehicles) from its manifest; returns its ref."""
    uid = run_uid(manifest, Path(directory) if directory else None)
    map_id = _save_map(conn, manifest, base)
    plugins = manifest.get("plugins") or {}
    final = manifest.get("final_metrics") or None
    values = dict(
        uid=uid,
        name=str(manifest.get("name", "")),
        directory=directory,
        status=str(manifest.get("status", "unknown")),
        level=manifest.get("level"),
        mode=manifest.get("mode"),
        algorithm=(plugins.get("algorithm") or {}).get("name")
        or (mission.get("algorithm") or {}).get("type"),
        environment=(plugins.get("environment") or {}).get("name")
        or (mission.get("environment") or {}).get("type"),
        seed=manifest.get("seed"),
        vehicles=manifest.get("vehicles"),
        map_id=map_id,
        started_at=_time(manifest.get("started_at")),
        ended_at=_time(manifest.get("ended_at")),
        updated_at=_dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None),
        steps=int(manifest.get("steps") or 0),
        error=manifest.get("error"),
        stop_reason=manifest.get("stop_reason"),
        guadal_version=manifest.get("guadal_version"),
        metric_columns=manifest.get("metric_columns"),
        final_metrics=_json_safe(final) if final else None,
        manifest=_json_safe(json.loads(json.dumps(manifest, default=str))),
        mission=_json_safe(mission),
    )
    changing = {k: v for k, v in values.items() if k != "uid"}
    stmt = _insert(conn, Run.__table__).values(**values)
    conn.execute(stmt.on_conflict_do_update(index_elements=["uid"], set_=changing))
    run_id = conn.execute(select(Run.id).where(Run.uid == uid)).scalar_one()

    sensor = sensor_name(mission)
    starts = (mission.get("fleet") or {}).get("initial_positions") or []
    vehicle_rows = []
    for v in range(int(manifest.get("vehicles") or 0)):
        start = starts[v].get("node") if v < len(starts) and isinstance(starts[v], dict) else None
        distance = (final or {}).get(f"distance_v{v}")
        vehicle_rows.append(
            dict(run_id=run_id, vehicle=v, start_node=start, sensor=sensor, distance=_finite(distance))
        )
    if vehicle_rows:
        stmt = _insert(conn, Vehicle.__table__).values(vehicle_rows)
        conn.execute(
            stmt.on_conflict_do_update(
                index_elements=["run_id", "vehicle"], set_={"distance": stmt.excluded.distance}
            )
        )
    events = manifest_events(manifest)
    if events:
        ref = RunRef(run_id, uid, map_id, values["started_at"])
        save_rows(conn, ref, "events", 0, events)
    return RunRef(
        run_id,
        uid,
        map_id,
        values["started_at"],
        list(manifest.get("metric_columns") or []),
        {v: sensor for v in range(int(manifest.get("vehicles") or 0))},
    )


def _finite(value):
    return value if isinstance(value, (int, float)) and math.isfinite(value) else None


def save_rows(conn, run: RunRef, table: str, first_seq: int, rows: list, columns: list | None = None) -> None:
    """Insert rows ``first_seq, first_seq+1, ...`` of one of the run's files (those already there are skipped)."""
    save_batches(conn, run, table, [(first_seq, rows)], columns)


def save_batches(
    conn, run: RunRef, table: str, batches: list[tuple[int, list]], columns: list | None = None
) -> None:
    """Insert several ``(first_seq, rows)`` batches of one table in one statement."""
    dicts = [d for first, rows in batches if rows for d in _CONVERT[table](run, first, rows, columns)]
    if not dicts:
        return
    model = ROW_TABLES[table]
    key = (
        ["run_id", "step"]
        if table in ("metrics", "field_snapshots")
        else ["run_id", "node"]
        if table == "fields"
        else ["run_id", "seq"]
    )
    conn.execute(_insert(conn, model.__table__).on_conflict_do_nothing(index_elements=key), dicts)
    if table == "fields" and columns is not None:
        conn.execute(
            update(Run).where(Run.id == run.id).values(field_columns=list(columns[len(FIELD_KEYS) :]))
        )
    now = _dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None)
    if table == "metrics":  # the list's stream resends on updated_at
        last = max(d["step"] for d in dicts)
        conn.execute(update(Run).where(Run.id == run.id, Run.steps < last).values(steps=last, updated_at=now))
    elif table == "vehicles":  # the boats were last heard now: a console opened later counts from here
        conn.execute(update(Run).where(Run.id == run.id).values(updated_at=now))


def forget_replaced_rows(conn, run: RunRef, resume: dict) -> None:
    """Before a resumed run is mirrored again: drop the rows its files no longer hold.

    A resume cuts the CSVs back to the last complete step (``resume["after_step"]``, keeping
    ``resume["kept_rows"]`` rows of each file) and writes the rest anew, so rows past the cut in
    the database may differ from the new ones under the same keys, which inserts skip. Rows up
    to the cut stay as they are (a console following the run sees only what is new); without
    ``kept_rows`` (older runs) every file-mirrored row goes, to be read again from the CSVs.
    Final fields are written anew at the end; events are the manifest's, which a resume keeps.
    """
    after_step, kept = int(resume.get("after_step", -1)), resume.get("kept_rows")
    for name, model in ROW_TABLES.items():
        if name == "events":
            continue
        stmt = delete(model).where(model.run_id == run.id)
        if name in ("metrics", "field_snapshots"):
            stmt = stmt.where(model.step > after_step)
        elif name != "fields" and kept is not None:
            stmt = stmt.where(model.seq >= int(kept.get(name, 0)))
        conn.execute(stmt)


def count_rows(conn, run: RunRef) -> int:
    """How many rows the run has in the tables that mirror its CSV files."""
    return sum(
        conn.execute(select(func.count()).select_from(model).where(model.run_id == run.id)).scalar_one()
        for name, model in ROW_TABLES.items()
        if name != "events"
    )


def notify(conn, run: RunRef) -> None:
    """Tell PostgreSQL listeners (the web console) that the run has new rows; SQLite readers poll ids."""
    if conn.dialect.name == "postgresql":
        conn.execute(text("SELECT pg_notify(:channel, :uid)"), {"channel": NOTIFY_CHANNEL, "uid": run.uid})


def _metrics(run, first, rows, columns):
    names = run.metric_columns
    out = []
    for row in rows:
        values = dict(zip(names, row))
        out.append(
            dict(
                run_id=run.id,
                step=int(values.get("step", first)),
                time_s=_finite(values.get("time_s")),
                total_distance=_finite(values.get("total_distance")),
                samples=values.get("samples"),
                coverage=_finite(values.get("coverage")),
                metrics={k: _json_safe(v) for k, v in values.items()},
            )
        )
        first += 1
    return out


def _measurements(run, first, rows, columns):
    out = []
    for seq, row in enumerate(rows, first):
        d = dict(zip(MEASUREMENT_COLUMNS, row))
        time_s = d["time_s"]
        taken = (
            run.started_at + _dt.timedelta(seconds=time_s)
            if run.started_at is not None and isinstance(time_s, (int, float)) and math.isfinite(time_s)
            else None
        )
        d.update(
            run_id=run.id, seq=seq, taken_at=taken, sensor=run.sensors.get(d["vehicle"]), map_id=run.map_id
        )
        out.append(d)
    return out


def _trajectory(run, first, rows, columns):
    return [dict(zip(TRAJECTORY_COLUMNS, row), run_id=run.id, seq=seq) for seq, row in enumerate(rows, first)]


def _vehicles(run, first, rows, columns):
    out = []
    for seq, row in enumerate(rows, first):
        d = dict(zip(VEHICLE_COLUMNS, row), run_id=run.id, seq=seq)
        d["armed"] = None if d["armed"] is None else bool(d["armed"])
        for key in ("time_s", "remaining", "battery", "link_age_s"):
            d[key] = _finite(d[key])
        out.append(d)
    return out


def _targets(run, first, rows, columns):
    return [dict(zip(TARGET_COLUMNS, row), run_id=run.id, seq=seq) for seq, row in enumerate(rows, first)]


def _events(run, first, rows, columns):
    return [dict(zip(EVENT_COLUMNS, row), run_id=run.id, seq=seq) for seq, row in enumerate(rows, first)]


def _fields(run, first, rows, columns):
    names = list(columns[len(FIELD_KEYS) :])
    out = []
    for row in rows:
        d = dict(zip(FIELD_KEYS, row))
        d.update(run_id=run.id, values={n: _json_safe(v) for n, v in zip(names, row[len(FIELD_KEYS) :])})
        out.append(d)
    return out


def _field_snapshots(run, first, rows, columns):
    """``[step, {name: [value per node]}]`` rows; 6 significant digits are plenty for a colour."""

    def short(v):
        return _json_safe(float(format(v, ".6g"))) if isinstance(v, float) else v

    return [
        dict(run_id=run.id, step=int(step), values={n: [short(v) for v in vs] for n, vs in values.items()})
        for step, values in rows
    ]


_CONVERT = {
    "metrics": _metrics,
    "measurements": _measurements,
    "trajectory": _trajectory,
    "events": _events,
    "fields": _fields,
    "field_snapshots": _field_snapshots,
    "vehicles": _vehicles,
    "targets": _targets,
}

"""The read API over a mission database, for ``guadal db``, ``guadal report --db`` and the web console.

Every function takes an engine from :func:`open_database` and returns plain JSON-ready dicts
(times as ISO 8601 text). Growing tables are read incrementally: pass the largest ``id`` you
have seen as ``after_id`` and get only newer rows, oldest first. Within one run ids only grow
(one writer per run), so polling ``after_id`` every second is cheap and misses nothing; on
PostgreSQL the writer also sends ``NOTIFY guadal_rows, '<run uid>'`` after each commit.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Sequence

from sqlalchemy import and_, func, or_, select

from ..errors import GuadalError
from .engine import current_revision, make_engine, redact
from .models import (
    Event,
    FieldValue,
    Map,
    Measurement,
    Run,
    Step,
    Target,
    TrajectoryPoint,
    Vehicle,
    VehicleStatus,
)

#: filters ``list_runs`` accepts (``guadal db runs`` options, ``guadal report --where KEY=VALUE``)
RUN_FILTERS = ("map", "algorithm", "environment", "level", "status", "name", "since", "until")


def open_database(url: str):
    """An engine for reading an existing guadal database, or one sentence on why there is none."""
    from sqlalchemy.exc import SQLAlchemyError

    engine = make_engine(url)
    try:
        revision = current_revision(engine)
    except SQLAlchemyError as exc:
        raise GuadalError(f"cannot open database {redact(url)}: {str(exc).splitlines()[0]}.") from None
    if revision is None:
        raise GuadalError(f"{redact(url)} is not a guadal database yet; create it with 'guadal db init'.")
    return engine


def _plain(row) -> dict:
    out = {}
    for key, value in row._mapping.items():
        if isinstance(value, _dt.datetime):  # SQLite gives back naive UTC
            value = (value if value.tzinfo else value.replace(tzinfo=_dt.timezone.utc)).isoformat()
        out[key] = value
    return out


def parse_time(value: str | _dt.datetime | None, what: str) -> _dt.datetime | None:
    """ISO 8601 date or time (UTC unless it says otherwise), or one sentence on what is wrong."""
    if value is None:
        return None
    if isinstance(value, _dt.datetime):
        return _utc(value)
    try:
        parsed = _dt.datetime.fromisoformat(value)
    except ValueError:
        raise GuadalError(
            f"{what} '{value}' is not a date or time; use ISO 8601, e.g. 2026-10-01 or 2026-10-01T14:30."
        ) from None
    return _utc(parsed)


def _utc(moment: _dt.datetime) -> _dt.datetime:
    """UTC, naive: how both engines compare stored times (SQLite keeps no zone)."""
    if moment.tzinfo is not None:
        moment = moment.astimezone(_dt.timezone.utc)
    return moment.replace(tzinfo=None)


def _map_clause(ref: str):
    """A map named by name, file path, or SHA-256 (a prefix of 8+ characters will do)."""
    clauses = [Map.name == ref, Map.path == ref]
    if len(ref) >= 8 and all(c in "0123456789abcdef" for c in ref.lower()):
        clauses.append(Map.sha256.like(ref.lower() + "%"))
    return or_(*clauses)


# --- runs ------------------------------------------------------------------------------------
RUN_COLUMNS = (
    Run.id,
    Run.uid,
    Run.name,
    Run.status,
    Run.level,
    Run.mode,
    Run.algorithm,
    Run.environment,
    Run.seed,
    Run.vehicles,
    Run.steps,
    Map.name.label("map"),
    Run.started_at,
    Run.ended_at,
    Run.updated_at,
    Run.directory,
    Run.stop_reason,
    Run.error,
    Run.final_metrics,
)


def list_runs(
    engine,
    *,
    map: str | None = None,
    algorithm: str | None = None,
    environment: str | None = None,
    level: str | None = None,
    status: str | None = None,
    name: str | None = None,
    since=None,
    until=None,
    limit: int | None = None,
) -> list[dict]:
    """Runs, newest first, filtered by any of map, algorithm, environment, level, status, name, dates."""
    stmt = select(*RUN_COLUMNS).outerjoin(Map, Run.map_id == Map.id)
    for column, value in (
        (Run.algorithm, algorithm),
        (Run.environment, environment),
        (Run.level, level),
        (Run.status, status),
        (Run.name, name),
    ):
        if value is not None:
            stmt = stmt.where(column == value)
    if map is not None:
        stmt = stmt.where(_map_clause(map))
    if since is not None:
        stmt = stmt.where(Run.started_at >= parse_time(since, "since"))
    if until is not None:
        stmt = stmt.where(Run.started_at < parse_time(until, "until"))
    stmt = stmt.order_by(Run.started_at.desc(), Run.id.desc()).limit(limit)
    with engine.connect() as conn:
        return [_plain(r) for r in conn.execute(stmt)]


#: the largest row id: ids are 64-bit integers in both databases
MAX_ROW_ID = 2**63 - 1


def get_run(engine, ref: str | int) -> dict:
    """One run with its manifest and resolved mission, by id, uid, or run directory (path or name)."""
    text = str(ref).rstrip("/")
    clauses = [Run.uid == text, Run.directory == text, Run.directory.like("%/" + text)]
    if text.isdigit() and len(text) <= 19 and int(text) <= MAX_ROW_ID:  # a larger number is no row id
        clauses.append(Run.id == int(text))
    stmt = (
        select(*RUN_COLUMNS, Run.manifest, Run.mission, Run.metric_columns, Run.field_columns, Run.map_id)
        .outerjoin(Map, Run.map_id == Map.id)
        .where(or_(*clauses))
        .order_by(Run.id.desc())
    )
    with engine.connect() as conn:
        rows = conn.execute(stmt).all()
    if not rows:
        raise GuadalError(f"no run '{ref}' in the database; 'guadal db runs' lists them.")
    if len({r.id for r in rows}) > 1:
        raise GuadalError(
            f"'{ref}' names {len(rows)} runs; give its id or uid ('guadal db runs' lists them)."
        )
    return _plain(rows[0])


def vehicles(engine, run_id: int) -> list[dict]:
    """Each vehicle of a run: start node, sensor, distance travelled (once the run ended)."""
    stmt = select(*Vehicle.__table__.c).where(Vehicle.run_id == run_id).order_by(Vehicle.vehicle)
    with engine.connect() as conn:
        return [_plain(r) for r in conn.execute(stmt)]


# --- a run's rows, incrementally ---------------------------------------------------------------
def _since(engine, model, run_id: int, after_id: int, limit: int | None, order) -> list[dict]:
    table = model.__table__
    stmt = (
        select(*table.c).where(table.c.run_id == run_id, table.c.id > after_id).order_by(order).limit(limit)
    )
    with engine.connect() as conn:
        return [_plain(r) for r in conn.execute(stmt)]


def steps(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """metrics.csv rows: step, time_s, total_distance, samples, coverage and every metric (``metrics``)."""
    return _since(engine, Step, run_id, after_id, limit, Step.id)


def measurements(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """Samples: vehicle, node, lat, lon, value, time_s, taken_at, sensor."""
    return _since(engine, Measurement, run_id, after_id, limit, Measurement.id)


def trajectory(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """Planned positions (source 'plan') and GPS fixes (source 'gps')."""
    return _since(engine, TrajectoryPoint, run_id, after_id, limit, TrajectoryPoint.id)


def events(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """Faults, failsafes, rejected commands, resumes and how the run ended."""
    return _since(engine, Event, run_id, after_id, limit, Event.id)


def vehicle_status(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """Each vehicle's reported state: remaining budget, mode, armed, battery, link age, fault."""
    return _since(engine, VehicleStatus, run_id, after_id, limit, VehicleStatus.id)


def targets(engine, run_id: int, after_id: int = 0, limit: int | None = None) -> list[dict]:
    """The node each vehicle was sent to at each planner decision (step of its first hop)."""
    return _since(engine, Target, run_id, after_id, limit, Target.id)


def fields(engine, run_id: int) -> list[dict]:
    """The final per-node maps (written when the run ends): node, row, col, lat, lon, values."""
    return _since(engine, FieldValue, run_id, 0, None, FieldValue.node)


def latest_ids(engine, run_id: int | None = None) -> dict[str, int]:
    """The largest id in each growing table (of one run, or all): compare to see if anything changed."""
    out = {}
    with engine.connect() as conn:
        for name, model in (
            ("runs", Run),
            ("steps", Step),
            ("measurements", Measurement),
            ("trajectory", TrajectoryPoint),
            ("events", Event),
            ("vehicles", VehicleStatus),
            ("targets", Target),
        ):
            stmt = select(func.max(model.id))
            if run_id is not None:
                stmt = stmt.where((model.id if model is Run else model.run_id) == run_id)
            out[name] = conn.execute(stmt).scalar() or 0
        updated = select(func.max(Run.updated_at))
        if run_id is not None:
            updated = updated.where(Run.id == run_id)
        stamp = conn.execute(updated).scalar()
        out["runs_updated_at"] = stamp.isoformat() if stamp else None
    return out


# --- samples across runs ---------------------------------------------------------------------
def samples(
    engine,
    map: str,
    *,
    since=None,
    until=None,
    bbox: Sequence[float] | None = None,
    limit: int | None = None,
) -> list[dict]:
    """Every sample taken on a map, optionally in a time window and a box (west, south, east, north)."""
    with engine.connect() as conn:
        map_ids = conn.execute(select(Map.id).where(_map_clause(map))).scalars().all()
    if not map_ids:
        raise GuadalError(f"no map '{map}' in the database; give a map name, path or SHA-256.")
    conditions = [Measurement.map_id.in_(map_ids)]
    if since is not None:
        conditions.append(Measurement.taken_at >= parse_time(since, "since"))
    if until is not None:
        conditions.append(Measurement.taken_at < parse_time(until, "until"))
    if bbox is not None:
        west, south, east, north = bbox
        conditions += [
            Measurement.lat >= south,
            Measurement.lat <= north,
            Measurement.lon >= west,
            Measurement.lon <= east,
        ]
    stmt = (
        select(
            Run.uid.label("run"),
            Run.name.label("mission"),
            Measurement.vehicle,
            Measurement.sensor,
            Measurement.taken_at,
            Measurement.time_s,
            Measurement.lat,
            Measurement.lon,
            Measurement.value,
            Measurement.node,
            Measurement.step,
        )
        .join(Run, Run.id == Measurement.run_id)
        .where(and_(*conditions))
        .order_by(Measurement.taken_at, Measurement.id)
        .limit(limit)
    )
    with engine.connect() as conn:
        return [_plain(r) for r in conn.execute(stmt)]


def parse_bbox(text: str | None) -> tuple[float, float, float, float] | None:
    """'WEST,SOUTH,EAST,NORTH' in degrees (GeoJSON order), or one sentence on what is wrong."""
    if text is None:
        return None
    try:
        west, south, east, north = (float(p) for p in text.split(","))
    except ValueError:
        raise GuadalError(
            f"bbox '{text}' must be four numbers WEST,SOUTH,EAST,NORTH in degrees, e.g. -5.99,37.41,-5.98,37.42."
        ) from None
    if west > east or south > north:
        raise GuadalError(f"bbox '{text}' must have WEST <= EAST and SOUTH <= NORTH.")
    return west, south, east, north

"""The mission database schema: one table per thing a user asks about.

Every table that grows during a mission has a monotonic integer ``id``: a reader (the web
console, ``guadal db``) asks for "rows of run R with id > X" and gets only what is new, cheaply.
Rows written by a mission carry an idempotent key, ``(run_id, seq)`` or ``(run_id, step)``, where
``seq`` is the row's position in its CSV file: the live writer, a replayed spool and
``guadal db sync`` all insert the same keys, and a row that is already there is skipped, so
nothing is written twice.

Values are stored as the CSVs print them (10 significant digits), so a run exported from the
database is the same text as its run directory. Times are UTC, stored without a zone (SQLite
keeps none; PostgreSQL's ``timestamp`` then does not depend on the server's time zone).
"""

from __future__ import annotations

import datetime as _dt

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

#: an auto-increment id: BIGINT on PostgreSQL, INTEGER PRIMARY KEY (the rowid) on SQLite
RowId = BigInteger().with_variant(Integer(), "sqlite")


class Base(DeclarativeBase):
    metadata = MetaData(
        naming_convention={
            "ix": "ix_%(table_name)s_%(column_0_N_name)s",
            "uq": "uq_%(table_name)s_%(column_0_N_name)s",
            "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
            "pk": "pk_%(table_name)s",
        }
    )


class Map(Base):
    """A navigation map, identified by the SHA-256 of its file."""

    __tablename__ = "maps"
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    sha256: Mapped[str] = mapped_column(String(64), unique=True)
    name: Mapped[str | None] = mapped_column(String(200), index=True)
    path: Mapped[str | None] = mapped_column(Text)  # where it was first seen
    rows: Mapped[int | None] = mapped_column(Integer)
    cols: Mapped[int | None] = mapped_column(Integer)
    water_nodes: Mapped[int | None] = mapped_column(Integer)
    cell_size_m: Mapped[float | None] = mapped_column(Float)
    lat_min: Mapped[float | None] = mapped_column(Float)
    lat_max: Mapped[float | None] = mapped_column(Float)
    lon_min: Mapped[float | None] = mapped_column(Float)
    lon_max: Mapped[float | None] = mapped_column(Float)
    summary: Mapped[dict | None] = mapped_column(JSON)


class Run(Base):
    """One mission run: its manifest, resolved mission and status, kept current as it goes."""

    __tablename__ = "runs"
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    uid: Mapped[str] = mapped_column(String(64), unique=True)  # manifest.json "run_id"
    name: Mapped[str] = mapped_column(String(200), index=True)
    directory: Mapped[str | None] = mapped_column(Text)
    status: Mapped[str] = mapped_column(String(20), index=True)
    level: Mapped[str | None] = mapped_column(String(20), index=True)
    mode: Mapped[str | None] = mapped_column(String(20))
    algorithm: Mapped[str | None] = mapped_column(String(100), index=True)
    environment: Mapped[str | None] = mapped_column(String(100), index=True)
    seed: Mapped[int | None] = mapped_column(BigInteger)
    vehicles: Mapped[int | None] = mapped_column(Integer)
    map_id: Mapped[int | None] = mapped_column(ForeignKey("maps.id"), index=True)
    started_at: Mapped[_dt.datetime | None] = mapped_column(DateTime(), index=True)
    ended_at: Mapped[_dt.datetime | None] = mapped_column(DateTime())
    updated_at: Mapped[_dt.datetime | None] = mapped_column(DateTime())
    steps: Mapped[int] = mapped_column(Integer, default=0)
    error: Mapped[str | None] = mapped_column(Text)
    stop_reason: Mapped[str | None] = mapped_column(Text)
    guadal_version: Mapped[str | None] = mapped_column(String(40))
    metric_columns: Mapped[list | None] = mapped_column(JSON)
    field_columns: Mapped[list | None] = mapped_column(JSON)
    final_metrics: Mapped[dict | None] = mapped_column(JSON)
    manifest: Mapped[dict | None] = mapped_column(JSON)
    mission: Mapped[dict | None] = mapped_column(JSON)  # mission.resolved.yaml


class Vehicle(Base):
    """A vehicle of a run: where it started, what it measured with, how far it went."""

    __tablename__ = "run_vehicles"
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), primary_key=True)
    vehicle: Mapped[int] = mapped_column(Integer, primary_key=True)
    start_node: Mapped[int | None] = mapped_column(Integer)
    sensor: Mapped[str | None] = mapped_column(String(100))
    distance: Mapped[float | None] = mapped_column(Float)


class Step(Base):
    """One row of metrics.csv: the fleet after one hop."""

    __tablename__ = "steps"
    __table_args__ = (UniqueConstraint("run_id", "step"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    step: Mapped[int] = mapped_column(Integer)
    time_s: Mapped[float | None] = mapped_column(Float)
    total_distance: Mapped[float | None] = mapped_column(Float)
    samples: Mapped[int | None] = mapped_column(Integer)
    coverage: Mapped[float | None] = mapped_column(Float)
    metrics: Mapped[dict] = mapped_column(JSON)  # every column of the row, task metrics included


class Measurement(Base):
    """One sample (measurements.csv row), with the map and wall-clock time for cross-run queries."""

    __tablename__ = "measurements"
    __table_args__ = (
        UniqueConstraint("run_id", "seq"),
        Index("ix_measurements_map_time", "map_id", "taken_at"),
        Index("ix_measurements_map_position", "map_id", "lat", "lon"),
    )
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    step: Mapped[int] = mapped_column(Integer)
    vehicle: Mapped[int] = mapped_column(Integer)
    node: Mapped[int | None] = mapped_column(Integer)
    lat: Mapped[float | None] = mapped_column(Float)
    lon: Mapped[float | None] = mapped_column(Float)
    value: Mapped[float | None] = mapped_column(Float)
    time_s: Mapped[float | None] = mapped_column(Float)  # mission clock
    taken_at: Mapped[_dt.datetime | None] = mapped_column(DateTime())  # UTC: run start + time_s
    sensor: Mapped[str | None] = mapped_column(String(100))
    map_id: Mapped[int | None] = mapped_column(ForeignKey("maps.id"))


class TrajectoryPoint(Base):
    """One row of trajectory.csv: a planned position (source=plan) or a GPS fix (source=gps)."""

    __tablename__ = "trajectory"
    __table_args__ = (UniqueConstraint("run_id", "seq"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    step: Mapped[int] = mapped_column(Integer)
    vehicle: Mapped[int] = mapped_column(Integer)
    node: Mapped[int | None] = mapped_column(Integer)
    row: Mapped[int | None] = mapped_column(Integer)
    col: Mapped[int | None] = mapped_column(Integer)
    lat: Mapped[float | None] = mapped_column(Float)
    lon: Mapped[float | None] = mapped_column(Float)
    distance: Mapped[float | None] = mapped_column(Float)
    source: Mapped[str] = mapped_column(String(8))
    time_s: Mapped[float | None] = mapped_column(Float)


class Event(Base):
    """Something that happened to the fleet: a fault, a failsafe, a rejected command, a resume."""

    __tablename__ = "events"
    __table_args__ = (UniqueConstraint("run_id", "seq"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    kind: Mapped[str] = mapped_column(String(40), index=True)
    vehicle: Mapped[int | None] = mapped_column(Integer)
    time_s: Mapped[float | None] = mapped_column(Float)
    message: Mapped[str | None] = mapped_column(Text)
    detail: Mapped[dict | None] = mapped_column(JSON)


class FieldValue(Base):
    """One row of fields.csv: the final per-node maps (ground truth, model mean, std, ...)."""

    __tablename__ = "fields"
    __table_args__ = (UniqueConstraint("run_id", "node"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    node: Mapped[int] = mapped_column(Integer)
    row: Mapped[int | None] = mapped_column(Integer)
    col: Mapped[int | None] = mapped_column(Integer)
    lat: Mapped[float | None] = mapped_column(Float)
    lon: Mapped[float | None] = mapped_column(Float)
    values: Mapped[dict] = mapped_column(JSON)  # column name -> value, in fields.csv's order


class Control(Base):
    """An operator's request to a running mission (from the web console), and what became of it.

    The console inserts it; the mission polls for its run's unapplied requests, acts, and sets
    ``applied_at`` and ``outcome``; the action itself is recorded as a fleet event.
    """

    __tablename__ = "controls"
    __table_args__ = (Index("ix_controls_run_pending", "run_id", "applied_at"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    action: Mapped[str] = mapped_column(String(20))
    vehicle: Mapped[int | None] = mapped_column(Integer)
    who: Mapped[str] = mapped_column(String(100))
    origin: Mapped[str | None] = mapped_column(String(100))  # the address the request came from
    requested_at: Mapped[_dt.datetime] = mapped_column(DateTime())  # UTC, as every time here
    applied_at: Mapped[_dt.datetime | None] = mapped_column(DateTime())
    outcome: Mapped[str | None] = mapped_column(Text)


class FieldSnapshot(Base):
    """The model's per-node maps while a mission runs, for live viewers (at most one a second).

    Not part of the run directory, which keeps only the final maps (``fields``).
    """

    __tablename__ = "field_snapshots"
    __table_args__ = (UniqueConstraint("run_id", "step"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    step: Mapped[int] = mapped_column(Integer)
    values: Mapped[dict] = mapped_column(JSON)  # field name -> [value per node], 6 significant digits


class VehicleStatus(Base):
    """One row of vehicles.csv: a vehicle's state as its autopilot reported it, for operators.

    Written at most once a second of mission time per vehicle, and at once when its mode,
    arming or fault changes (``guadal_cli.fleet.status``).
    """

    __tablename__ = "vehicle_status"
    __table_args__ = (UniqueConstraint("run_id", "seq"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    step: Mapped[int] = mapped_column(Integer)
    vehicle: Mapped[int] = mapped_column(Integer)
    time_s: Mapped[float | None] = mapped_column(Float)
    remaining: Mapped[float | None] = mapped_column(Float)  # metres of budget left
    mode: Mapped[str | None] = mapped_column(String(40))
    armed: Mapped[bool | None] = mapped_column(Boolean)
    battery: Mapped[float | None] = mapped_column(Float)  # percent; NULL when not reported (sim)
    link_age_s: Mapped[float | None] = mapped_column(Float)  # NULL without a link (sim)
    fault: Mapped[str | None] = mapped_column(Text)


class Target(Base):
    """One row of targets.csv: the node a vehicle was sent to at a planner decision.

    ``step`` is the step of the first hop towards it.
    """

    __tablename__ = "targets"
    __table_args__ = (UniqueConstraint("run_id", "seq"),)
    id: Mapped[int] = mapped_column(RowId, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)
    step: Mapped[int] = mapped_column(Integer)
    vehicle: Mapped[int] = mapped_column(Integer)
    node: Mapped[int] = mapped_column(Integer)
    lat: Mapped[float | None] = mapped_column(Float)
    lon: Mapped[float | None] = mapped_column(Float)
    time_s: Mapped[float | None] = mapped_column(Float)


#: the tables a run's rows go to, by the name the recorder uses for them
ROW_TABLES = {
    "metrics": Step,
    "measurements": Measurement,
    "trajectory": TrajectoryPoint,
    "events": Event,
    "fields": FieldValue,
    "field_snapshots": FieldSnapshot,
    "vehicles": VehicleStatus,
    "targets": Target,
}

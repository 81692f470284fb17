"""A run out of the database: a run directory (``csv``, the same text the mission wrote) or Parquet.

A run exported as CSV is a normal run directory: ``guadal report`` reads it, and its CSVs are
byte-identical to the original's (values are stored as the CSVs print them).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import GuadalError
from ..records import (
    MEASUREMENT_COLUMNS,
    TARGET_COLUMNS,
    TRAJECTORY_COLUMNS,
    VEHICLE_COLUMNS,
    _CsvStream,
    mission_yaml,
)
from . import queries
from .store import FIELD_KEYS, from_json_safe, parse_cell

FORMATS = ("csv", "parquet")


def _value(v):
    return parse_cell(v) if isinstance(v, str) and v in ("nan", "inf", "-inf") else v


def run_tables(engine, run: dict) -> dict[str, tuple[list[str], list[list]]]:
    """The run's files as (columns, rows), rows in file order (vehicles and targets where it has them)."""
    run_id = run["id"]
    metric_columns = list(run.get("metric_columns") or [])
    steps = queries.steps(engine, run_id)
    if not metric_columns and steps:
        metric_columns = list(steps[0]["metrics"])
    tables = {
        "metrics": (
            metric_columns,
            [
                [_value(s["metrics"].get(c)) for c in metric_columns]
                for s in sorted(steps, key=lambda s: s["step"])
            ],
        ),
        "trajectory": (
            TRAJECTORY_COLUMNS,
            [
                [r[c] for c in TRAJECTORY_COLUMNS]
                for r in sorted(queries.trajectory(engine, run_id), key=_seq)
            ],
        ),
        "measurements": (
            MEASUREMENT_COLUMNS,
            [
                [r[c] for c in MEASUREMENT_COLUMNS]
                for r in sorted(queries.measurements(engine, run_id), key=_seq)
            ],
        ),
    }
    for name, columns, rows in (
        ("vehicles", VEHICLE_COLUMNS, queries.vehicle_status(engine, run_id)),
        ("targets", TARGET_COLUMNS, queries.targets(engine, run_id)),
    ):
        if rows:  # runs recorded before these files have none
            tables[name] = (columns, [[r[c] for c in columns] for r in sorted(rows, key=_seq)])
    field_rows = queries.fields(engine, run_id)
    if field_rows:
        names = list(run.get("field_columns") or field_rows[0]["values"])
        tables["fields"] = (
            FIELD_KEYS + names,
            [[r[k] for k in FIELD_KEYS] + [_value(r["values"].get(n)) for n in names] for r in field_rows],
        )
    return tables


def _seq(row: dict) -> int:
    return row["seq"]


def export_run(engine, ref, destination: Path, fmt: str = "csv") -> Path:
    """Write run ``ref`` (id, uid or directory name) to ``destination``; returns the directory."""
    if fmt not in FORMATS:
        raise GuadalError(f"export format '{fmt}' is not known; use one of {', '.join(FORMATS)}.")
    run = queries.get_run(engine, ref)
    destination = Path(destination)
    if destination.exists() and any(destination.iterdir()):
        raise GuadalError(f"{destination} already exists and is not empty; choose another --output.")
    destination.mkdir(parents=True, exist_ok=True)
    tables = run_tables(engine, run)
    (destination / "manifest.json").write_text(json.dumps(from_json_safe(run["manifest"]), indent=2) + "\n")
    mission = from_json_safe(run["mission"])
    (destination / "mission.resolved.yaml").write_text(mission_yaml(mission))
    if fmt == "csv":
        for name, (columns, rows) in tables.items():
            stream = _CsvStream(destination / f"{name}.csv", columns)
            stream.write(rows)
            stream.close()
    else:
        _write_parquet(destination, tables)
    return destination


def _write_parquet(destination: Path, tables: dict) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise GuadalError(
            "Parquet export needs pyarrow; install it with pip install 'guadal[parquet]'."
        ) from None
    for name, (columns, rows) in tables.items():
        data = {c: [row[i] for row in rows] for i, c in enumerate(columns)}
        pq.write_table(pa.table(data), destination / f"{name}.parquet")


def parse_where(conditions: list[str]) -> dict[str, str]:
    """``KEY=VALUE`` run filters (``guadal report --where``), or one sentence on what is wrong."""
    filters = {}
    for condition in conditions:
        key, sep, value = condition.partition("=")
        key = key.strip()
        if not sep or key not in queries.RUN_FILTERS or not value.strip():
            raise GuadalError(
                f"'{condition}' must be KEY=VALUE with KEY one of {', '.join(queries.RUN_FILTERS)}.",
                field="where",
            )
        filters[key] = value.strip()
    return filters


def export_matching(engine, conditions: list[str], destination: Path) -> list[Path]:
    """Every run matching ``conditions`` exported as a run directory below ``destination``."""
    found = queries.list_runs(engine, **parse_where(conditions))
    if not found:
        shown = " and ".join(conditions) or "any filter"
        raise GuadalError(f"no run in the database matches {shown}; 'guadal db runs' lists them.")
    out = []
    for run in found:
        name = Path(run["directory"]).name if run["directory"] else f"{run['name']}-{run['id']}"
        target = Path(destination) / name
        if target.exists():
            target = Path(destination) / f"{name}-{run['id']}"
        out.append(export_run(engine, run["id"], target))
    return out

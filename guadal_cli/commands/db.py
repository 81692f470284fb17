"""``guadal db``: create, fill and query the mission database (SQLite by default, PostgreSQL by URL)."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from ..console import GuadalGroup, console, print_json, print_table
from ..errors import GuadalError

app = typer.Typer(
    name="db",
    cls=GuadalGroup,
    help="The mission database: every run, step, sample and GPS fix (SQLite beside the runs, or PostgreSQL).",
    no_args_is_help=True,
)

DbOption = Annotated[
    str | None,
    typer.Option(
        "--db",
        help="Database URL: sqlite:///FILE or postgresql://USER@HOST/DB (default: $GUADAL_DB, else runs/guadal.db).",
        show_default=False,
    ),
]
JsonOption = Annotated[bool, typer.Option("--json", help="Print JSON for scripts.")]


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0].rstrip(".")


def _url(db: str | None, runs_dir: Path | None = None) -> str:
    from ..db.engine import resolve_url

    url = resolve_url(db, runs_dir=runs_dir)
    if url is None:
        raise GuadalError("the database is turned off (--db none or GUADAL_DB=none); give a database URL.")
    return url


def _migrate(db: str | None, verb: str) -> None:
    from ..db.engine import current_revision, head_revision, make_engine, redact, upgrade

    url = _url(db)
    try:
        engine = make_engine(url)
        before = current_revision(engine)
        after = upgrade(engine)
    except GuadalError:
        raise
    except Exception as exc:  # the driver's own errors: unreachable server, unwritable file
        raise GuadalError(f"cannot {verb} database {redact(url)}: {_first_line(exc)}.") from None
    change = "already at" if before == after else f"{before or 'empty'} ->"
    console.print(f"database {redact(url)}: schema {change} {after} (this guadal: {head_revision()})")


@app.command("init")
def init(db: DbOption = None) -> None:
    """Create the database and its tables (safe to repeat)."""
    _migrate(db, "create")


@app.command("upgrade")
def upgrade(db: DbOption = None) -> None:
    """Bring a database made by an older guadal to this version's schema."""
    _migrate(db, "upgrade")


def _import(runs: list[Path], db: str | None, as_json: bool, title: str) -> None:
    from sqlalchemy.exc import SQLAlchemyError

    from ..db.engine import ensure_schema, make_engine, redact
    from ..db.ingest import find_run_dirs, import_run

    found = find_run_dirs(runs)
    url = _url(db, runs_dir=found[0].resolve().parent)
    try:
        engine = make_engine(url, writer=True)
        ensure_schema(engine)
        done = [import_run(engine, d) for d in found]
    except SQLAlchemyError as exc:
        raise GuadalError(f"database {redact(url)} refused the rows: {_first_line(exc)}.") from None
    rows = [(str(r.directory.name), r.status, r.rows, r.new_rows, r.uid) for r in done]
    print_table(f"{title} into {redact(url)}", ["run", "status", "rows", "new rows", "uid"], rows, as_json)


@app.command("import")
def import_(
    runs: Annotated[list[Path], typer.Argument(help="Run directories, or folders that contain them.")],
    db: DbOption = None,
    as_json: JsonOption = False,
) -> None:
    """Index existing run directories (idempotent: rows already there are skipped)."""
    _import(runs, db, as_json, "imported")


@app.command("sync")
def sync(
    runs: Annotated[list[Path], typer.Argument(help="Run directories, or folders that contain them.")],
    db: DbOption = None,
    as_json: JsonOption = False,
) -> None:
    """Make the database hold exactly what the run directories hold (after a crash or an outage)."""
    _import(runs, db, as_json, "synced")


def _open(db: str | None):
    from ..db.queries import open_database

    return open_database(_url(db))


@app.command("runs")
def runs(
    db: DbOption = None,
    map: Annotated[str | None, typer.Option("--map", help="Map name, path or SHA-256.")] = None,
    algorithm: Annotated[str | None, typer.Option("--algorithm")] = None,
    environment: Annotated[str | None, typer.Option("--environment")] = None,
    level: Annotated[str | None, typer.Option("--level", help="sim, sitl or real.")] = None,
    status: Annotated[
        str | None, typer.Option("--status", help="running, complete, interrupted, failed.")
    ] = None,
    since: Annotated[str | None, typer.Option("--since", help="Started at or after (ISO 8601, UTC).")] = None,
    until: Annotated[str | None, typer.Option("--until", help="Started before (ISO 8601, UTC).")] = None,
    limit: Annotated[int | None, typer.Option("--limit", min=1)] = None,
    as_json: JsonOption = False,
) -> None:
    """List runs, newest first."""
    from ..db.queries import list_runs

    found = list_runs(
        _open(db),
        map=map,
        algorithm=algorithm,
        environment=environment,
        level=level,
        status=status,
        since=since,
        until=until,
        limit=limit,
    )
    if as_json:
        print_json(found)
        return
    columns = ["id", "name", "status", "level", "algorithm", "map", "steps", "started_at"]
    print_table(f"{len(found)} runs", columns, [[r[c] for c in columns] for r in found])


@app.command("export")
def export(
    run: Annotated[str, typer.Argument(help="Run id, uid or directory name (see 'guadal db runs').")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Directory to create.")],
    db: DbOption = None,
    file_format: Annotated[str, typer.Option("--format", help="csv (a run directory) or parquet.")] = "csv",
) -> None:
    """Write a run from the database as a run directory (CSV) or as Parquet files."""
    from ..db.export import export_run

    where = export_run(_open(db), run, output, file_format.lower())
    console.print(f"run {run} written to {where}")


SAMPLE_COLUMNS = [
    "run",
    "mission",
    "vehicle",
    "sensor",
    "taken_at",
    "time_s",
    "lat",
    "lon",
    "value",
    "node",
    "step",
]


@app.command("samples")
def samples(
    map: Annotated[str, typer.Option("--map", help="Map name, path or SHA-256.")],
    db: DbOption = None,
    since: Annotated[str | None, typer.Option("--since", help="Taken at or after (ISO 8601, UTC).")] = None,
    until: Annotated[str | None, typer.Option("--until", help="Taken before (ISO 8601, UTC).")] = None,
    bbox: Annotated[
        str | None, typer.Option("--bbox", help="WEST,SOUTH,EAST,NORTH in degrees (GeoJSON order).")
    ] = None,
    file_format: Annotated[str, typer.Option("--format", help="csv or geojson.")] = "csv",
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="File to write (default: stdout).")
    ] = None,
) -> None:
    """Every sample taken on a map, across runs, optionally in a time window and a box."""
    from ..db.queries import parse_bbox
    from ..db.queries import samples as query
    from ..records import fmt as cell_text

    if file_format.lower() not in ("csv", "geojson"):
        raise GuadalError(f"samples format '{file_format}' is not known; use csv or geojson.")
    box = parse_bbox(bbox)  # a wrong box is named before the database is opened
    found = query(_open(db), map, since=since, until=until, bbox=box)
    out = open(output, "w", newline="", encoding="utf-8") if output else sys.stdout
    try:
        if file_format.lower() == "csv":
            writer = csv.writer(out, lineterminator="\n")
            writer.writerow(SAMPLE_COLUMNS)
            writer.writerows([[cell_text(r[c]) for c in SAMPLE_COLUMNS] for r in found])
        else:
            features = [
                {
                    "type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [r["lon"], r["lat"]]},
                    "properties": {c: r[c] for c in SAMPLE_COLUMNS if c not in ("lat", "lon")},
                }
                for r in found
            ]
            json.dump({"type": "FeatureCollection", "features": features}, out)
            out.write("\n")
    finally:
        if output:
            out.close()

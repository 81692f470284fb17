"""``guadal db import`` and ``guadal db sync``: a run directory's files into the database.

The CSVs are the ground truth; importing reads them whole and inserts what is missing, so it
is idempotent and also repairs a run whose live writer was cut off (``kill -9``, an outage
that outlived the mission). A last line without its newline (a write cut short) is left out.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError
from ..records import read_manifest, read_resolved_mission
from .store import count_rows, forget_replaced_rows, parse_cell, save_rows, save_run

SPOOL_NAME = "database.spool.jsonl"
_BATCH = 2000
_FILES = (
    ("metrics", "metrics.csv"),
    ("trajectory", "trajectory.csv"),
    ("measurements", "measurements.csv"),
    ("vehicles", "vehicles.csv"),  # runs from before these files have none: nothing to read
    ("targets", "targets.csv"),
)


@dataclass
class Imported:
    directory: Path
    uid: str
    status: str
    rows: int  # rows read from the CSVs
    new_rows: int  # rows the database did not have yet


def read_csv_rows(path: Path) -> tuple[list[str], list[list]]:
    """Header and parsed rows of a CSV; a torn last line (no newline) is dropped."""
    if not path.is_file():
        return [], []
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        data = data[: data.rfind(b"\n") + 1]
    reader = csv.reader(io.StringIO(data.decode("utf-8")))
    header = next(reader, [])
    return header, [[parse_cell(c) for c in row] for row in reader if row]


def read_run(directory: Path) -> tuple[dict, dict]:
    """The manifest and resolved mission of a run directory, or one sentence on what is wrong."""
    return read_manifest(directory), read_resolved_mission(directory)


def import_run(engine, directory: Path) -> Imported:
    """Make the database hold everything in ``directory``; safe to repeat, safe beside a live writer.

    A resumed run first loses the rows past its earliest cut (``forget_replaced_rows``): rows an
    earlier process delivered there would otherwise stand in for the rows written since.
    """
    directory = Path(directory).resolve()
    manifest, mission = read_run(directory)
    with engine.begin() as conn:
        run = save_run(conn, manifest, mission, str(directory), base=directory)
        before = count_rows(conn, run)
        resumes = manifest.get("resumes") or []
        if resumes:  # the earliest cut: what any process delivered after it may have been replaced
            forget_replaced_rows(conn, run, min(resumes, key=lambda r: int(r.get("after_step", -1))))
        total = save_run_files(conn, run, directory)
        new = count_rows(conn, run) - before
    spool = directory / SPOOL_NAME
    if spool.exists():
        spool.unlink()  # everything it held is in the CSVs, and now in the database
    return Imported(directory, run.uid, str(manifest.get("status")), total, max(new, 0))


def save_run_files(conn, run, directory: Path) -> int:
    """Insert what the database lacks of the run directory's CSVs; returns the rows read."""
    total = 0
    for table, name in (*_FILES, ("fields", "fields.csv")):
        header, rows = read_csv_rows(directory / name)
        if table == "metrics" and header:
            run.metric_columns = header
        total += len(rows)
        for start in range(0, len(rows), _BATCH):
            save_rows(
                conn,
                run,
                table,
                start,
                rows[start : start + _BATCH],
                columns=header if table == "fields" else None,
            )
    return total


def find_run_dirs(paths: list[Path]) -> list[Path]:
    """Run directories named, or found one level inside the folders named."""
    found = []
    for path in paths:
        path = Path(path)
        if (path / "manifest.json").is_file():
            found.append(path)
        elif path.is_dir():
            found.extend(sorted(p for p in path.iterdir() if (p / "manifest.json").is_file()))
        else:
            raise GuadalError(f"{path}: no such run directory.")
    if not found:
        raise GuadalError(
            f"no run directories (folders with a manifest.json) in {', '.join(map(str, paths))}."
        )
    return found

"""A run's downloads, made the way ``guadal db export`` and ``guadal report`` make them.

The run comes out of the database as a run directory (so it downloads even where the original
folder is on another machine), then the report's geo exports turn it into GeoJSON, KML and
ground-station plans. Nothing here formats a file of its own.
"""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

from ..db.export import export_run
from ..db.queries import get_run
from ..errors import GuadalError
from ..report import geo
from ..report.runs import file_stem, find_runs

#: kind -> (file suffix, media type)
KINDS = {
    "csv": (".zip", "application/zip"),
    "geojson": (".geojson", "application/geo+json"),
    "kml": (".kml", "application/vnd.google-earth.kml+xml"),
    "plan": ("_plans.zip", "application/zip"),
}


def _zip(files: list[Path], root: Path) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(files):
            archive.write(path, path.relative_to(root).as_posix())
    return buffer.getvalue()


def build_download(engine, run_id: int, kind: str) -> tuple[str, str, bytes]:
    """``(file name, media type, content)`` of one download; LookupError for an unknown run."""
    try:
        run = get_run(engine, run_id)
    except GuadalError as exc:
        raise LookupError(run_id) from exc
    stem = file_stem(f"{run['name']}-{run['id']}")
    suffix, media = KINDS[kind]
    with tempfile.TemporaryDirectory(prefix="guadal-download-") as tmp:
        folder = Path(tmp) / stem
        export_run(engine, run["id"], folder, "csv")
        if kind == "csv":
            return stem + suffix, media, _zip(list(folder.iterdir()), Path(tmp))
        (report_run,) = find_runs([folder])
        written = geo.export_run(report_run, Path(tmp) / "geo")
        if kind == "plan":
            plans = [p for p in written if p.suffix in (".plan", ".waypoints")]
            if not plans:
                raise GuadalError(f"run {run_id} has no planned route yet, so there is no plan to download.")
            return stem + suffix, media, _zip(plans, Path(tmp) / "geo")
        (path,) = [p for p in written if p.suffix == suffix]
        return stem + suffix, media, path.read_bytes()

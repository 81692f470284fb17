"""A sweep's results: its runs for ``guadal report``, and the summary table by its axes.

The summary is the report's own group table (one way to compute mean ± std), grouped by the
swept axes except ``seed``, which is what the means are taken over.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import GuadalError
from .manifest import read_sweep_manifest

SUMMARY_FILES = ("summary.csv", "summary.json", "summary.md")


def sweep_runs(paths: list[Path]):
    """``(runs, axes)`` when the one path given is a sweep directory, else None.

    The runs are the current run directory of each combination (earlier attempts set aside
    beside them are left out); the axes are the swept mission keys, ``seed`` excluded.
    """
    from ..report.runs import find_runs

    if len(paths) != 1:
        return None
    directory = Path(paths[0])
    data = read_sweep_manifest(directory)
    if data is None:
        return None
    dirs = [directory / e["run_dir"] for e in data.get("combinations", []) if isinstance(e, dict)]
    dirs = [d for d in dirs if (d / "manifest.json").is_file()]
    if not dirs:
        raise GuadalError(f"sweep '{directory}' has no run directory yet; run it with 'guadal sweep' first.")
    return find_runs(dirs), [a for a in data.get("axes", []) if a != "seed"]


def summarize(directory: Path):
    """The report of a sweep directory grouped by its axes, and the summary files written."""
    from ..report.build import DEFAULT_GROUP_BY, Options, build
    from ..report.tables import to_csv

    runs, axes = sweep_runs([directory])
    report = build(runs, Options(group_by=axes or list(DEFAULT_GROUP_BY), animate=None))
    directory = Path(directory)
    csv_text = to_csv(report.group_columns, report.group_rows)
    import json

    for name, text in zip(
        SUMMARY_FILES, (csv_text, json.dumps(report.as_json(), indent=2) + "\n", report.markdown())
    ):
        tmp = directory / f".{name}.partial"
        tmp.write_text(text)
        tmp.replace(directory / name)
    return report

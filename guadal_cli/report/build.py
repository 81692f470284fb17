"""Assembling a report: tables from the runs, then (with an output folder) every file.

Layout of the output folder::

    report.html            everything below, tables inline and images embedded
    tables/                runs.csv, groups.csv, report.json, report.md
    figures/               metric_<m>_vs_<x>, map_<run>, track_<run> (PNG and SVG)
    animations/            animation_<run>.gif or .mp4 (every run, the first of each group, or chosen ones)
    geo/                   <run>.geojson, <run>.kml, <run>_v<k>.plan, <run>_v<k>.waypoints
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import GuadalError
from . import geo, plots, tables
from . import html as html_page
from .animate import FORMATS, MAX_FRAMES, animate, ffmpeg_available
from .runs import Group, Run, group_runs, mixed_map_warning, status_warning

#: runs are compared only with runs on the same map at the same level unless --group-by says otherwise
DEFAULT_GROUP_BY = ["map", "level", "algorithm.type"]


@dataclass
class Options:
    group_by: list[str] = field(default_factory=lambda: list(DEFAULT_GROUP_BY))
    x_axis: str = "distance"
    metrics: list[str] | None = None  # curves to draw; None = coverage and every task metric
    animate: str | None = "gif"  # gif, mp4 or None
    animate_runs: str = "all"  # all, first (of each group) or comma-separated run names
    max_frames: int = MAX_FRAMES


@dataclass
class Report:
    runs: list[Run]
    groups: list[Group]
    group_by: list[str]
    run_columns: list[str]
    run_rows: list[list]
    group_columns: list[str]
    group_rows: list[list]
    warnings: list[str]
    files: list[Path] = field(default_factory=list)

    def as_json(self) -> dict:
        return {
            "group_by": self.group_by,
            "warnings": self.warnings,
            "runs": tables.to_records(self.run_columns, self.run_rows),
            "groups": tables.to_records(self.group_columns, self.group_rows),
            "files": [str(p) for p in self.files],
        }

    def display_tables(self) -> list[tuple[str, list[str], list[list[str]]]]:
        """(title, columns, text rows) for people: groups then runs, one table per environment."""
        split = len({r.environment for r in self.runs}) > 1
        out = []
        gcols, grows = tables.folded(self.group_columns, self.group_rows)
        g_envs = [g.runs[0].environment for g in self.groups]
        for env, cols, rows in tables.by_environment(gcols, grows, g_envs):
            where = f" in environment {env}" if split else ""
            n = len(rows)
            out.append(
                (
                    f"{n} group{'s' if n != 1 else ''}{where} by {', '.join(self.group_by)} (mean ± std over complete runs)",
                    cols,
                    rows,
                )
            )
        text = [[tables.cell_text(v) for v in r] for r in self.run_rows]
        for env, cols, rows in tables.by_environment(
            self.run_columns, text, [r.environment for r in self.runs]
        ):
            where = f" in environment {env}" if split else ""
            n = len(rows)
            out.append((f"{n} run{'s' if n != 1 else ''}{where} (final values)", cols, rows))
        return out

    def markdown(self) -> str:
        notes = "".join(f"> warning: {w}\n\n" for w in self.warnings)
        return notes + "\n".join(
            f"## {title}\n\n{tables.to_markdown(cols, rows)}" for title, cols, rows in self.display_tables()
        )


def check_options(options: Options) -> None:
    """Refuse impossible requests before any work is done."""
    if options.x_axis not in plots.X_AXES:
        raise GuadalError(
            f"must be one of {', '.join(plots.X_AXES)} (got '{options.x_axis}').", field="x_axis"
        )
    if options.animate is not None and options.animate not in FORMATS:
        raise GuadalError(
            f"must be one of {', '.join(FORMATS)} or none (got '{options.animate}').", field="animate"
        )
    if not options.group_by:
        raise GuadalError("needs at least one mission field, such as algorithm.type.", field="group_by")
    if options.max_frames < 2:
        raise GuadalError(f"must be at least 2 (got {options.max_frames}).", field="max_frames")


def build(runs: list[Run], options: Options) -> Report:
    """The tables and warnings of a report (reads metrics.csv, and trajectories of GPS runs)."""
    check_options(options)
    warnings = []
    environments = sorted({r.environment for r in runs})
    group_by = list(options.group_by)
    if len(environments) > 1 and "environment.type" not in group_by:
        group_by.insert(0, "environment.type")
        warnings.append(
            f"runs use {len(environments)} environments ({', '.join(environments)}), whose metrics differ; "
            "groups are split by environment.type as well."
        )
    groups = group_runs(runs, group_by)
    names = tables.metric_names(runs)
    run_columns, run_rows = tables.run_table(runs, names)
    gps = [r for r in runs if r.has_gps]
    if gps:
        extra = ["gps_offtrack_mean_m", "gps_offtrack_max_m"]
        summaries = {id(r): plots.deviation_summary(r) for r in gps}
        run_columns += extra
        for run, row in zip(runs, run_rows):
            summary = summaries.get(id(run), {})
            row += [summary.get(c, float("nan")) for c in extra]
    group_columns, group_rows = tables.group_table(groups, group_by, names)
    warnings += [w for w in (mixed_map_warning(groups), status_warning(runs)) if w]
    return Report(runs, groups, group_by, run_columns, run_rows, group_columns, group_rows, warnings)


def curve_metrics(runs: list[Run], wanted: list[str] | None) -> list[str]:
    available = [c for c in ("coverage", *tables.metric_names(runs)) if c not in ("time_s", "total_distance")]
    available = list(dict.fromkeys(available))
    if wanted is None:
        return [c for c in available if c != "samples"]
    unknown = [m for m in wanted if m not in available]
    if unknown:
        raise GuadalError(
            f"no run recorded {', '.join(repr(m) for m in unknown)}; available: {', '.join(available)}.",
            field="metrics",
        )
    return wanted


def animated_runs(report: Report, which: str) -> list[Run]:
    """Every run, the first of each group, or the runs named (a name must be one of the report's)."""
    if which == "all":
        return list(report.runs)
    if which == "first":
        return [g.runs[0] for g in report.groups]
    names = [n.strip() for n in which.split(",") if n.strip()]
    by_name = {r.name: r for r in report.runs}
    unknown = [n for n in names if n not in by_name]
    if unknown or not names:
        raise GuadalError(
            f"must be 'all', 'first' or names of runs in this report ({', '.join(by_name)}); got '{which}'.",
            field="animate_runs",
        )
    return [by_name[n] for n in names]


def write(
    report: Report, out_dir: Path, options: Options, on_file: Callable[[str], None] = lambda what: None
) -> list[str]:
    """Write every table, figure, animation and export; return warnings met on the way."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise GuadalError(f"'{out_dir}' is a file; give a folder for the report.", field="out_dir")
    if options.animate == "mp4" and not ffmpeg_available():
        raise GuadalError(
            "mp4 needs an ffmpeg program on the PATH, and none was found; use gif.", field="animate"
        )
    metrics = curve_metrics(report.runs, options.metrics)
    to_animate = animated_runs(report, options.animate_runs) if options.animate else []
    extra_warnings: list[str] = []
    files = report.files

    tdir = out_dir / "tables"
    tdir.mkdir(parents=True, exist_ok=True)
    for name, text in (
        ("runs.csv", tables.to_csv(report.run_columns, report.run_rows)),
        ("groups.csv", tables.to_csv(report.group_columns, report.group_rows)),
        ("report.md", report.markdown()),
    ):
        (tdir / name).write_text(text)
        files.append(tdir / name)

    fdir = out_dir / "figures"
    curve_figs, map_figs, track_figs = [], [], []
    for metric in metrics:
        on_file(f"curve {metric}")
        curve_figs += [
            (p, f"{metric} against {options.x_axis}")
            for p in plots.metric_curves(report.groups, metric, options.x_axis, fdir)
        ]
    for run in report.runs:
        on_file(f"maps {run.name}")
        map_figs += [(p, f"final maps of {run.name} ({run.status})") for p in plots.final_maps(run, fdir)]
        track_figs += [(p, f"planned path and GPS track of {run.name}") for p in plots.gps_track(run, fdir)]

    anims = []
    if options.animate:
        for run in to_animate:
            on_file(f"animation {run.name}")
            path, warning = animate(run, out_dir / "animations", options.animate, options.max_frames)
            if warning:
                extra_warnings.append(warning)
            if path is not None:
                anims.append((path, f"{run.name} step by step ({run.algorithm}, seed {run.seed})"))

    gdir = out_dir / "geo"
    exports = {}
    for run in report.runs:
        on_file(f"geo {run.name}")
        exports[run.name] = geo.export_run(run, gdir)
        files += exports[run.name]

    for items in (curve_figs, map_figs, track_figs, anims):
        files += [p for p, _ in items]
    report.warnings += extra_warnings
    (tdir / "report.json").write_text(json.dumps(report.as_json(), indent=2) + "\n")
    files.append(tdir / "report.json")
    tables_files = [tdir / n for n in ("runs.csv", "groups.csv", "report.json", "report.md")]

    pngs = lambda items: "".join(html_page.figure(p, c) for p, c in items if p.suffix != ".svg")  # noqa: E731
    page = html_page.page(
        f"guadal report: {len(report.runs)} runs in {len(report.groups)} groups",
        report.warnings,
        [
            *((title, tables.to_html(cols, rows)) for title, cols, rows in report.display_tables()),
            ("Metrics during the mission", pngs(curve_figs)),
            ("Final maps", pngs(map_figs)),
            ("Planned path and GPS track", pngs(track_figs)),
            ("Step by step", pngs(anims)),
            ("Files", html_page.file_links(out_dir, tables_files, exports)),
        ],
    )
    (out_dir / "report.html").write_text(page)
    files.append(out_dir / "report.html")
    return extra_warnings

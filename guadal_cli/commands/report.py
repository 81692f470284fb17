"""``guadal report``: compare run directories as tables, figures, animations and geo files."""

from __future__ import annotations

import sys
from contextlib import ExitStack, contextmanager, nullcontext
from pathlib import Path
from typing import Annotated

import typer

from ..console import console, err_console, flags, print_json

app = typer.Typer()

#: report.build's Options fields (and write's folder), as this command's flags
_FLAGS = {
    "x_axis": "--x",
    "animate": "--animate",
    "group_by": "--group-by",
    "max_frames": "--frames",
    "metrics": "--metrics",
    "out_dir": "--output",
    "animate_runs": "--animate-runs",
    "where": "--where",
}


@app.command("report")
def report(
    runs: Annotated[
        list[Path] | None, typer.Argument(help="Run directories, or folders that contain them.")
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="Folder for the HTML page, figures, animations and geo files; without it only the tables are printed.",
        ),
    ] = None,
    group_by: Annotated[
        str | None,
        typer.Option(
            "--group-by",
            "-g",
            help="Comma-separated 'map', 'level' or dotted fields of the resolved mission to group by "
            "(default: map,level,algorithm.type, or a sweep directory's axes; runs on different maps are "
            "averaged only when asked).",
        ),
    ] = None,
    x_axis: Annotated[
        str,
        typer.Option(
            "--x", help="Metric curves against 'distance' (fleet metres) or 'time' (mission seconds)."
        ),
    ] = "distance",
    metrics: Annotated[
        str | None,
        typer.Option(help="Comma-separated metrics to plot (default: coverage and every task metric)."),
    ] = None,
    animate: Annotated[
        str, typer.Option(help="Step-by-step animations: gif, mp4 (needs ffmpeg) or none.")
    ] = "gif",
    animate_runs: Annotated[
        str,
        typer.Option(help="Which runs to animate: all, first (of each group) or comma-separated run names."),
    ] = "all",
    frames: Annotated[
        int, typer.Option(help="At most this many animation frames (steps are subsampled).")
    ] = 120,
    as_csv: Annotated[
        bool, typer.Option("--csv", help="Print the tables as CSV (runs, a blank line, groups).")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the tables as JSON.")] = False,
    as_markdown: Annotated[bool, typer.Option("--markdown", help="Print the tables as Markdown.")] = False,
    db: Annotated[
        str | None, typer.Option(help="Compare runs from this database (URL) instead of run directories.")
    ] = None,
    where: Annotated[
        list[str] | None,
        typer.Option(help="With --db: KEY=VALUE filter (algorithm, level, map, status, ...); repeatable."),
    ] = None,
) -> None:
    """Compare runs: per-run and per-group tables; with --output also figures, animations, GeoJSON/KML, ground-station plans and one HTML page."""
    from ..errors import GuadalError
    from ..report import tables
    from ..report.build import DEFAULT_GROUP_BY, Options, build, write
    from ..report.runs import find_runs
    from ..sweep.summary import sweep_runs

    if sum((as_csv, as_json, as_markdown)) > 1:
        raise GuadalError("choose one of --csv, --json and --markdown.")
    options = Options(
        group_by=[f.strip() for f in (group_by or "").split(",") if f.strip()],
        x_axis=x_axis,
        metrics=[m.strip() for m in metrics.split(",") if m.strip()] if metrics else None,
        animate=None if animate.lower() == "none" else animate.lower(),
        max_frames=frames,
        animate_runs=animate_runs,
    )
    quiet = as_csv or as_json or as_markdown
    if bool(runs) == bool(db):
        raise GuadalError("give run directories or --db URL (with --where filters), one of the two.")
    # with --db: the matching runs, exported to a folder the report reads
    with ExitStack() as exported, flags(_FLAGS):
        if db:
            runs = [exported.enter_context(runs_from_database(db, where or []))]
        swept = sweep_runs(runs)  # a sweep directory: its runs, grouped by its axes
        found = swept[0] if swept else find_runs(runs)
        if group_by is None:
            options.group_by = (swept[1] if swept else None) or list(DEFAULT_GROUP_BY)
        result = build(found, options)
        if output is not None:
            with console.status("writing report", spinner="dots") if not quiet else nullcontext() as status:

                def on_file(what: str) -> None:
                    if status is not None:
                        status.update(f"writing report: {what}")

                write(result, output, options, on_file)
    for warning in result.warnings:
        err_console.print(f"[yellow]warning:[/] {warning}", soft_wrap=True)
    if as_json:
        print_json(result.as_json())
    elif as_csv:
        sys.stdout.write(tables.to_csv(result.run_columns, result.run_rows) + "\n")
        sys.stdout.write(tables.to_csv(result.group_columns, result.group_rows))
    elif as_markdown:
        sys.stdout.write(result.markdown())
    else:
        for title, columns, rows in result.display_tables():
            _show(title, columns, rows, drop_constant=("map", "level", "vehicles"))
        if output is not None:
            console.print(f"report: {output / 'report.html'}")


#: shorter headers where the terminal is narrow; files and --csv/--json keep the CSV names
SHORT = {
    "total_distance": "distance m",
    "time_s": "time s",
    "coverage": "cover",
    "vehicles": "veh",
    "gps_offtrack_mean_m": "gps off m",
    "gps_offtrack_max_m": "gps max m",
}


def _show(title: str, columns: list[str], rows: list[list[str]], drop_constant=()) -> None:
    """A rich table; columns that hold one value for every row are named in the title instead."""
    from rich.table import Table

    keep = list(range(len(columns)))
    notes = []
    for name in drop_constant:
        if name in columns and rows and len({r[columns.index(name)] for r in rows}) == 1:
            keep.remove(columns.index(name))
            notes.append(f"{name} {rows[0][columns.index(name)]}")
    table = Table(title=title + (f" — {', '.join(notes)}" if notes else ""), title_justify="left")
    for i in keep:
        cells = [r[i] for r in rows if r[i] != ""]
        numeric = bool(cells) and all(_numeric(c) for c in cells)
        header = SHORT.get(columns[i], columns[i])
        widest = max([len(header), *(len(c) for c in cells)])
        table.add_column(
            header,
            no_wrap=True,
            overflow="ellipsis",
            justify="right" if numeric else "left",
            min_width=min(widest, 30) if i == 0 else None,
        )
    status = columns.index("status") if "status" in columns else None
    for row in rows:
        style = None if status is None or row[status] == "complete" else "yellow"
        table.add_row(*(row[i] for i in keep), style=style)
    console.print(table)


def _numeric(text: str) -> bool:
    head = text.split(" ± ")[0]
    try:
        float(head)
    except ValueError:
        return False
    return True


@contextmanager
def runs_from_database(db: str, where: list[str]):
    """A temporary folder holding the runs of database ``db`` that match the ``where`` filters."""
    import tempfile

    from ..db.engine import resolve_url
    from ..db.export import export_matching, parse_where
    from ..db.queries import open_database

    parse_where(where)  # a wrong filter is named before the database is opened
    with tempfile.TemporaryDirectory(prefix="guadal-report-") as folder:
        export_matching(open_database(resolve_url(db)), where, Path(folder))
        yield Path(folder)

"""``guadal sweep``: run a campaign of missions; ``guadal sweep validate``: check it first.

``guadal sweep SWEEP.yaml`` is short for ``guadal sweep run SWEEP.yaml``.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Annotated

import typer

from ..console import GuadalGroup, console, err_console, print_json, print_mapping, print_table
from ..errors import GuadalError


class _RunByDefault(GuadalGroup):
    """``guadal sweep FILE ...`` runs FILE: a first word that is no sub-command means ``run``."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and not args[0].startswith("-"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


app = typer.Typer(
    name="sweep",
    cls=_RunByDefault,
    help="Campaigns of missions: a base mission, axes to vary, seeds; on local processes or a Dask cluster.",
    no_args_is_help=True,
)

SweepFileArg = Annotated[Path, typer.Argument(help="Sweep YAML file (see docs/sweep.md).")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable output.")]


def _plan(sweep_file: Path):
    from ..sweep.plan import plan_sweep
    from ..sweep.spec import load_sweep

    return plan_sweep(load_sweep(sweep_file))


@app.command("validate")
def validate(sweep_file: SweepFileArg, as_json: JsonOpt = False) -> None:
    """Check every combination (schema, plugins, maps, start positions) and count the missions."""
    with err_console.status("checking every combination", spinner="dots"):
        plan = _plan(sweep_file)
    sweep = plan.sweep
    levels = sorted({c.level for c in plan.combinations})
    summary = {
        "sweep": sweep.name,
        "missions": len(plan),
        "axes": ", ".join(f"{k} ({len(v)})" for k, v in {**sweep.grid, **sweep.zip}.items()) or "none",
        "seeds": len(sweep.seeds) if sweep.seeds is not None else "the base mission's",
        "levels": ", ".join(levels),
        "distinct maps": plan.distinct["maps"],
        "distinct plugin sections": plan.distinct["plugin_sections"],
        "sweep directory": str(sweep.output),
        "runs on": sweep.scheduler or f"{sweep.workers or os.cpu_count()} local worker processes",
    }
    print_mapping(f"{sweep_file} is valid: {len(plan)} missions", summary, as_json=as_json)


@app.command("run")
def run(
    sweep_file: SweepFileArg,
    workers: Annotated[
        int | None,
        typer.Option(
            "--workers", "-w", min=1, help="Local worker processes (default: the file's, or one per core)."
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler", help="Run on a Dask cluster: its scheduler's address, e.g. tcp://HOST:8786."
        ),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Sweep directory (default: the file's output).")
    ] = None,
    retries: Annotated[
        int | None,
        typer.Option("--retries", min=0, help="Attempts a failed combination gets beyond its first."),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or table.")] = False,
    as_json: JsonOpt = False,
) -> None:
    """Run every combination not yet complete; re-run the same command to resume."""
    from ..sweep.engine import run_sweep, to_run
    from ..sweep.manifest import SweepManifest
    from ..sweep.plan import plan_sweep
    from ..sweep.spec import load_sweep
    from ..sweep.summary import summarize

    executor = None
    try:
        sweep = load_sweep(sweep_file)
        sweep.output = output or sweep.output
        sweep.retries = sweep.retries if retries is None else retries
        # workers start (and import guadal) while this process checks the plan: on another core
        executor = _executor(scheduler or sweep.scheduler, workers or sweep.workers, len(sweep))
        plan = plan_sweep(sweep)
        manifest = SweepManifest.open(sweep.output, plan)
        todo = to_run(plan, manifest)
    except (GuadalError, KeyboardInterrupt) as exc:
        if executor is not None:
            executor.stop([])
        if isinstance(exc, GuadalError):
            raise  # the app's error boundary says it
        err_console.print("[yellow]interrupted[/] while checking the sweep; nothing was run.")
        raise typer.Exit(130) from None
    show = not (quiet or as_json)
    before = manifest.counts()
    if show:
        skipped = before["complete"]
        exhausted = before["failed"] - sum(1 for c in todo if manifest.entries[c.id]["status"] == "failed")
        notes = [f"{skipped} complete (skipped)"] if skipped else []
        notes += [f"{exhausted} failed with no attempt left (--retries)"] if exhausted else []
        notes += (
            [f"{manifest.dropped} earlier combinations no longer in the file (their runs stay)"]
            if manifest.dropped
            else []
        )
        where = scheduler or sweep.scheduler or f"{workers or sweep.workers or os.cpu_count()} local workers"
        console.print(
            f"sweep {sweep.name}: {len(plan)} missions, {len(todo)} to run on {where}"
            + (f"; {', '.join(notes)}" if notes else "")
        )
    previous_term = signal.signal(signal.SIGTERM, _interrupt)
    try:
        if todo:
            with _progress(len(todo), sweep.name, show) as on_change:
                counts = run_sweep(plan, manifest, executor, todo, on_change)
        else:
            counts = before
            manifest.save(force=True, status="complete" if counts["complete"] == len(plan) else "incomplete")
    except KeyboardInterrupt:
        counts = manifest.counts()
        err_console.print(
            f"[yellow]interrupted[/]: {counts['complete']} of {len(plan)} complete, kept in {sweep.output}; "
            "run the same command again to continue."
        )
        raise typer.Exit(130) from None
    finally:
        signal.signal(signal.SIGTERM, previous_term)
        executor.close()
    try:
        report = summarize(sweep.output) if counts["complete"] else None
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/] while writing the summary; every mission is in sweep.json.")
        raise typer.Exit(130) from None
    failed = [e for e in manifest.entries.values() if e["status"] == "failed"]
    if as_json:
        print_json(
            {
                "directory": str(sweep.output),
                "counts": counts,
                "summary": report.as_json() if report else None,
            }
        )
    elif show:
        if report is not None:
            from ..report.tables import folded

            columns, rows = folded(report.group_columns, report.group_rows)
            print_table(
                f"{sweep.name}: {len(report.groups)} groups by {', '.join(report.group_by)} (mean ± std over seeds)",
                columns,
                rows,
            )
        for entry in failed[:10]:
            err_console.print(f"[red]failed[/] {entry['run_dir']}: {entry['error']}", soft_wrap=True)
        if len(failed) > 10:
            err_console.print(f"... and {len(failed) - 10} more failed; see {sweep.output / 'sweep.json'}")
        console.print(
            f"{counts['complete']} complete, {counts['failed']} failed of {len(plan)}; sweep directory: {sweep.output}"
            + (" (summary.csv, summary.json, summary.md)" if report else "")
        )
    if counts["complete"] != len(plan):
        raise typer.Exit(1)


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # SIGTERM stops a sweep exactly as Ctrl-C does


def _executor(scheduler: str | None, workers: int | None, tasks: int):
    from ..sweep.executors import DaskExecutor, LocalExecutor

    if scheduler:
        return DaskExecutor(scheduler)
    return LocalExecutor(max(1, min(workers or os.cpu_count() or 1, tasks)))


class _progress:
    """A rich progress bar of done/running/failed with an ETA; a no-op when quiet."""

    def __init__(self, total: int, name: str, show: bool):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.total, self.show = total, show
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[counts]}"),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
            console=console,
            disable=not show,
        )
        self.task = self.progress.add_task(name, total=total, counts="")

    def __enter__(self):
        self.progress.__enter__()
        return self.update

    def update(self, counts: dict) -> None:
        self.progress.update(
            self.task,
            completed=counts["finished"],
            counts=f"[green]{counts['complete']} done[/] [cyan]{counts['running']} running[/] "
            f"[red]{counts['failed']} failed[/]",
        )

    def __exit__(self, *exc):
        return self.progress.__exit__(*exc)

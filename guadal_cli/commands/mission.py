"""``guadal run``, ``guadal validate``, ``guadal schema``: the mission commands."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..console import console, err_console, print_json, print_mapping
from ..errors import GuadalError

# the library (numpy, scipy) is imported inside each command, so that `guadal --help` and the
# commands that do not need it start at once

app = typer.Typer()

MissionFile = Annotated[Path, typer.Argument(help="Mission YAML file.")]
AsJson = Annotated[bool, typer.Option("--json", help="Machine-readable output.")]


@app.command("run")
def run(
    mission: MissionFile,
    run_dir: Annotated[
        Path | None,
        typer.Option(
            help="The run directory itself (must be new or empty); default: a new one in the mission's "
            "output.directory."
        ),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Deprecated name of --run-dir.", hidden=True)
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Override the mission's seed.")] = None,
    quiet: Annotated[
        bool,
        typer.Option(
            "--quiet", "-q", help="Print only the run directory (for scripts): no progress bar or summary."
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    db: Annotated[
        str | None,
        typer.Option(
            help="Also write the run to this database: sqlite:///FILE, postgresql://USER@HOST/DB or none "
            "(default: $GUADAL_DB, the mission's output.database, else guadal.db beside the runs)."
        ),
    ] = None,
) -> None:
    """Run a mission and write its run directory."""
    from ..mission import prepare
    from ..runner import MissionRunner

    if output is not None:
        if run_dir is not None:
            raise GuadalError("give the run directory once: --run-dir (--output is its old name).")
        err_console.print(
            "[yellow]note:[/] --output is deprecated for 'guadal run'; it is the run directory itself, "
            "now named --run-dir.",
            soft_wrap=True,
        )
        run_dir = output
    runner = MissionRunner(prepare(mission, seed=seed), output=run_dir, database=db)
    run_with_progress(runner, quiet=quiet, as_json=as_json)


@app.command("validate")
def validate(mission: MissionFile, as_json: AsJson = False) -> None:
    """Check a mission completely (schema, plugins, map, positions) without running it."""
    from ..mission import prepare

    prep = prepare(mission)
    summary = {
        "mission": prep.mission.name,
        "environment": prep.mission.environment.type,
        "algorithm": prep.mission.algorithm.type,
        "mode": prep.mode,
        "level": prep.mission.backend.level,
        "vehicles": prep.mission.fleet.vehicles,
        "initial_nodes": prep.initial_nodes,
        "water_nodes": prep.graph.n_nodes,
    }
    print_mapping(f"{mission} is valid", summary, as_json=as_json)


@app.command("schema")
def schema() -> None:
    """Print the JSON Schema of mission files (for editor completion and checks)."""
    from ..mission import json_schema

    print_json(json_schema())


def run_with_progress(runner, quiet: bool, as_json: bool) -> None:
    """Run (or resume) a mission with a progress bar, then print its result; Ctrl-C keeps the run."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..report.tables import cell_text

    mission = runner.mission
    budget = mission.fleet.max_distance * mission.fleet.vehicles
    show = not (quiet or as_json)
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        console=console,
        disable=not show,
        transient=False,
    )
    task = progress.add_task(mission.name, total=budget, status="")

    def on_step(step: int, fleet) -> None:
        progress.update(task, completed=sum(fleet.distances.values()), status=f"step {step}")

    runner.on_step = on_step
    try:
        with progress:
            result = runner.run()
    except KeyboardInterrupt:
        if runner.output.exists():
            console.print(
                f"[yellow]interrupted[/]: partial results kept in {runner.output} "
                f"(go on with: guadal resume {runner.output})"
            )
        raise typer.Exit(130) from None
    if as_json:
        print_json(
            {
                "directory": str(result.directory),
                "status": result.status,
                "steps": result.steps,
                "metrics": result.final_metrics,
            }
        )
    elif quiet:
        console.print(str(result.directory), soft_wrap=True, markup=False)
    else:
        print_mapping(
            f"{mission.name}: {result.status} after {result.steps} steps",
            {k: cell_text(v) for k, v in result.final_metrics.items()},
        )
        console.print(f"run directory: {result.directory}", soft_wrap=True, markup=False)

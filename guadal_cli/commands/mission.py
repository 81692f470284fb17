"""``guadal run``, ``guadal validate``, ``guadal schema``: the mission commands."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ..console import console, fail, print_json, print_mapping
from ..errors import GuadalError

# the library (numpy, scipy, networkx) is imported inside each command, so that `guadal --help`
# and the commands that do not need it start at once


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run(
        mission: Path = typer.Argument(..., help="Mission YAML file."),
        output: Path | None = typer.Option(
            None, "--output", "-o", help="Run directory to create (must be new or empty)."
        ),
        seed: int | None = typer.Option(None, "--seed", help="Override the mission's seed."),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
    ) -> None:
        """Run a mission and write its run directory."""
        from ..mission import prepare
        from ..runner import MissionRunner

        try:
            runner = MissionRunner(prepare(mission, seed=seed), output=output)
        except GuadalError as exc:
            raise fail(exc)
        run_with_progress(runner, quiet=quiet, as_json=as_json)

    @app.command("validate")
    def validate(
        mission: Path = typer.Argument(..., help="Mission YAML file."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    ) -> None:
        """Check a mission completely (schema, plugins, map, positions) without running it."""
        from ..mission import prepare

        try:
            prep = prepare(mission)
        except GuadalError as exc:
            raise fail(exc)
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
        raise typer.Exit(130)
    except GuadalError as exc:
        raise fail(exc)
    if as_json:
        print_json(
            {
                "directory": str(result.directory),
                "status": result.status,
                "steps": result.steps,
                "metrics": result.final_metrics,
            }
        )
    elif not quiet:
        print_mapping(f"{mission.name}: {result.status} after {result.steps} steps", result.final_metrics)
        console.print(f"run directory: {result.directory}")

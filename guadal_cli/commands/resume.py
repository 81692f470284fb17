"""``guadal resume RUN_DIR``: finish a run that was interrupted, killed or crashed."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .mission import run_with_progress

app = typer.Typer()


@app.command("resume")
def resume(
    run_dir: Annotated[Path, typer.Argument(help="Run directory of an unfinished run.")],
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    db: Annotated[
        str | None,
        typer.Option(
            help="The database the run goes on writing to, brought back in line with its files first "
            "(default: $GUADAL_DB, the mission's output.database, else guadal.db beside the runs). "
            "Give it when the mission's URL had a password: the run directory keeps it masked."
        ),
    ] = None,
) -> None:
    """Go on with an unfinished run where it stopped, appending to its run directory.

    The recorded steps are replayed (nothing is measured twice), then the mission continues
    live; at sim level the result is byte-identical to an uninterrupted run. See docs/resume.md.
    """
    from ..resume import prepare_resume
    from ..runner import MissionRunner

    runner = MissionRunner(prepare_resume(run_dir), output=run_dir, resume=True, database=db)
    run_with_progress(runner, quiet=quiet, as_json=as_json)

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
) -> None:
    """Go on with an unfinished run where it stopped, appending to its run directory.

    The recorded steps are replayed (nothing is measured twice), then the mission continues
    live; at sim level the result is byte-identical to an uninterrupted run. See docs/resume.md.
    """
    from ..resume import prepare_resume
    from ..runner import MissionRunner

    runner = MissionRunner(prepare_resume(run_dir), output=run_dir, resume=True)
    run_with_progress(runner, quiet=quiet, as_json=as_json)

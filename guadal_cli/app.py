"""The ``guadal`` command line: a typer app assembled from ``commands/``.

Its error boundary (:class:`~guadal_cli.console.GuadalGroup`) turns every exception into one
sentence and an exit code; see ``guadal_cli.console`` for the codes.
"""

from __future__ import annotations

import typer

from . import __version__
from .commands import bridge as bridge_cmd
from .commands import db as db_cmd
from .commands import discretize as discretize_cmd
from .commands import map as map_cmd
from .commands import mission as mission_cmd
from .commands import plugins as plugins_cmd
from .commands import report as report_cmd
from .commands import resume as resume_cmd
from .commands import sitl as sitl_cmd
from .commands import stack as stack_cmd
from .commands import sweep as sweep_cmd
from .console import GuadalGroup

app = typer.Typer(
    cls=GuadalGroup,
    name="guadal",
    help="Mission runner for Informative Path Planning: the same planner in sim, SITL and on real boats.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"guadal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool | None = typer.Option(
        None, "--version", callback=_version, is_eager=True, help="Show the version."
    ),
) -> None:
    """guadal: run, validate and compare IPP missions."""


mission_cmd.register(app)
resume_cmd.register(app)
plugins_cmd.register(app)
map_cmd.register(app)
sitl_cmd.register(app)
bridge_cmd.register(app)
stack_cmd.register(app)
discretize_cmd.register(app)
report_cmd.register(app)
app.add_typer(sweep_cmd.app, name="sweep")
app.add_typer(db_cmd.app, name="db")


def main() -> None:
    app()

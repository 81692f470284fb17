"""The ``guadal`` command line: one typer app assembled from the module-level apps in ``commands/``.

Its error boundary (:class:`~guadal_cli.console.GuadalGroup`) turns every exception into one
sentence and an exit code; see ``guadal_cli.console`` for the codes.
"""

from __future__ import annotations

import importlib
from typing import Annotated

import typer

from . import __version__
from .console import GuadalGroup

#: ``commands/<name>.py`` modules, in the order ``guadal --help`` lists them; each defines ``app``
COMMANDS = (
    "mission",
    "resume",
    "plugins",
    "map",
    "sitl",
    "bridge",
    "stack",
    "discretize",
    "report",
    "sweep",
    "db",
    "serve",
)

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
    version: Annotated[
        bool | None, typer.Option("--version", callback=_version, is_eager=True, help="Show the version.")
    ] = None,
) -> None:
    """guadal: run, validate and compare IPP missions."""


# a verb's app holds its command(s), merged here; a noun's app (map, stack) is a group of its own
for name in COMMANDS:
    app.add_typer(importlib.import_module(f".commands.{name}", __package__).app)


def main() -> None:
    app()

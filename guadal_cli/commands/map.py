"""``guadal map ...``: look at map files."""

from __future__ import annotations

from pathlib import Path

import typer

from ..console import fail, print_mapping
from ..errors import GuadalError
from ..maps.format import load_map

map_app = typer.Typer(help="Inspect guadal map files.", no_args_is_help=True)


@map_app.command("info")
def info(
    path: Path = typer.Argument(..., help="A guadal map file."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
) -> None:
    """Grid shape, water nodes, cell size, water area and lat/lon bounds."""
    try:
        summary = load_map(path).summary()
    except GuadalError as exc:
        raise fail(exc)
    print_mapping(f"map {path}", summary, as_json=as_json)


def register(app: typer.Typer) -> None:
    app.add_typer(map_app, name="map")

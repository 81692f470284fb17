"""``guadal map ...``: look at map files."""

from __future__ import annotations

from pathlib import Path

import typer

from ..console import GuadalGroup, console, print_mapping
from ..errors import GuadalError

map_app = typer.Typer(cls=GuadalGroup, help="Inspect guadal map files.", no_args_is_help=True)


@map_app.command("info")
def info(
    path: Path = typer.Argument(..., help="A guadal map file."),
    as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
) -> None:
    """Grid shape, water nodes, cell size, water area and lat/lon bounds."""
    from ..maps.format import load_map

    summary = load_map(path).summary()
    print_mapping(f"map {path}", summary, as_json=as_json)


@map_app.command("show")
def show(
    path: Path = typer.Argument(..., help="A guadal map file."),
    output: Path | None = typer.Option(
        None, "--output", "-o", help="PNG to write (default: the map's name with .png)."
    ),
) -> None:
    """Write a PNG preview of a map: water cells, cell outlines and node centres on lat/lon axes."""
    from ..maps.format import load_map
    from ..maps.preview import preview_map

    target = output or path.with_suffix(".png")
    if target.resolve() == path.resolve():
        raise GuadalError("--output names the map file itself; give the preview a .png name.")
    preview_map(load_map(path), target)
    console.print(f"preview: {target}")


def register(app: typer.Typer) -> None:
    app.add_typer(map_app, name="map")

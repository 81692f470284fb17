"""``guadal map ...``: look at map files."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..console import GuadalGroup, console, print_mapping
from ..errors import GuadalError

app = typer.Typer(name="map", cls=GuadalGroup, help="Inspect guadal map files.", no_args_is_help=True)

MapFile = Annotated[Path, typer.Argument(help="A guadal map file.")]


@app.command("info")
def info(
    path: MapFile,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Grid shape, water nodes, cell size, water area and lat/lon bounds."""
    from ..maps.format import load_map

    print_mapping(f"map {path}", load_map(path).summary(), as_json=as_json)


@app.command("show")
def show(
    path: MapFile,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="PNG to write (default: the map's name with .png).")
    ] = None,
) -> None:
    """Write a PNG preview of a map: water cells, cell outlines and node centres on lat/lon axes."""
    from ..maps.format import load_map
    from ..maps.preview import preview_map

    target = output or path.with_suffix(".png")
    if target.resolve() == path.resolve():
        raise GuadalError("--output names the map file itself; give the preview a .png name.")
    preview_map(load_map(path), target)
    console.print(f"preview: {target}")

"""``guadal plugins``: what is installed, per group, read from metadata without importing."""

from __future__ import annotations

from typing import Annotated

import typer

from .. import plugins
from ..console import print_table

app = typer.Typer()


@app.command("plugins")
def list_plugins(
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """List installed plugins per group (nothing is imported)."""
    rows = [
        (kind, info.name, info.target, f"{info.distribution} {info.version}")
        for kind in plugins.GROUPS
        for info in plugins.available(kind).values()
    ]
    print_table("guadal plugins", ["kind", "name", "target", "package"], rows, as_json=as_json)

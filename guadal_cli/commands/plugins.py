"""``guadal plugins``: what is installed, per group, read from metadata without importing."""

from __future__ import annotations

import typer

from .. import plugins
from ..console import print_table


def register(app: typer.Typer) -> None:
    @app.command("plugins")
    def plugins_cmd(as_json: bool = typer.Option(False, "--json", help="Machine-readable output.")) -> None:
        """List installed plugins per group (nothing is imported)."""
        rows = [
            (kind, info.name, info.target, f"{info.distribution} {info.version}")
            for kind in plugins.GROUPS
            for info in plugins.available(kind).values()
        ]
        print_table("guadal plugins", ["kind", "name", "target", "package"], rows, as_json=as_json)

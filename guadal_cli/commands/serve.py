"""``guadal serve``: the live supervision console in a web browser."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..console import console

app = typer.Typer()


@app.command("serve")
def serve(
    db: Annotated[
        str | None,
        typer.Option("--db", help="Database URL (default: GUADAL_DB, else runs/guadal.db here)."),
    ] = None,
    host: Annotated[
        str, typer.Option("--host", help="Address to listen on; beyond loopback a login is required.")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="TCP port (0: a free one).")] = 8765,
    control: Annotated[
        bool,
        typer.Option("--control", help="Let logged-in operators pause, resume, abort and hold boats."),
    ] = False,
    token_file: Annotated[
        Path | None,
        typer.Option(
            "--token-file",
            help="File of operator secrets, 'name:secret' per line (default: the GUADAL_SERVE_TOKEN variable).",
        ),
    ] = None,
    tiles: Annotated[
        str | None,
        typer.Option(
            "--tiles", help="Background tile URL, e.g. https://host/{z}/{x}/{y}.png (default: none)."
        ),
    ] = None,
) -> None:
    """Serve the mission console: every run in the database, live or replayed, in a browser."""
    from ..web.server import ConsoleServer

    server = ConsoleServer.configure(db, host, port, control, token_file, tiles)

    def ready(url: str) -> None:
        mode = "operator controls on" if control else "view only"
        console.print(f"console: {url}  ({mode}; database {server.database_label})", soft_wrap=True)

    server.run(on_ready=ready)

"""``python -m guadal_cli.sitl``: the same command as ``guadal sitl`` without importing the rest
of the CLI (planners, maps, scientific stack), so a launcher starting many emulators starts fast."""

import typer

from ..commands.sitl import sitl


def main() -> None:
    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
    app.command()(sitl)
    app()


if __name__ == "__main__":
    main()

"""The ``guadal`` command line: a typer app assembled from ``commands/``."""

from __future__ import annotations

import datetime as _dt
import os
import sys
import tempfile
import traceback
from pathlib import Path

import typer
from rich.markup import escape

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

app = typer.Typer(
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


#: exit code of an unforeseen failure (sysexits' EX_SOFTWARE): distinct from bad input (2)
EXIT_BUG = 70


def crash_log_dir() -> Path:
    """Where tracebacks of unforeseen failures go: ``$XDG_STATE_HOME/guadal/crashes``."""
    state = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(state) / "guadal" / "crashes"


def _write_crash_log(exc: BaseException) -> Path | None:
    """The traceback in a new log file (the system's temporary folder if the usual one is not writable)."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
    text = (
        f"guadal {__version__}, python {sys.version.split()[0]}\n"
        f"command: {' '.join(sys.argv)}\n\n" + "".join(traceback.format_exception(exc))
    )
    for folder in (crash_log_dir(), Path(tempfile.gettempdir()) / "guadal-crashes"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{stamp}-{os.getpid()}.log"
            path.write_text(text, encoding="utf-8")
            return path
        except OSError:
            continue
    return None


def main() -> None:
    """The app behind one boundary: bad input is one sentence and exit 2 (in each command); anything
    unforeseen is one sentence naming the log that holds its traceback, and exit 70."""
    try:
        app()
    except Exception as exc:  # a bug: the user gets a sentence, the traceback goes to a file
        from .console import err_console

        path = _write_crash_log(exc)
        where = f"the details are in {path}" if path else "no log could be written"
        command = next((a for a in sys.argv[1:] if not a.startswith("-")), "guadal")
        err_console.print(
            f"[bold red]error:[/] guadal {escape(command)} failed unexpectedly "
            f"({escape(type(exc).__name__)}: {escape(str(exc)[:200])}); this is a bug, please report it "
            f"with the log: {where}.",
            soft_wrap=True,
        )
        sys.exit(EXIT_BUG)

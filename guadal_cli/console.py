"""Shared terminal output: one console, one way to print tables or JSON, one error boundary.

Exit codes of every command: 0 done; 2 bad input (a :class:`GuadalError`: one sentence naming
what is wrong and what is allowed); 70 a bug (any other exception: one sentence naming the
command and a log file that holds the traceback; 70 is ``EX_SOFTWARE`` of sysexits.h);
130 interrupted.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
import traceback
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from typer.core import TyperGroup

from . import __version__
from .errors import GuadalError

# Piped into a file or a CI log, rich would assume 80 columns and squeeze wide tables into "…";
# a terminal keeps its own width (and COLUMNS still wins where set).
_WIDTH = None if sys.stdout.isatty() or os.environ.get("COLUMNS") else 200
console = Console(highlight=False, width=_WIDTH)
err_console = Console(stderr=True, highlight=False, width=_WIDTH)


#: exit codes: bad input (a GuadalError), and a failure nobody foresaw (sysexits' EX_SOFTWARE)
EXIT_BAD_INPUT = 2
EXIT_BUG = 70


@contextmanager
def flags(names: dict[str, str]):
    """Report a library error about one of these fields as the command-line flag it came from.

    ``with flags({"cell_size_m": "--cell-size"}): ...`` turns ``cell_size_m: must be ...``
    into ``--cell-size must be ...``; the library itself never knows about flags.
    """
    try:
        yield
    except GuadalError as exc:
        if exc.file is None and exc.field in names:
            exc.flag = names[exc.field]
        raise


class GuadalGroup(TyperGroup):
    """The one place where exceptions become what a user reads: a sentence and an exit code."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except GuadalError as exc:
            _say(f"[bold red]error:[/] {escape(str(exc))}")
            raise typer.Exit(EXIT_BAD_INPUT) from None
        except (typer.Exit, typer.Abort, BrokenPipeError):
            raise
        except OSError as exc:
            if exc.filename is None:  # not about a path: not the user's to mend
                return self._bug(ctx, exc)
            _say(
                f"[bold red]error:[/] cannot use '{escape(str(exc.filename))}': {escape(exc.strerror or str(exc))}."
            )
            raise typer.Exit(EXIT_BAD_INPUT) from None
        except Exception as exc:
            if _is_click_exception(exc):
                raise
            return self._bug(ctx, exc)

    @staticmethod
    def _bug(ctx, exc: Exception):
        command = " ".join(["guadal", *_command_path(ctx)])
        log = _write_crash_log(command, exc)
        where = f"the details are in {log}" if log else "no log could be written"
        _say(
            f"[bold red]error:[/] {escape(command)} failed unexpectedly ({escape(_summary(exc))}); "
            f"this is a bug, please report it with the log: {escape(where)}."
        )
        raise typer.Exit(EXIT_BUG) from None


def _say(markup: str) -> None:
    err_console.print(markup, soft_wrap=True)


def _is_click_exception(exc: Exception) -> bool:
    # usage errors raised while parsing a subcommand's options: typer prints those itself
    from typer import _click

    return isinstance(exc, _click.exceptions.ClickException)


def _command_path(ctx) -> list[str]:
    """``["stack", "up"]`` for ``guadal stack up``, whatever the program was called."""
    names = [ctx.invoked_subcommand] if ctx.invoked_subcommand else []
    while ctx.parent is not None:
        names.insert(0, ctx.info_name)
        ctx = ctx.parent
    return names


def _summary(exc: Exception) -> str:
    """``Type: first line of the message`` (at most 200 characters, credentials masked)."""
    lines = _CREDENTIALS.sub("://***@", str(exc)).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0][:200]}" if lines else type(exc).__name__


#: credentials in URLs (mqtt://user:password@host) never reach a log file
_CREDENTIALS = re.compile(r"://[^/@\s]+@")


def crash_log_dir() -> Path:
    """Where tracebacks of unexpected errors go: ``$XDG_STATE_HOME/guadal/crashes``."""
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / "guadal" / "crashes"


def _write_crash_log(command: str, exc: Exception) -> Path | None:
    """The traceback, the version and the command, in a new file; None if no folder is writable."""
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    body = (
        f"guadal {__version__} on Python {sys.version.split()[0]}\ncommand: {command}\n"
        f"time: {time.strftime('%Y-%m-%dT%H:%M:%S%z')}\n\n{text}"
    )
    name = f"crash-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.log"
    for folder in (crash_log_dir(), Path(tempfile.gettempdir()) / "guadal-crashes"):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / name
            path.write_text(_CREDENTIALS.sub("://***@", body))
            return path
        except OSError:
            continue
    return None


def print_json(data) -> None:
    sys.stdout.write(json.dumps(data, indent=2, default=str) + "\n")


def print_table(title: str, columns: Sequence[str], rows: Sequence[Sequence], as_json: bool = False) -> None:
    """A rich table for people, or a JSON list of objects for scripts."""
    if as_json:
        print_json([dict(zip(columns, row)) for row in rows])
        return
    table = Table(title=title, title_justify="left")
    for col in columns:
        table.add_column(col)
    for row in rows:
        table.add_row(*("" if v is None else str(v) for v in row))
    console.print(table)


def print_mapping(title: str, data: dict, as_json: bool = False) -> None:
    if as_json:
        print_json(data)
        return
    print_table(title, ["field", "value"], [(k, v) for k, v in data.items()])

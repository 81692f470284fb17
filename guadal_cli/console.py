"""Shared terminal output: one console, one way to print tables or JSON, one way to fail."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Sequence

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .errors import GuadalError

# Piped into a file or a CI log, rich would assume 80 columns and squeeze wide tables into "…";
# a terminal keeps its own width (and COLUMNS still wins where set).
_WIDTH = None if sys.stdout.isatty() or os.environ.get("COLUMNS") else 200
console = Console(highlight=False, width=_WIDTH)
err_console = Console(stderr=True, highlight=False, width=_WIDTH)


def fail(exc: GuadalError | str) -> typer.Exit:
    """Print one error sentence (no traceback) and return the exit to raise."""
    err_console.print(f"[bold red]error:[/] {escape(str(exc))}", soft_wrap=True)
    return typer.Exit(getattr(exc, "exit_code", 2))


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

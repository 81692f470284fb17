"""One CLI style: every ``commands/X.py`` defines a module-level typer app whose commands are
module-level functions with ``Annotated`` parameters, usable (and testable) on their own."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
import typing

import pytest
import typer
from support import LAKE
from typer.testing import CliRunner

from guadal_cli.app import COMMANDS


@pytest.mark.parametrize("name", COMMANDS)
def test_each_command_module_defines_its_app_and_commands_at_module_level(name):
    module = importlib.import_module(f"guadal_cli.commands.{name}")
    assert isinstance(module.app, typer.Typer)
    commands = module.app.registered_commands
    assert commands, f"commands/{name}.py registers no command"
    for info in commands:
        function = info.callback
        assert getattr(module, function.__name__) is function, "a command must be importable by name"
        hints = typing.get_type_hints(function, include_extras=True)
        for parameter in list(hints)[:-1] if "return" in hints else hints:
            assert typing.get_origin(hints[parameter]) is typing.Annotated, (
                f"{name}.{function.__name__}({parameter}) is not an Annotated parameter"
            )


def test_a_command_module_runs_alone():
    from guadal_cli.commands import map as map_commands

    result = CliRunner().invoke(map_commands.app, ["info", str(LAKE), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["water_nodes"] == 351


def test_starting_the_cli_imports_no_scientific_library():
    code = (
        "import sys\n"
        "from guadal_cli.app import app\n"
        "heavy = {'numpy', 'scipy', 'matplotlib', 'pymavlink', 'paho', 'pydantic'} & set(sys.modules)\n"
        "print(sorted(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"

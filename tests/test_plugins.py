"""Plugin contracts: every installed plugin subclasses its kind's base, anything else is one
sentence, nothing beyond the named module is imported, and the schema knows every Config."""

from __future__ import annotations

import json

import jsonschema
import pytest
import yaml
from support import ROOT, base_mission, run_cli

from guadal_cli import plugins
from guadal_cli.errors import GuadalError


@pytest.mark.parametrize("kind", plugins.GROUPS)
def test_every_installed_plugin_honours_its_contract(kind):
    base = plugins.base_class(kind)
    assert plugins.available(kind), f"no {kind} plugin is installed"
    for name in plugins.available(kind):
        cls = plugins.load(kind, name)
        assert issubclass(cls, base) and not getattr(cls, "__abstractmethods__", None)
        assert hasattr(cls, "Config")


@pytest.mark.parametrize(
    "kind, name, expected",
    [
        ("algorithm", "collections:OrderedDict", "'collections', a module of Python's standard library"),
        ("algorithm", "guadal_cli.envs.gp:GPEnvironment", "is class GPEnvironment, not a subclass of"),
        (
            "backend",
            "guadal_cli.plugins:GROUPS",
            "is a dict, not a subclass of guadal_cli.fleet.base.Backend",
        ),
        ("sensor", "guadal_cli.nowhere:Probe", "could not be imported from module 'guadal_cli.nowhere'"),
        ("algorithm", ":", "names no module and object; give 'package.module:Class'"),
        ("algorithm", ".x:Y", "could not be imported from module '.x'"),
    ],
)
def test_anything_but_a_plugin_is_one_sentence(kind, name, expected):
    with pytest.raises(GuadalError, match=expected):
        plugins.load(kind, name)


def test_validate_imports_no_module_of_the_standard_library(tmp_path, write_mission):
    # 'this' prints the Zen of Python when imported: it must not be imported at all
    path = write_mission(base_mission(algorithm={"type": "this:x"}))
    result = run_cli("validate", path)
    assert result.returncode == 2
    assert "Beautiful is better than ugly" not in result.stdout + result.stderr
    assert result.stderr.strip().splitlines() == [
        f"error: {path}: algorithm.type: the algorithm plugin 'this:x' names 'this', a module of Python's "
        "standard library, which holds no guadal plugin; name the plugin's own module, as 'package.module:Class'."
    ]


def test_schema_completes_plugin_parameters_and_accepts_every_example_mission():
    result = run_cli("schema")
    assert result.returncode == 0, result.stderr
    schema = json.loads(result.stdout)
    validator = jsonschema.Draft202012Validator(schema)
    examples = sorted((ROOT / "missions").glob("*.yaml"))
    assert examples
    for path in examples:
        errors = list(validator.iter_errors(yaml.safe_load(path.read_text())))
        assert not errors, f"{path.name}: {errors[0].message}"
    # a parameter the gp environment does not have is refused by the schema, as by validate
    mission = base_mission()
    assert validator.is_valid(mission)
    mission["environment"] = {**mission["environment"], "kernal": {"type": "rbf"}}
    assert not validator.is_valid(mission)
    mission = base_mission(algorithm={"type": "expected_improvement", "xi": -1})
    assert not validator.is_valid(mission)
    titles = [branch["title"] for branch in schema["properties"]["algorithm"]["oneOf"]]
    assert "algorithm greedy" in titles and "algorithm from a module" in titles

"""Mutated example missions: each is refused with one sentence, or validates and then runs.

A mission that ``validate`` accepts must not crash at ``run`` for anything the file contains,
so every accepted mutation is run too (its first steps: enough to build every part and meet
the first decisions).
"""

from __future__ import annotations

import copy

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support import ROOT
from support.fuzz import NASTY, assert_one_sentence, examples, paths_of, set_at, time_limit

from guadal_cli.errors import GuadalError
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner

SIM_EXAMPLES = {
    p.stem: yaml.safe_load(p.read_text())
    for p in sorted((ROOT / "missions").glob("*.yaml"))
    if yaml.safe_load(p.read_text()).get("backend", {}).get("level", "sim") == "sim"
}
#: steps run for an accepted mutation: every plugin built, the first decisions taken
STEPS = 12


def validate_then_run(mission_dict, folder) -> None:
    path = folder / "mission.yaml"
    try:
        path.write_text(yaml.safe_dump(mission_dict, sort_keys=False, allow_unicode=True))
    except (ValueError, yaml.YAMLError):
        return  # not writable as YAML (a lone surrogate, say): no user can hand it in
    with time_limit(60):
        try:
            prep = prepare(path)
        except GuadalError as exc:
            assert_one_sentence(exc)
            return
        prep.mission.max_steps = min(prep.mission.max_steps, STEPS)
        try:
            result = MissionRunner(prep).run()
        except GuadalError as exc:
            assert_one_sentence(exc)
            return
        assert result.status == "complete"


@pytest.fixture
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


@settings(
    max_examples=examples(40),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data(), name=st.sampled_from(sorted(SIM_EXAMPLES)))
def test_a_mutated_example_mission_is_refused_in_one_sentence_or_runs(data, name, folder):
    mission = copy.deepcopy(SIM_EXAMPLES[name])
    # the map path is relative to the shipped mission's folder
    mission["map"] = str((ROOT / "missions" / mission["map"]).resolve())
    mission.setdefault("output", {})["directory"] = str(folder / "runs")
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        paths = paths_of(mission)
        path = data.draw(st.sampled_from(paths), label="path")
        action = data.draw(st.sampled_from(["replace", "replace", "delete", "add"]), label="action")
        if action == "replace":
            mission = set_at(mission, path, data.draw(NASTY, label="value"))
        elif action == "delete" and path:
            mission = set_at(mission, path, None, delete=True)
        else:
            mission = set_at(mission, path + ("unexpected",), data.draw(NASTY, label="value"))
    validate_then_run(mission, folder)

"""Every combination of a sweep, validated before anything runs, each with a stable id.

A combination is checked as completely as ``guadal validate`` checks a mission file, but what
many combinations share is checked once: the schema is checked per combination (cheap), each
distinct plugin section, map, fleet start and environment once. Ten thousand combinations that
vary seeds and a few plugin parameters thus cost a few distinct checks, not ten thousand.

The id of a combination is a hash of its *resolved* mission: plugin parameters with their
defaults filled in, start positions as node ids, and the map by its content rather than its
path. Moving the sweep folder or spelling out a default does not change an id; changing what
the mission does, does.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError
from .spec import Sweep

#: the levels a sweep runs: simulation, or a sitl stack launched for each mission alone
ALLOWED_LEVELS = ("sim", "sitl")


@dataclass
class Combination:
    index: int
    values: dict  # axis -> value
    mission: dict  # what a mission file for this combination would hold
    id: str = ""
    level: str = "sim"

    def label(self) -> str:
        shown = ", ".join(f"{k}={_short(v)}" for k, v in self.values.items())
        return f"combination {self.index}" + (f" ({shown})" if shown else "")


@dataclass
class Plan:
    sweep: Sweep
    combinations: list[Combination]
    distinct: dict  # what was checked once: maps, plugin sections, fleet starts, environments

    def __len__(self) -> int:
        return len(self.combinations)


def _short(value) -> str:
    text = json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else str(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _canonical(data) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), default=str)


class _Once:
    """Results (or the error) of a check, by key: each distinct thing is checked once."""

    def __init__(self):
        self.results: dict = {}

    def __call__(self, key, check, *args):
        if key not in self.results:
            try:
                self.results[key] = (True, check(*args))
            except GuadalError as exc:
                self.results[key] = (False, exc)
        ok, value = self.results[key]
        if not ok:
            raise value
        return value


def _resolve_sections(mission, where: str):
    """Plugin classes and configs, and the three plugin sections as run (defaults filled in)."""
    from ..mission import resolve_plugins

    env_cls, env_cfg, _, alg_cfg, mode, _, backend_cfg = resolve_plugins(mission, where)
    resolved = {
        "environment": {"type": mission.environment.type, **env_cfg.model_dump(mode="json")},
        "algorithm": {"type": mission.algorithm.type, "mode": mode, **alg_cfg.model_dump(mode="json")},
        "backend": {"level": mission.backend.level, **backend_cfg.model_dump(mode="json")},
    }
    return env_cls, env_cfg, resolved


def _load_graph(mission, base_dir: Path, where: str):
    from ..graph import NavGraph
    from ..maps.format import load_map
    from ..mission import mission_map_path
    from ..records import file_sha256

    map_path = mission_map_path(mission, base_dir)
    try:
        map_ = load_map(map_path)
    except GuadalError as exc:
        raise GuadalError(f"{where}map.path: {exc}") from exc
    return NavGraph(map_), file_sha256(map_path)


def _build_environment(env_cls, env_cfg, graph, base_dir: Path, seed: int, where: str) -> None:
    """Build and reset the environment once: its nested plugins and files are checked too."""
    from ..mission import mission_seeds

    try:
        env_cls(env_cfg, graph, base_dir=base_dir).reset(mission_seeds(seed)[0])
    except GuadalError as exc:
        raise GuadalError(f"{where}{exc}") from exc


def plan_sweep(sweep: Sweep) -> Plan:
    """Resolve and validate every combination; the first bad one is one :class:`GuadalError`."""
    from pydantic import ValidationError

    from ..errors import explain_validation_error
    from ..mission import Mission, resolve_initial_nodes

    plugins_once, maps_once, starts_once, envs_once = _Once(), _Once(), _Once(), _Once()
    combinations: list[Combination] = []
    seen: dict[str, int] = {}
    for index, (values, data) in enumerate(sweep.combinations()):
        combo = Combination(index=index, values=values, mission=data)
        where = f"{sweep.path}: {combo.label()}: "
        try:
            mission = Mission.model_validate(data)
        except ValidationError as exc:
            raise GuadalError(f"{where}{explain_validation_error(exc, Mission)}") from exc
        level = mission.backend.level
        if level not in ALLOWED_LEVELS or (
            level == "sitl" and not (mission.backend.model_extra or {}).get("launch")
        ):
            raise GuadalError(
                f"{where}backend.level '{level}' cannot be swept: a sweep runs only sim missions, or sitl "
                "missions with backend.launch: true (a stack of their own), never real boats."
            )
        sections = (mission.environment.as_dict(), mission.algorithm.as_dict(), mission.backend.model_dump())
        env_cls, env_cfg, resolved_sections = plugins_once(
            _canonical(sections), _resolve_sections, mission, where
        )
        map_key = mission.map.path  # as written: one base folder for all, so one name is one file
        graph, map_sha = maps_once(map_key, _load_graph, mission, sweep.base_dir, where)
        fleet = mission.fleet.model_dump(mode="json")
        nodes = starts_once((map_key, _canonical(fleet)), resolve_initial_nodes, mission.fleet, graph, where)
        envs_once(
            (map_key, _canonical(resolved_sections["environment"])),
            _build_environment,
            *(env_cls, env_cfg, graph, sweep.base_dir, mission.seed, where),
        )
        resolved = mission.model_dump(mode="json")  # every field, those added later included
        for where_it_goes in ("directory", "database"):  # where a run is written is not what it does
            resolved["output"].pop(where_it_goes, None)
        resolved.update(map=map_sha, fleet={**fleet, "initial_positions": nodes}, **resolved_sections)
        combo.id = hashlib.sha256(_canonical(resolved).encode()).hexdigest()[:12]
        combo.level = level
        if combo.id in seen:
            other = combinations[seen[combo.id]]
            raise GuadalError(
                f"{sweep.path}: {combo.label()} and {other.label()} are the same mission; "
                "remove the repeated axis value."
            )
        seen[combo.id] = index
        combinations.append(combo)
    distinct = {
        "maps": len(maps_once.results),
        "plugin_sections": len(plugins_once.results),
        "fleet_starts": len(starts_once.results),
        "environments": len(envs_once.results),
    }
    return Plan(sweep=sweep, combinations=combinations, distinct=distinct)


def task_for(plan: Plan, combo: Combination, sweep_dir: Path, attempt: int) -> dict:
    """What a worker needs to run one combination (plain data: it crosses process and host lines)."""
    return {
        "id": combo.id,
        "mission": combo.mission,
        "base_dir": str(plan.sweep.base_dir),
        "source": f"{plan.sweep.path}#{combo.id}",
        "run_dir": str(Path(sweep_dir).resolve() / "runs" / combo.id),
        "attempt": attempt,
    }

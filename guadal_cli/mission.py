"""The mission file: typed schema, loading, and one clear sentence per bad field.

A mission is validated completely before anything runs: the top-level schema here, then each
plugin section by the plugin it names (only that plugin is imported), then the map and the
fleet's starting positions. :func:`prepare` returns everything the runner needs.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from . import plugins
from .errors import GuadalError, explain_validation_error
from .graph import NavGraph
from .maps.format import Map, check_node_limit, checked_path, load_map

#: a mission file is a page of YAML; anything bigger is a mistake (or an attack)
MAX_MISSION_BYTES = 1_000_000
#: sections nest a few levels deep; thousands of levels would exhaust Python's stack
MAX_MISSION_DEPTH = 32
#: values once YAML anchors are expanded: a few hundred in a real mission
MAX_MISSION_VALUES = 100_000
#: the longest distance budget (metres) and speed (m/s) a vehicle may be given
MAX_DISTANCE_M = 1_000_000.0
MIN_SPEED_MS, MAX_SPEED_MS = 0.001, 100.0


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class NodePosition(_Strict):
    node: int = Field(ge=0)


class GridPosition(_Strict):
    row: int
    col: int


class GeoPosition(_Strict):
    lat: float = Field(ge=-90, le=90)
    lon: float = Field(ge=-180, le=180)


Position = int | NodePosition | GridPosition | GeoPosition


class MapSection(_Strict):
    path: str = Field(description="Map file (guadal map JSON), relative to the mission file.")


class PluginSection(BaseModel):
    """``{type: NAME, ...params}``; the plugin named validates its own params."""

    model_config = ConfigDict(extra="allow")
    type: str = Field(description="Registered plugin name, or 'module:Class'.")

    def as_dict(self) -> dict:
        return {"type": self.type, **(self.model_extra or {})}


class AlgorithmSection(PluginSection):
    mode: Literal["sequential", "target"] | None = Field(
        default=None, description="Operating mode; default: the algorithm's own."
    )


class FleetSection(_Strict):
    vehicles: int = Field(ge=1, description="Number of vehicles.")
    initial_positions: Literal["auto"] | list[Position] = Field(
        default="auto",
        description="'auto' (nodes nearest the lake's centre) or one entry per vehicle: "
        "a node id, {node}, {row, col} or {lat, lon}.",
    )
    max_distance: float = Field(
        gt=0, le=MAX_DISTANCE_M, description="Distance budget per vehicle, metres (at most 1,000 km)."
    )
    speed: float = Field(
        default=0.5,
        ge=MIN_SPEED_MS,
        le=MAX_SPEED_MS,
        description="Nominal speed, m/s (sets simulated time).",
    )
    allow_shared_nodes: bool = Field(
        default=False, description="Allow two vehicles on the same node at the same step."
    )


class BackendSection(BaseModel):
    """``level`` picks the backend plugin; its other keys are that backend's settings."""

    model_config = ConfigDict(extra="allow")
    level: str = Field(default="sim", description="sim, sitl or real (any installed backend).")


class OutputSection(_Strict):
    directory: str = Field(default="runs", description="Parent folder of run directories.")
    coverage_radius: float = Field(
        default=10.0,
        gt=0,
        le=MAX_DISTANCE_M,
        description="A node counts as covered within this many metres of a sample.",
    )
    database: str | None = Field(
        default=None,
        description="Database URL the run is also written to (sqlite:///FILE, postgresql://USER@HOST/DB) "
        "or 'none'; by default guadal.db beside the run directories.",
    )


class Mission(_Strict):
    name: str = Field(
        min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$", description="Used in run directory names."
    )
    seed: int = Field(default=0, ge=0, lt=2**63)
    map: MapSection
    environment: PluginSection
    algorithm: AlgorithmSection
    fleet: FleetSection
    backend: BackendSection = BackendSection()
    output: OutputSection = OutputSection()
    max_steps: int = Field(default=100_000, ge=1, le=10_000_000, description="Safety stop on steps.")

    @field_validator("map", mode="before", json_schema_input_type=str | MapSection)
    @classmethod
    def _map_shorthand(cls, value: Any):
        return {"path": value} if isinstance(value, str) else value


def json_schema() -> dict:
    """JSON Schema of the mission file, for editors: the plugin sections are unions of every
    installed plugin's ``Config``, so parameters complete too."""
    schema = Mission.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "guadal mission"
    mode = schema["$defs"]["AlgorithmSection"]["properties"]["mode"]
    for section, name_key, shared, name_required in (
        ("environment", "type", {}, True),
        ("algorithm", "type", {"mode": mode}, True),
        ("backend", "level", {}, False),  # level defaults to sim
    ):
        union, defs = plugins.config_union(section, name_key, shared, name_required)
        schema["properties"][section] = {
            **union,
            "description": f"The {section}: {name_key} and its parameters.",
        }
        schema["$defs"].update(defs)
    return schema


@dataclass
class Prepared:
    """A validated mission with its plugins resolved and its map loaded."""

    mission: Mission
    path: Path
    base_dir: Path
    map: Map
    graph: NavGraph
    environment_cls: type
    environment_config: BaseModel
    algorithm_cls: type
    algorithm_config: BaseModel
    mode: str
    backend_cls: type
    backend_config: BaseModel
    initial_nodes: list[int]
    environment: object  # built and reset: its nested plugins and files are checked too
    environment_seed: int
    planner_seed: int
    #: a resumed run: where its record last saw each vehicle (a launched sitl stack puts its boats
    #: there, as boats that waited where they were would be); None for a new run
    resume_nodes: list[int] | None = None

    def resolved_dict(self) -> dict:
        """The mission as run: defaults filled in, plugin params as validated."""
        data = self.mission.model_dump(mode="json")
        data["environment"] = {
            "type": self.mission.environment.type,
            **self.environment_config.model_dump(mode="json"),
        }
        data["algorithm"] = {
            "type": self.mission.algorithm.type,
            "mode": self.mode,
            **self.algorithm_config.model_dump(mode="json"),
        }
        data["backend"] = {"level": self.mission.backend.level, **self.backend_config.model_dump(mode="json")}
        data["fleet"]["initial_positions"] = [{"node": n} for n in self.initial_nodes]
        data["map"] = {"path": str(self.map.source) if self.map.source else self.mission.map.path}
        if data["output"].get("database"):
            from .db.engine import redact

            data["output"]["database"] = redact(data["output"]["database"])
        return data


class _CappedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing nesting deeper than :data:`MAX_MISSION_DEPTH` as it composes.

    The depth is counted while the document is composed, so a file of ten thousand ``[`` fails
    at level 33 with a sentence, not at level 1000 with a RecursionError.
    """

    depth = 0

    def compose_node(self, parent, index):
        self.depth += 1
        try:
            if self.depth > MAX_MISSION_DEPTH:
                mark = self.peek_event().start_mark
                raise GuadalError(
                    f"nested more than {MAX_MISSION_DEPTH} levels deep at line {mark.line + 1}; "
                    "a mission's sections nest a few levels at most."
                )
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


def _non_finite(data, where: str = "", budget: list | None = None) -> str | None:
    """The path of the first NaN or infinite number in ``data``; counts values against a cap."""
    budget = [MAX_MISSION_VALUES] if budget is None else budget
    stack = [(where, data)]
    while stack:
        path, value = stack.pop()
        budget[0] -= 1
        if budget[0] < 0:
            raise GuadalError(
                f"holds more than {MAX_MISSION_VALUES:,} values once its anchors (&, *) are expanded; "
                "a mission is a page of settings."
            )
        if isinstance(value, float) and not math.isfinite(value):
            return path or "the document"
        if isinstance(value, dict):
            stack.extend((f"{path}.{k}" if path else str(k), v) for k, v in reversed(list(value.items())))
        elif isinstance(value, list):
            stack.extend((f"{path}[{i}]", v) for i, v in reversed(list(enumerate(value))))
    return None


def read_mission_file(path: Path) -> dict:
    """The mission's YAML as a dict: size, depth and numbers checked before anything reads it."""
    where = checked_path(path, "mission file")
    try:
        if not path.is_file():
            raise GuadalError(f"{where}: mission file does not exist.")
        size = path.stat().st_size
        if size > MAX_MISSION_BYTES:
            raise GuadalError(
                f"{where}: the file is {size:,} bytes; a mission file is at most {MAX_MISSION_BYTES:,} bytes."
            )
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        raise GuadalError(f"{where}: cannot read the mission file ({reason}).") from exc
    try:
        data = yaml.load(text, Loader=_CappedLoader)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "invalid YAML"
        raise GuadalError(f"{where}: malformed YAML{at}: {problem}.") from exc
    except GuadalError as exc:
        raise GuadalError(f"{where}: {exc}") from exc
    except RecursionError as exc:  # a deep structure inside one flow scalar, say
        raise GuadalError(f"{where}: nested too deeply for a mission file.") from exc
    except ValueError as exc:  # an integer past Python's 4300 digits
        raise GuadalError(
            f"{where}: a number in it is too long to read ({str(exc).split(':')[0]})."
        ) from None
    if not isinstance(data, dict):
        raise GuadalError(
            f"{where}: a mission file must be a YAML mapping of sections (name, map, environment, ...)."
        )
    try:
        bad = _non_finite(data)
    except GuadalError as exc:
        raise GuadalError(f"{where}: {exc}") from exc
    if bad is not None:
        raise GuadalError(f"{where}: {bad}: must be a finite number (NaN and infinities are not allowed).")
    return data


def parse_mission(data: dict, path: Path) -> Mission:
    try:
        return Mission.model_validate(data)
    except ValidationError as exc:
        raise GuadalError(f"{path}: {explain_validation_error(exc, Mission)}") from exc


def resolve_initial_nodes(fleet: FleetSection, graph: NavGraph, where: str) -> list[int]:
    """Node ids for the starting positions, checked against the map."""
    n = fleet.vehicles
    if n > graph.n_nodes:
        raise GuadalError(f"{where}fleet.vehicles: {n} vehicles do not fit on {graph.n_nodes} water nodes.")
    if fleet.initial_positions == "auto":
        nodes = auto_positions(graph, n)
    else:
        if len(fleet.initial_positions) != n:
            raise GuadalError(
                f"{where}fleet.initial_positions: {len(fleet.initial_positions)} positions given for {n} vehicles; "
                "give one per vehicle or 'auto'."
            )
        nodes = []
        for i, pos in enumerate(fleet.initial_positions):
            field = f"{where}fleet.initial_positions[{i}]"
            if isinstance(pos, int) or isinstance(pos, NodePosition):
                node = pos if isinstance(pos, int) else pos.node
                if not 0 <= node < graph.n_nodes:
                    raise GuadalError(
                        f"{field}: node {node} does not exist (nodes are 0..{graph.n_nodes - 1})."
                    )
            elif isinstance(pos, GridPosition):
                rows, cols = graph.map.shape
                if not (0 <= pos.row < rows and 0 <= pos.col < cols):
                    raise GuadalError(
                        f"{field}: cell ({pos.row}, {pos.col}) is off the grid (rows 0..{rows - 1}, cols 0..{cols - 1})."
                    )
                node = graph.node_at(pos.row, pos.col)
                if node is None:
                    raise GuadalError(
                        f"{field}: cell ({pos.row}, {pos.col}) is land; a vehicle must start on water."
                    )
            else:
                rc = graph.map.rowcol_of(pos.lat, pos.lon)
                if rc is None:
                    raise GuadalError(f"{field}: ({pos.lat}, {pos.lon}) lies outside the map.")
                node = graph.node_at(*rc)
                if node is None:
                    raise GuadalError(
                        f"{field}: ({pos.lat}, {pos.lon}) is on land; a vehicle must start on water."
                    )
            nodes.append(int(node))
    if not fleet.allow_shared_nodes and len(set(nodes)) != len(nodes):
        raise GuadalError(
            f"{where}fleet.initial_positions: two vehicles start on the same node; "
            "give distinct positions or set fleet.allow_shared_nodes: true."
        )
    if not graph.same_component(nodes):
        raise GuadalError(
            f"{where}fleet.initial_positions: the vehicles start in separate water bodies; "
            "all must start in one connected body of water."
        )
    return nodes


def auto_positions(graph: NavGraph, n: int) -> list[int]:
    """The nodes nearest the centre of the largest water body, like boats launched together."""
    sizes = np.bincount(graph.component)
    body = np.nonzero(graph.component == int(np.argmax(sizes)))[0]
    if len(body) < n:
        raise GuadalError(
            f"fleet.vehicles: the largest water body has only {len(body)} nodes for {n} vehicles."
        )
    centre = graph.xy[body].mean(axis=0)
    order = body[np.lexsort((body, np.hypot(*(graph.xy[body] - centre).T)))]
    return [int(v) for v in order[:n]]


def check_output_directory(directory: str, base_dir: Path, where: str) -> Path:
    """The parent of run directories, checked now so that ``run`` cannot fail to create it.

    The nearest folder that exists must take a new folder: that is tried for real (a folder made
    and removed at once), since permissions alone do not tell (``/proc``, read-only mounts, root).
    """
    field = f"{where}output.directory"
    checked_path(directory, field)
    parent = Path(os.path.abspath(base_dir / directory))
    if parent == Path(parent.anchor):
        raise GuadalError(
            f"{field}: '{directory}' is the filesystem root; give a folder for run directories (e.g. runs)."
        )
    try:
        existing = parent
        while not existing.exists():
            existing = existing.parent
        if not existing.is_dir():
            raise GuadalError(f"{field}: '{existing}' is a file, so no run directory can be made under it.")
        os.rmdir(tempfile.mkdtemp(prefix=".guadal-check-", dir=existing))
    except OSError as exc:
        raise GuadalError(
            f"{field}: cannot create run directories under '{directory}' ({exc.strerror or exc})."
        ) from exc
    return parent


def prepare(path: str | Path, seed: int | None = None) -> Prepared:
    """Load, validate and resolve a mission file; raises :class:`GuadalError` on any bad input."""
    path = Path(path)
    data = read_mission_file(path)
    if seed is not None:
        data["seed"] = seed
    return prepare_dict(data, path.resolve().parent, path)


def resolve_plugins(mission: Mission, where: str = "") -> tuple:
    """The plugin classes and validated configs a mission names, with its mode checked.

    Returns ``(env_cls, env_cfg, alg_cls, alg_cfg, mode, backend_cls, backend_cfg)``.
    """
    try:
        env_cls, env_cfg = plugins.build_config("environment", mission.environment.as_dict(), "environment")
        alg_cls, alg_cfg = plugins.build_config("algorithm", mission.algorithm.as_dict(), "algorithm")
        # the level names the backend plugin, and stays among its settings
        backend_cls, backend_cfg = plugins.build_config(
            "backend", mission.backend.model_dump(), "backend", name_key="level"
        )
    except GuadalError as exc:
        raise GuadalError(f"{where}{exc}") from exc
    mode = mission.algorithm.mode or alg_cls.modes[0]
    if mode not in alg_cls.modes:
        raise GuadalError(
            f"{where}algorithm.mode: '{mission.algorithm.type}' supports {', '.join(alg_cls.modes)}, not '{mode}'."
        )
    missing = set(alg_cls.requires) - set(env_cls.provides)
    if missing:
        raise GuadalError(
            f"{where}algorithm.type: '{mission.algorithm.type}' needs {', '.join(sorted(missing))} from the "
            f"environment, which '{mission.environment.type}' does not provide "
            f"(it provides: {', '.join(sorted(env_cls.provides)) or 'nothing'})."
        )
    return env_cls, env_cfg, alg_cls, alg_cfg, mode, backend_cls, backend_cfg


def mission_map_path(mission: Mission, base_dir: Path) -> Path:
    """The map file a mission names, relative paths taken from the mission's folder."""
    map_path = Path(mission.map.path)
    return map_path if map_path.is_absolute() else Path(base_dir) / map_path


def prepare_dict(
    data: dict, base_dir: str | Path, source: str | Path = "mission", check_output: bool = True
) -> Prepared:
    """Validate and resolve a mission given as a mapping (what a mission file holds).

    Relative paths inside it are taken from ``base_dir``; ``source`` names the mission in error
    sentences and in the run manifest. A sweep builds each of its missions this way, and the
    run is the same, byte for byte, as ``guadal run`` of a file holding ``data``. A resumed run
    has its run directory already: ``check_output=False`` skips ``output.directory``.
    """
    path = Path(source)
    mission = parse_mission(data, path)
    base_dir = Path(base_dir).resolve()
    where = f"{path}: "
    env_cls, env_cfg, alg_cls, alg_cfg, mode, backend_cls, backend_cfg = resolve_plugins(mission, where)
    if check_output:
        check_output_directory(mission.output.directory, base_dir, where)
    try:
        checked_path(mission.map.path, "map file")
        map_ = load_map(mission_map_path(mission, base_dir))
        check_node_limit(map_)
    except GuadalError as exc:
        raise exc.within("map.path", file=path) from None
    graph = NavGraph(map_)
    initial_nodes = resolve_initial_nodes(mission.fleet, graph, where)
    try:
        alg_cfg = alg_cls.for_mission(
            alg_cfg, mission=mission, graph=graph, mode=mode, base_dir=base_dir, provides=env_cls.provides
        )
    except GuadalError as exc:
        raise exc.within("algorithm", file=path) from None
    env_seed, planner_seed = mission_seeds(mission.seed)
    try:
        environment = env_cls(env_cfg, graph, base_dir=base_dir)
        environment.reset(env_seed)
    except GuadalError as exc:
        raise exc.within(file=path) from None
    return Prepared(
        mission=mission,
        path=path,
        base_dir=base_dir,
        map=map_,
        graph=graph,
        environment_cls=env_cls,
        environment_config=env_cfg,
        algorithm_cls=alg_cls,
        algorithm_config=alg_cfg,
        mode=mode,
        backend_cls=backend_cls,
        backend_config=backend_cfg,
        initial_nodes=initial_nodes,
        environment=environment,
        environment_seed=env_seed,
        planner_seed=planner_seed,
    )


def mission_seeds(seed: int) -> tuple[int, int]:
    """The environment's and the planner's seeds, both drawn from the mission's one seed."""
    env_seed, planner_seed = (int(s) for s in np.random.SeedSequence(seed).generate_state(2))
    return env_seed, planner_seed

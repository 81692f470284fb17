"""Conformance checks for plugins: does a plugin keep its kind's contract?

A third-party environment, algorithm, backend, ground truth or sensor is run through the same
checks as the built-in ones (the suite runs them on every built-in plugin)::

    from guadal_cli.testing import check_planner, parametrize_with_checks

    check_planner(MyPlanner)                       # raises ContractError naming what is broken

    @parametrize_with_checks([MyPlanner, (MyEnvironment, {"radius": 3.0})])
    def test_my_plugins(plugin, check):            # one pytest test per (plugin, check)
        check(plugin)

Each check raises :class:`ContractError` (an ``AssertionError``) whose message names the plugin,
the contract and what was seen. The checks run on a small built-in pond (:func:`check_graph`)
within seconds; they use the real Episode, fleet and model code, not stand-ins.
"""

from __future__ import annotations

import atexit
import math
import shutil
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from . import plugins
from .errors import GuadalError
from .graph import NavGraph
from .maps.format import Map

#: metric columns the runner writes itself; an environment's metric of the same name would clash
GENERAL_METRICS = ("step", "time_s", "total_distance", "samples", "coverage")
MODES = ("sequential", "target")
#: planner decisions tried per mode
DECISIONS = 25


class ContractError(AssertionError):
    """A plugin breaks its kind's contract."""


@dataclass
class Plugin:
    """A plugin under check: its kind, class and validated config, plus what its checks need.

    ``options``: ``graph`` (default :func:`check_graph`), ``base_dir`` (relative paths in the
    config), ``environment`` (for a planner: an environment class or instance that provides what
    it requires; default: the first installed one that does).
    """

    kind: str
    cls: type
    config: BaseModel
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.cls.__name__

    def __repr__(self) -> str:  # pytest ids and failure headers
        return f"{self.kind} {self.name}"

    @property
    def graph(self) -> NavGraph:
        return self.options.get("graph") or check_graph()

    @property
    def base_dir(self) -> Path | None:
        return self.options.get("base_dir")


def _fail(p: Plugin, contract: str, seen: str) -> ContractError:
    return ContractError(f"{p.kind} {p.name} breaks the contract '{contract}': {seen}")


def kind_of(cls: type) -> str:
    """The plugin kind whose base class ``cls`` subclasses."""
    for kind in plugins.GROUPS:
        if isinstance(cls, type) and issubclass(cls, plugins.base_class(kind)):
            return kind
    bases = ", ".join(plugins.BASES.values())
    raise ContractError(f"{cls!r} subclasses none of the plugin contracts ({bases}).")


def plugin(obj: Any, config: BaseModel | dict | None = None, *, kind: str | None = None, **options) -> Plugin:
    """A :class:`Plugin` from a class, an instance (its ``config`` is used), a ``(class, config)``
    pair or a Plugin. A dict config is validated by the class's ``Config``; none means its defaults."""
    if isinstance(obj, Plugin):
        return obj
    if isinstance(obj, tuple):
        obj, config = obj
    cls = obj if isinstance(obj, type) else type(obj)
    if config is None and not isinstance(obj, type):
        config = getattr(obj, "config", None)
    kind = kind or kind_of(cls)
    probe = Plugin(kind, cls, None, options)  # type: ignore[arg-type]
    config_cls = getattr(cls, "Config", None)
    if not (isinstance(config_cls, type) and issubclass(config_cls, BaseModel)):
        raise _fail(probe, "Config is a pydantic model", f"Config is {config_cls!r}")
    if config is None or isinstance(config, dict):
        try:
            config = config_cls(**(config or {}))
        except Exception as exc:
            raise _fail(
                probe, "Config validates the plugin's section", f"{type(exc).__name__}: {exc}"
            ) from exc
    return Plugin(kind, cls, config, options)


# --- the small world the checks run in ---------------------------------------------------------
_GRAPH: NavGraph | None = None


def check_graph() -> NavGraph:
    """A 9 x 9 pond of 10 m cells around a 3 x 3 island (72 nodes): small, with ways round."""
    global _GRAPH
    if _GRAPH is None:
        mask = np.ones((9, 9), dtype=bool)
        mask[3:6, 3:6] = False
        folder = Path(tempfile.mkdtemp(prefix="guadal-check-"))
        atexit.register(shutil.rmtree, folder, True)
        Map(
            mask=mask,
            cell_size_m=10.0,
            reference={"row": 4, "col": 4, "lat": 37.418, "lon": -5.9805},
            name="check pond",
        ).save(folder / "pond.json")
        from .maps.format import load_map

        _GRAPH = NavGraph(load_map(folder / "pond.json"))  # with a source file, as bridges need
    return _GRAPH


def start_nodes(graph: NavGraph, n: int) -> list[int]:
    """``n`` start nodes far apart (corners first), so vehicles have room."""
    order = np.argsort(-np.hypot(graph.x - graph.x.mean(), graph.y - graph.y.mean()), kind="stable")
    return [int(v) for v in order[:: max(1, len(order) // n)][:n]]


def _environment(p: Plugin, seed: int = 0):
    env = p.cls(p.config, p.graph, base_dir=p.base_dir)
    env.reset(seed)
    return env


# --- checks every kind shares --------------------------------------------------------------------
def check_config_round_trip(p: Plugin) -> None:
    """Config is a pydantic model whose dump validates back to itself (mission.resolved.yaml and
    resume rely on it)."""
    try:
        again = p.cls.Config.model_validate(p.config.model_dump(mode="json"))
    except Exception as exc:
        raise _fail(p, "Config survives a dump and validation", f"{type(exc).__name__}: {exc}") from exc
    if again != p.config:
        raise _fail(p, "Config survives a dump and validation", f"{again!r} != {p.config!r}")


def check_constructor_only_stores(p: Plugin) -> None:
    """The constructor stores its parameters and does no work: the config is kept as given and
    not changed, and no learned state (``name_``) exists before ``reset``."""
    before = p.config.model_dump()
    if p.kind == "environment":
        obj = p.cls(p.config, p.graph, base_dir=p.base_dir)
        if obj.graph is not p.graph:
            raise _fail(p, "the constructor stores its parameters", "self.graph is not the graph given")
    else:
        obj = p.cls(p.config)
    if obj.config is not p.config:
        raise _fail(p, "the constructor stores its parameters", "self.config is not the config given")
    if p.config.model_dump() != before:
        raise _fail(p, "the constructor stores its parameters", "it changed its config")
    learned = sorted(k for k in vars(obj) if k.endswith("_") and not k.startswith("_"))
    if learned:
        raise _fail(p, "learned state is created in reset, not in the constructor", ", ".join(learned))


# --- environments -----------------------------------------------------------------------------------
def check_environment_declarations(p: Plugin) -> None:
    """``provides`` is a set of field names; ``metric_names`` a tuple of unique names that do not
    clash with the runner's own columns."""
    provides, names = p.cls.provides, p.cls.metric_names
    if not (isinstance(provides, (set, frozenset)) and all(isinstance(x, str) for x in provides)):
        raise _fail(p, "provides is a frozenset of field names", repr(provides))
    if not (isinstance(names, tuple) and all(isinstance(x, str) for x in names)):
        raise _fail(p, "metric_names is a tuple of names", repr(names))
    clash = [x for x in names if x in GENERAL_METRICS or x.startswith("distance_v")]
    if len(set(names)) != len(names) or clash:
        raise _fail(p, "metric names are unique and not the runner's columns", repr(names))


def _state(env, nodes) -> str:
    """Ground truth, fields and a few samples, as text: equal texts are equal values (NaN included)."""
    truth = env.ground_truth
    return repr(
        (
            None if truth is None else np.asarray(truth).tolist(),
            {k: np.asarray(v).tolist() for k, v in sorted(env.observation_fields().items())},
            _senses(env, nodes),
        )
    )


def _senses(env, nodes) -> list:
    try:
        return [env.sense(i % 3, int(n)) for i, n in enumerate(nodes)]
    except GuadalError as exc:  # no synthetic sensor: allowed, as long as it says so
        return [str(exc)]


def check_environment_reset_is_deterministic(p: Plugin) -> None:
    """``reset(seed)`` draws the same world for the same seed, whether the environment is new or
    has run a while (the Episode resets it; sim and sitl rely on the same samples)."""
    nodes = list(range(0, p.graph.n_nodes, 5))
    a, b = _environment(p, 11), _environment(p, 11)
    first = _state(a, nodes)
    if _state(b, nodes) != first:
        raise _fail(p, "reset is deterministic for a seed", "two environments reset with seed 11 differ")
    a.update(_measurements(a, [0, 1, 2]))
    a.reset(11)
    if _state(a, nodes) != first:
        raise _fail(p, "reset is deterministic for a seed", "reset(11) after updates gives another world")


def _measurements(env, nodes) -> list:
    from .fleet.base import Measurement

    g = env.graph
    out = []
    for i, n in enumerate(nodes):
        try:
            value = float(env.sense(i, n))
        except GuadalError:
            value = 0.5  # no synthetic sensor: a vehicle's reading
        out.append(Measurement(i, int(n), value, float(g.lat[n]), float(g.lon[n]), float(i)))
    return out


def check_environment_fields_and_metrics(p: Plugin) -> None:
    """``observation_fields`` has exactly the ``provides`` names, one value per node; ``metrics``
    exactly ``metric_names``, real numbers, none infinite; both before and after updates (an
    empty update included), ``advance`` accepted; ``sense`` gives finite floats or refuses with
    a GuadalError; ``task_state`` is a dict."""
    env = _environment(p, 3)
    n = p.graph.n_nodes
    for when, measurements in (("after reset", None), ("after update([])", []), ("after updates", [0, 7, 9])):
        if measurements is not None:
            env.advance(1.0 + len(measurements))
            env.update(_measurements(env, measurements) if measurements else [])
        fields = env.observation_fields()
        if set(fields) != set(p.cls.provides):
            raise _fail(
                p,
                "observation_fields are keyed by provides",
                f"{sorted(fields)} {when}, not {sorted(p.cls.provides)}",
            )
        for name, values in fields.items():
            values = np.asarray(values)
            if values.shape != (n,) or not np.issubdtype(values.dtype, np.number):
                raise _fail(
                    p,
                    "observation fields hold one number per node",
                    f"'{name}' is {values.dtype} of shape {values.shape} {when}, not ({n},)",
                )
        metrics = env.metrics()
        if list(metrics) != list(p.cls.metric_names):
            raise _fail(p, "metrics are keyed by metric_names", f"{list(metrics)} {when}")
        bad = {k: v for k, v in metrics.items() if not isinstance(v, (int, float)) or math.isinf(v)}
        if bad:
            raise _fail(p, "metrics are real numbers, never infinite", f"{bad} {when}")
        if not isinstance(env.task_state(), dict):
            raise _fail(p, "task_state is a dict", repr(env.task_state()))
    for node in range(n):
        try:
            value = env.sense(0, node)
        except GuadalError:
            break
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise _fail(p, "sense gives a finite float", f"{value!r} at node {node}")


# --- planners ---------------------------------------------------------------------------------------
def check_planner_declarations(p: Plugin) -> None:
    """``modes`` is a non-empty tuple of sequential/target (the first is the default);
    ``requires`` a set of field names."""
    modes, requires = p.cls.modes, p.cls.requires
    if not (
        isinstance(modes, tuple) and modes and set(modes) <= set(MODES) and len(set(modes)) == len(modes)
    ):
        raise _fail(p, "modes is a non-empty tuple of 'sequential' and/or 'target'", repr(modes))
    if not (isinstance(requires, (set, frozenset)) and all(isinstance(x, str) for x in requires)):
        raise _fail(p, "requires is a frozenset of field names", repr(requires))


def _planner_environment(p: Plugin):
    """The environment a planner is checked in: given, or the first installed one providing its needs."""
    given = p.options.get("environment")
    if given is not None:
        env = plugin(given, kind="environment", graph=p.graph, base_dir=p.base_dir)
    else:
        env = None
        for name in plugins.available("environment"):
            cls = plugins.load("environment", name)
            if set(p.cls.requires) <= set(cls.provides):
                env = plugin(cls, kind="environment", graph=p.graph, base_dir=p.base_dir)
                break
        if env is None:
            raise _fail(
                p,
                "requires is provided by an environment",
                f"no installed environment provides {', '.join(sorted(p.cls.requires))}",
            )
    missing = set(p.cls.requires) - set(env.cls.provides)
    if missing:
        raise _fail(
            p,
            "requires is provided by the environment",
            f"{env.name} does not provide {', '.join(sorted(missing))}",
        )
    return env


def check_planner_requires_are_provided(p: Plugin) -> None:
    """Every field in ``requires`` is provided by the environment it runs in."""
    _planner_environment(p)


def _episode(p: Plugin, mode: str, n_vehicles: int = 3, seed: int = 5):
    """An Episode of the planner on the check pond, prepared as ``prepare_dict`` would (the planner's
    ``for_mission`` included: a GuadalError from it means the config refuses ``mode``)."""
    from .episode import Episode
    from .fleet.local import SimBackend, SimConfig
    from .mission import Mission, Prepared, mission_seeds

    env_plugin = _planner_environment(p)
    graph = p.graph
    nodes = start_nodes(graph, n_vehicles)
    mission = Mission.model_validate(
        {
            "name": "conformance",
            "seed": seed,
            "map": str(graph.map.source or "pond.json"),
            "environment": {"type": f"{env_plugin.cls.__module__}:{env_plugin.cls.__qualname__}"},
            "algorithm": {"type": f"{p.cls.__module__}:{p.cls.__qualname__}", "mode": mode},
            "fleet": {
                "vehicles": n_vehicles,
                "initial_positions": [{"node": v} for v in nodes],
                "max_distance": 400.0,
                "speed": 1.0,
            },
            "max_steps": 400,
        }
    )
    base_dir = Path(p.base_dir or Path.cwd())
    config = p.cls.for_mission(
        p.config, mission=mission, graph=graph, mode=mode, base_dir=base_dir, provides=env_plugin.cls.provides
    )
    env_seed, planner_seed = mission_seeds(seed)
    env = env_plugin.cls(env_plugin.config, graph, base_dir=p.base_dir)
    env.reset(env_seed)
    prep = Prepared(
        mission=mission,
        path=Path("conformance"),
        base_dir=base_dir,
        map=graph.map,
        graph=graph,
        environment_cls=env_plugin.cls,
        environment_config=env_plugin.config,
        algorithm_cls=p.cls,
        algorithm_config=config,
        mode=mode,
        backend_cls=SimBackend,
        backend_config=SimConfig(),
        initial_nodes=nodes,
        environment=env,
        environment_seed=env_seed,
        planner_seed=planner_seed,
    )
    return Episode(prep)


def _modes(p: Plugin) -> list[str]:
    """The declared modes whose missions the planner's ``for_mission`` accepts with this config
    (a trained policy, say, plays only the mode it was trained in); at least one must be."""
    accepted, refused = [], []
    for mode in p.cls.modes:
        try:
            _episode(p, mode)
        except GuadalError as exc:
            refused.append(f"{mode} mode: {exc}")
        else:
            accepted.append(mode)
    if not accepted:
        raise _fail(p, "for_mission accepts its config in a mode it declares", " ".join(refused))
    return accepted


def _play(p: Plugin, mode: str, planner=None) -> tuple[list[dict], object]:
    """Targets of up to DECISIONS decisions in an Episode (which checks them, raising on a bad
    one), and the planner that made them (a new one unless given)."""
    ep = _episode(p, mode)
    planner = planner or p.cls(ep.prep.algorithm_config)
    obs = ep.reset()
    planner.reset(ep.graph, ep.n_vehicles, mode, ep.planner_seed)
    decisions = []
    for _ in range(DECISIONS):
        if not isinstance(planner.done, bool):
            raise _fail(p, "done is a bool", repr(planner.done))
        if planner.done or ep.stop_reason:
            break
        targets = planner.next_targets(obs)
        if not isinstance(targets, dict):
            raise _fail(
                p, "next_targets returns a dict {vehicle: node}", f"a {type(targets).__name__} in {mode} mode"
            )
        try:
            obs, *_, info = ep.step(targets)
        except GuadalError as exc:
            raise _fail(p, f"next_targets returns valid targets in {mode} mode", str(exc)) from exc
        decisions.append({int(v): int(t) for v, t in targets.items()})
        if not info["targets"]:
            break
    return decisions, planner


def check_planner_targets_are_valid(p: Plugin) -> None:
    """In every mode it accepts, ``next_targets`` returns ``{vehicle: node}`` that the Episode
    accepts (known vehicles, nodes reachable over water, neighbours in sequential mode), and
    moves some vehicle at its first decision."""
    for mode in _modes(p):
        decisions, _ = _play(p, mode)
        if not decisions or not decisions[0]:
            raise _fail(
                p, f"next_targets moves vehicles in {mode} mode", "it sent no target at the first decision"
            )


def check_planner_is_deterministic(p: Plugin) -> None:
    """``reset`` forgets the last mission and seeds the planner: the same seed, the same decisions,
    whether the planner is new or has planned before."""
    for mode in _modes(p):
        first, planner = _play(p, mode)
        if _play(p, mode, planner)[0] != first or _play(p, mode)[0] != first:
            raise _fail(
                p, "reset(seed) makes decisions repeatable", f"two plays with one seed differ in {mode} mode"
            )


# --- backends --------------------------------------------------------------------------------------
def check_backend_fleet(p: Plugin) -> None:
    """``make_fleet`` returns a Fleet that resets vehicles to their nodes, moves them one edge at a
    time within budget, measures where they are, refuses a wrong number of start nodes, and closes
    twice without harm."""
    from .fleet.base import Fleet, Measurement
    from .mission import FleetSection

    graph = p.graph
    nodes = start_nodes(graph, 2)
    fleet_config = FleetSection(
        vehicles=2, initial_positions=[{"node": v} for v in nodes], max_distance=35.0, speed=2.0
    )
    contract = "make_fleet returns a working Fleet"
    fleet = p.cls(p.config).make_fleet(
        graph=graph, fleet_config=fleet_config, sensor=lambda v, n: float(n), mission=_Started(graph, nodes)
    )
    if not isinstance(fleet, Fleet):
        raise _fail(p, contract, f"it returned a {type(fleet).__name__}")
    try:
        try:
            fleet.reset(nodes[:1])
        except GuadalError:
            pass
        else:
            raise _fail(p, contract, "reset accepted one start node for two vehicles")
        fleet.reset(nodes)
        if fleet.positions != {0: nodes[0], 1: nodes[1]} or any(fleet.distances.values()):
            raise _fail(p, contract, f"after reset: positions {fleet.positions}, distances {fleet.distances}")
        first = fleet.take_measurement()
        if [(m.vehicle, m.node) for m in first] != [(0, nodes[0]), (1, nodes[1])] or not all(
            isinstance(m, Measurement) for m in first
        ):
            raise _fail(p, contract, f"take_measurement at the start gave {first}")
        # vehicle 0 walks away from its start until its 35 m budget is spent; vehicle 1 stays
        far = int(np.argmax(graph.distances_from(nodes[0])))
        walked = 0.0
        for _ in range(10):
            here = fleet.positions[0]
            nxt = graph.shortest_path(here, far)[1]
            reached = {0: False}
            while not all(reached.values()):
                reached, done = fleet.move({0: nxt})
            if fleet.positions[0] == nxt:
                walked += graph.edge_length(here, nxt)
            if done[0]:
                break
        if not (done[0] and walked <= 35.0 + 1e-9 and fleet.positions[1] == nodes[1]):
            raise _fail(p, contract, f"a vehicle with a 35 m budget walked {walked:g} m (done: {done})")
        if abs(fleet.distances[0] - walked) > 1e-6 or abs(fleet.remaining()[0] - (35.0 - walked)) > 1e-6:
            raise _fail(p, contract, f"distances {fleet.distances} after {walked:g} m along graph edges")
        last = fleet.take_measurement([0])
        if [(m.vehicle, m.node) for m in last] != [(0, fleet.positions[0])]:
            raise _fail(p, contract, f"take_measurement([0]) gave {last}")
        if not (isinstance(fleet.mission_time, float) and fleet.mission_time >= 0):
            raise _fail(p, contract, f"mission_time is {fleet.mission_time!r}")
    finally:
        fleet.close()
    fleet.close()


@dataclass
class _Started:
    """The bits of a prepared mission a backend may read (its map file, its start nodes, where a
    resumed run left its boats)."""

    graph: NavGraph
    initial_nodes: list[int]
    resume_nodes: list[int] | None = None


# --- ground truths ---------------------------------------------------------------------------------
def check_ground_truth_values(p: Plugin) -> None:
    """``generate`` returns one finite value per node, the same for the same generator seed,
    drawing its randomness from the generator it is given and nothing else."""
    graph = p.graph
    contract = "generate gives one finite value per node from the generator it is given"
    np.random.seed(1)
    a = np.asarray(p.cls(p.config).generate(graph, np.random.default_rng(4), p.base_dir), dtype=float)
    np.random.seed(2)
    b = np.asarray(p.cls(p.config).generate(graph, np.random.default_rng(4), p.base_dir), dtype=float)
    if a.shape != (graph.n_nodes,):
        raise _fail(p, contract, f"shape {a.shape}, not ({graph.n_nodes},)")
    if not np.all(np.isfinite(a)):
        raise _fail(p, contract, "some values are not finite")
    if not np.array_equal(a, b):
        raise _fail(p, contract, "the same seed gave different values")


# --- sensors ---------------------------------------------------------------------------------------
def check_sensor_reads(p: Plugin) -> None:
    """``cli_field`` names a Config field; ``read(lat, lon)`` gives a finite float or raises
    SensorError, at every node; ``close`` may be called twice."""
    from .vehicle.sensors import SensorContext, SensorError

    if getattr(p.cls, "cli_field", None) not in p.cls.Config.model_fields:
        raise _fail(p, "cli_field names a Config field", repr(getattr(p.cls, "cli_field", None)))
    graph = p.graph
    sensor = p.cls(p.config, SensorContext(graph, p.base_dir))
    try:
        for node in range(graph.n_nodes):
            try:
                value = sensor.read(float(graph.lat[node]), float(graph.lon[node]))
            except SensorError:
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise _fail(p, "read gives a finite float or raises SensorError", f"{value!r} at node {node}")
    finally:
        sensor.close()
    sensor.close()


# --- the suites ----------------------------------------------------------------------------------------
_COMMON = [check_config_round_trip, check_constructor_only_stores]
CHECKS: dict[str, list[Callable[[Plugin], None]]] = {
    "environment": [
        *_COMMON,
        check_environment_declarations,
        check_environment_reset_is_deterministic,
        check_environment_fields_and_metrics,
    ],
    "algorithm": [
        *_COMMON,
        check_planner_declarations,
        check_planner_requires_are_provided,
        check_planner_targets_are_valid,
        check_planner_is_deterministic,
    ],
    "backend": [*_COMMON, check_backend_fleet],
    "ground_truth": [*_COMMON, check_ground_truth_values],
    "sensor": [check_config_round_trip, check_sensor_reads],  # a sensor opens its port when built
}


def checks_for(p: Plugin) -> list[Callable[[Plugin], None]]:
    return list(CHECKS[p.kind])


def check_plugin(
    obj: Any, config: BaseModel | dict | None = None, *, kind: str | None = None, **options
) -> None:
    """Run every check of the plugin's kind; the first broken contract raises :class:`ContractError`."""
    p = plugin(obj, config, kind=kind, **options)
    for check in checks_for(p):
        check(p)


def _checker(kind: str):
    def run(obj: Any, config: BaseModel | dict | None = None, **options) -> None:
        check_plugin(obj, config, kind=kind, **options)

    run.__name__ = f"check_{'planner' if kind == 'algorithm' else kind}"
    run.__doc__ = f"Every check of the {kind} contract (see :func:`check_plugin`)."
    return run


check_environment = _checker("environment")
check_planner = _checker("algorithm")
check_backend = _checker("backend")
check_ground_truth = _checker("ground_truth")
check_sensor = _checker("sensor")


def all_checks(items: Iterable[Any]) -> list[tuple[Plugin, Callable[[Plugin], None]]]:
    """``(plugin, check)`` for every check of every plugin in ``items`` (see :func:`plugin`)."""
    return [(p, check) for p in map(plugin, items) for check in checks_for(p)]


def parametrize_with_checks(items: Iterable[Any]):
    """A pytest decorator: one test per (plugin, check), with ids like ``GreedyStd-check_...``."""
    import pytest

    cases = all_checks(items)
    return pytest.mark.parametrize(
        "plugin, check", cases, ids=[f"{p.kind}-{p.name}-{check.__name__}" for p, check in cases]
    )

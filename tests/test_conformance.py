"""guadal_cli.testing: every built-in plugin keeps its contract, and a broken one is named."""

from __future__ import annotations

import os

import numpy as np
import pytest
from pydantic import BaseModel
from support.vehicle import Probe

from guadal_cli import plugins
from guadal_cli.envs.gp import GPEnvironment
from guadal_cli.envs.ground_truth import ShekelField
from guadal_cli.fleet.remote import RealBackend
from guadal_cli.planners.base import SEQUENTIAL, Planner
from guadal_cli.planners.greedy import GreedyStd
from guadal_cli.stack import Stack
from guadal_cli.testing import (
    ContractError,
    check_backend,
    check_environment,
    check_graph,
    check_ground_truth,
    check_planner,
    check_sensor,
    parametrize_with_checks,
    start_nodes,
)
from guadal_cli.vehicle.sensors import SerialSensor

CONFIGS = {
    ("algorithm", "policy"): {"model": "support.rl:std_ahead"},  # a hand-written sequential policy
    ("backend", "sitl"): {"level": "sitl", "launch": True, "speedup": 200},
    ("ground_truth", "file"): {"path": "truth.csv"},
    ("sensor", "synthetic"): {"path": "truth.csv", "noise_std": 0.1, "seed": 1},
    ("sensor", "replay"): {"path": "survey.csv"},
}
#: need a live peer made in the test itself (below)
ELSEWHERE = {("backend", "real"), ("sensor", "serial")}
BUILT_IN = [
    (plugins.load(kind, name), CONFIGS.get((kind, name)))
    for kind in plugins.GROUPS
    for name in plugins.available(kind)
    if plugins.available(kind)[name].distribution == "guadal" and (kind, name) not in ELSEWHERE
]


def test_every_built_in_plugin_is_checked():
    """Only the two that need a live peer are checked elsewhere, in the tests below."""
    ours = {
        plugins.load(k, n)
        for k in plugins.GROUPS
        for n, info in plugins.available(k).items()
        if info.distribution == "guadal"
    }
    assert ours - {cls for cls, _ in BUILT_IN} == {RealBackend, SerialSensor}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Files the file ground truth and the synthetic and replay sensors read, on the checks' pond."""
    folder, graph = tmp_path_factory.mktemp("conformance"), check_graph()
    np.savetxt(folder / "truth.csv", graph.to_grid(np.arange(graph.n_nodes) / 10.0, fill=0.0), delimiter=",")
    samples = "".join(f"{graph.lat[n]},{graph.lon[n]},{n}\n" for n in range(0, graph.n_nodes, 4))
    (folder / "survey.csv").write_text("lat,lon,value\n" + samples)
    return folder


@parametrize_with_checks([(cls, config) for cls, config in BUILT_IN])
def test_built_in_plugins_keep_their_contracts(plugin, check, data):
    plugin.options["base_dir"] = data
    check(plugin)


def test_the_real_backend_against_a_running_stack():
    graph = check_graph()
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in start_nodes(graph, 2)]
    stack = Stack.launch(map_path=graph.map.source, vehicles=2, homes=homes, speedup=200, timeout=60)
    try:
        check_backend(RealBackend, {**stack.planner_backend(), "level": "real", "measurements": "synthetic"})
    finally:
        stack.down()


def test_the_serial_sensor_against_a_probe_on_a_pseudo_terminal():
    master, slave = os.openpty()
    probe = Probe(master, [b"VALUE 1.25\n"] * 60 + [b"ERR probe dry\n"] * 12)
    probe.start()
    try:
        check_sensor(SerialSensor, {"port": os.ttyname(slave), "timeout": 1.0})
    finally:
        os.close(slave)
        os.close(master)
    assert len(probe.requests) == check_graph().n_nodes


# --- broken plugins are named, with the contract they break -----------------------------------------
class Wanderer(Planner):
    """Sends each boat two cells away: not a neighbour, so wrong in sequential mode."""

    modes = (SEQUENTIAL,)

    def next_targets(self, observation):
        graph = observation.graph
        return {v: graph.neighbors(graph.neighbors(n)[0])[0] for v, n in observation.positions.items()}


class Eager(GreedyStd):
    def __init__(self, config=None):
        super().__init__(config)
        self.rng_ = np.random.default_rng(0)  # learned state belongs in reset


class Moody(GreedyStd):
    """Ignores its seed."""

    def next_targets(self, observation):
        return {
            v: int(np.random.choice(observation.graph.neighbors(n))) for v, n in observation.positions.items()
        }


class Salty(GreedyStd):
    requires = frozenset({"salinity"})


class Forgetful(GPEnvironment):
    """Draws its noise from the global generator: another world at every reset."""

    def reset(self, seed):
        super().reset(int(np.random.randint(1 << 30)))


class Coarse(GPEnvironment):
    def observation_fields(self):
        return {name: values[:-1] for name, values in super().observation_fields().items()}


class Clashing(GPEnvironment):
    metric_names = ("rmse", "coverage", "max_std")

    def metrics(self):
        m = super().metrics()
        return {"rmse": m["rmse"], "coverage": 0.0, "max_std": m["max_std"]}


class Short(ShekelField):
    def generate(self, graph, rng, base_dir=None):
        return super().generate(graph, rng, base_dir)[:-1]


class NotPydantic(Planner):
    class Config:
        pass

    def next_targets(self, observation):
        return {}


@pytest.mark.parametrize(
    "run, broken",
    [
        (lambda: check_planner(Wanderer), "next_targets returns valid targets in sequential mode"),
        (lambda: check_planner(Eager), "learned state is created in reset"),
        (lambda: check_planner(Moody), "reset(seed) makes decisions repeatable"),
        (lambda: check_planner(Salty), "no installed environment provides salinity"),
        (lambda: check_environment(Forgetful), "reset is deterministic for a seed"),
        (lambda: check_environment(Coarse), "observation fields hold one number per node"),
        (lambda: check_environment(Clashing), "metric names are unique and not the runner's columns"),
        (lambda: check_ground_truth(Short), "one finite value per node"),
        (lambda: check_planner(NotPydantic), "Config is a pydantic model"),
        (lambda: check_planner(GreedyStd, {"nonsense": 1}), "Config validates the plugin's section"),
    ],
    ids=lambda x: x if isinstance(x, str) else "",
)
def test_a_broken_plugin_fails_naming_the_contract(run, broken):
    with pytest.raises(ContractError, match="breaks the contract|subclasses none") as err:
        run()
    assert broken in str(err.value)
    assert isinstance(err.value, AssertionError)


def test_a_planner_is_checked_in_the_environment_it_is_given():
    class Pond(GPEnvironment):
        provides = frozenset({"mean"})

        def observation_fields(self):
            return {"mean": super().observation_fields()["mean"]}

    with pytest.raises(ContractError, match="Pond does not provide std"):
        check_planner(GreedyStd, environment=Pond)
    check_planner(GreedyStd, environment=(GPEnvironment, {"noise_std": 0.1}))


def test_parametrize_gives_one_test_per_plugin_and_check():
    mark = parametrize_with_checks([GreedyStd, (ShekelField, {"peaks": 2})])
    argnames, cases = mark.args
    assert argnames == "plugin, check"
    assert [(p.name, c.__name__) for p, c in cases][:2] == [
        ("GreedyStd", "check_config_round_trip"),
        ("GreedyStd", "check_constructor_only_stores"),
    ]
    assert cases[-1][0].config.peaks == 2 and isinstance(cases[-1][0].config, BaseModel)
    assert len(set(mark.kwargs["ids"])) == len(cases)

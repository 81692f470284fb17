"""Fixtures for the bridge tests: a private Mosquitto, a small lake with a land tongue, stacks."""

from __future__ import annotations

import numpy as np
import pytest
from support.vehicle import LAKE, Stack

from guadal_cli.channel.broker import start_broker
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map


@pytest.fixture(scope="session")
def lake(tmp_path_factory):
    mask = np.array([[c == "1" for c in row] for row in LAKE])
    m = Map(
        mask=mask,
        cell_size_m=5.0,
        reference={"row": 3, "col": 4, "lat": 37.418, "lon": -5.983},
        name="tongue",
    )
    path = tmp_path_factory.mktemp("map") / "tongue.json"
    m.save(path)
    m.source = path
    return m, NavGraph(m), path


@pytest.fixture(scope="session")
def broker():
    b = start_broker("auto")  # a private Mosquitto; the embedded broker where Mosquitto is not installed
    yield b
    b.stop()


@pytest.fixture
def stack(broker, lake, tmp_path):
    made = []

    def make(home_node, **kw):
        made.append(Stack(broker, lake, tmp_path, home_node, **kw))
        return made[-1]

    yield make
    for s in reversed(made):
        s.close()

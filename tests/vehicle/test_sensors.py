"""Sensor plugins: ground-truth grid, replayed survey, and a probe over a real pseudo-terminal."""

from __future__ import annotations

import os

import numpy as np
import pytest
from support.vehicle import Probe

from guadal_cli import plugins
from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map
from guadal_cli.vehicle.sensors import SensorContext, SensorError, build_sensor, parse_sensor_option


@pytest.fixture
def graph():
    mask = np.array([[c == "1" for c in row] for row in ["0110", "1111", "0110"]])
    return NavGraph(
        Map(mask=mask, cell_size_m=10.0, reference={"row": 1, "col": 1, "lat": 37.4, "lon": -5.9})
    )


def test_builtin_sensors_are_entry_points():
    found = plugins.available("sensor")
    assert {"synthetic", "replay", "serial"} <= set(found)
    assert found["serial"].target == "guadal_cli.vehicle.sensors:SerialSensor"


def test_sensor_option_maps_to_the_plugins_field():
    assert parse_sensor_option("serial:/dev/ttyUSB0") == {"type": "serial", "port": "/dev/ttyUSB0"}
    assert parse_sensor_option("synthetic:truth.csv") == {"type": "synthetic", "path": "truth.csv"}
    with pytest.raises(GuadalError, match="Did you mean 'serial'"):
        parse_sensor_option("serail:/dev/ttyUSB0")
    with pytest.raises(GuadalError, match="NAME:VALUE"):
        parse_sensor_option("synthetic")


def write_grid(path, rows):
    path.write_text("\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


def test_synthetic_reads_the_cell_under_the_boat(tmp_path, graph):
    write_grid(tmp_path / "truth.csv", [["x", 1.5, 2.5, "x"], [3, 4, 5, 6], ["x", 7, 8, "x"]])
    sensor = build_sensor({"type": "synthetic", "path": "truth.csv"}, SensorContext(graph, tmp_path))
    m = graph.map
    assert sensor.read(m.lat[1, 2], m.lon[1, 2]) == 5.0
    # 3 m off the centre of cell (2, 1) is still that cell
    assert sensor.read(m.lat[2, 1] + 3 / 111_000, m.lon[2, 1]) == 7.0


def test_synthetic_noise_is_seeded(tmp_path, graph):
    write_grid(tmp_path / "t.csv", [[0, 1, 1, 0], [1, 1, 1, 1], [0, 1, 1, 0]])
    section = {"type": "synthetic", "path": str(tmp_path / "t.csv"), "noise_std": 0.5, "seed": 3}
    lat, lon = graph.map.lat[1, 1], graph.map.lon[1, 1]
    s1, s2 = build_sensor(section, SensorContext(graph)), build_sensor(section, SensorContext(graph))
    r1 = [s1.read(lat, lon) for _ in range(200)]
    assert r1 == [s2.read(lat, lon) for _ in range(200)]
    assert 0.4 < np.std(r1) < 0.6 and abs(np.mean(r1) - 1.0) < 0.15


def test_synthetic_grid_of_the_wrong_shape_is_named(tmp_path, graph):
    write_grid(tmp_path / "t.csv", [[1, 2], [3, 4]])
    with pytest.raises(GuadalError, match=r"sensor.path: .* has shape \(2, 2\), the map is \(3, 4\)"):
        build_sensor({"type": "synthetic", "path": str(tmp_path / "t.csv")}, SensorContext(graph))


def test_replay_gives_the_nearest_sample(tmp_path, graph):
    m = graph.map
    (tmp_path / "s.csv").write_text(
        f"lat,lon,value\n{m.lat[1, 0]},{m.lon[1, 0]},10\n{m.lat[1, 3]},{m.lon[1, 3]},20\n"
    )
    sensor = build_sensor({"type": "replay", "path": str(tmp_path / "s.csv")}, SensorContext(graph))
    assert sensor.read(m.lat[1, 1], m.lon[1, 1]) == 10.0
    assert sensor.read(m.lat[2, 2], m.lon[2, 2]) == 20.0
    (tmp_path / "n.csv").write_text("node,value\n0,1.25\n")
    assert (
        build_sensor({"type": "replay", "path": str(tmp_path / "n.csv")}, SensorContext(graph)).read(
            37.4, -5.9
        )
        == 1.25
    )


@pytest.mark.parametrize(
    "text, message",
    [
        ("lat,lon,value\n1,2,x\n", "line 2 must give numbers"),
        ("node,value\n99,1\n", "node 99 is not on the map"),
        ("a,b\n1,2\n", "line 2 must give numbers"),
        ("lat,lon,value\n", "has no samples"),
    ],
)
def test_replay_bad_files_get_one_sentence(tmp_path, graph, text, message):
    (tmp_path / "s.csv").write_text(text)
    with pytest.raises(GuadalError, match=message):
        build_sensor({"type": "replay", "path": str(tmp_path / "s.csv")}, SensorContext(graph))


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    yield master, os.ttyname(slave)
    os.close(master)
    os.close(slave)


def test_serial_probe_over_a_pty(pty_pair, graph):
    master, port = pty_pair
    probe = Probe(master, [b"VALUE 7.25\n", b"ERR fouled membrane\n", None, b"HELLO\n", b"VALUE -0.5\n"])
    probe.start()
    sensor = build_sensor({"type": "serial", "port": port, "timeout": 0.3}, SensorContext(graph))
    try:
        assert sensor.read(37.4, -5.9) == 7.25
        with pytest.raises(SensorError, match="reported an error: fouled membrane"):
            sensor.read(37.4, -5.9)
        with pytest.raises(SensorError, match="did not answer within 0.3 s"):
            sensor.read(37.4, -5.9)
        with pytest.raises(SensorError, match="answered 'HELLO'; expected 'VALUE <number>'"):
            sensor.read(37.4, -5.9)
        assert sensor.read(37.4, -5.9) == -0.5
    finally:
        sensor.close()
    probe.join(2)
    assert probe.requests == [b"READ"] * 5


def test_serial_port_that_does_not_exist(graph, tmp_path):
    with pytest.raises(GuadalError, match="sensor serial: cannot open"):
        build_sensor({"type": "serial", "port": str(tmp_path / "ttyNOPE")}, SensorContext(graph))

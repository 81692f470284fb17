"""RemoteFleet against a real stack: Mosquitto, the MAVLink emulator and one bridge per boat.

One stack serves the module (starting one costs seconds); the test that stops a bridge runs last.
"""

from __future__ import annotations

import signal
import threading

import pytest
from support import LAKE
from support.fleet import Inbox, login, wait_for

from guadal_cli.channel import protocol as msg
from guadal_cli.channel.broker import start_broker
from guadal_cli.errors import GuadalError
from guadal_cli.fleet.remote import RemoteFleet, SitlConfig
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.mission import auto_positions
from guadal_cli.stack import Stack

N = 3


@pytest.fixture(scope="module")
def graph():
    return NavGraph(load_map(LAKE))


def probe_value(node: int) -> float:
    """What the boats' (replayed) probes read at a node."""
    return 100.0 + 0.5 * node


@pytest.fixture(scope="module")
def stack(graph, tmp_path_factory):
    survey = tmp_path_factory.mktemp("probe") / "survey.csv"
    survey.write_text("node,value\n" + "".join(f"{n},{probe_value(n)}\n" for n in range(graph.n_nodes)))
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in auto_positions(graph, N)]
    s = Stack.launch(
        map_path=LAKE,
        vehicles=N,
        homes=homes,
        speedup=100,
        broker_kind="mosquitto",
        timeout=60,
        bridge_args=["--sensor", f"replay:{survey}"],
    )
    yield s
    s.down()


def make_fleet(graph, stack_or_port, max_distance=200.0, **overrides):
    """A planner on a launched stack, with the stack's planner user and fleet key (or on a bare port)."""
    settings = {"hop_timeout": 30, "reset_timeout": 60, "connect_timeout": 20, **overrides}
    if isinstance(stack_or_port, Stack):
        s = stack_or_port
        settings = {
            "port": s.broker_port,
            "username": "planner",
            "password_file": str(s.secrets.user_password_file("planner")),
            "key_file": str(s.secrets.key_file),
            **settings,
        }
    else:
        settings["port"] = stack_or_port
    config = SitlConfig(level="sitl", **settings)
    return RemoteFleet(graph, N, max_distance, lambda v, node: float(node), config)


def signed(stack, topic: str, kind: str, **fields) -> bytes:
    """A payload signed with the stack's fleet key (what a compromised boat could send)."""
    return msg.Codec(stack.secrets.key_file.read_text().strip().encode()).encode(topic, kind, **fields)


def drive(fleet, targets):
    """The runner's inner loop: hops until every vehicle reached its target or is done."""
    reached = {v: False for v in targets}
    while not all(reached.values()):
        reached, done = fleet.move(targets)
    return done


def test_hops_move_the_boats_and_count_graph_metres(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    try:
        fleet.reset(start)
        assert fleet.positions == dict(enumerate(start)) and fleet.distances == {0: 0.0, 1: 0.0, 2: 0.0}
        hops = {v: graph.neighbors(n)[0] for v, n in enumerate(start)}
        hops = {v: t for v, t in hops.items() if t not in start}
        reached, done = fleet.move(hops)
        assert all(reached.values()) and not any(done.values())
        for v, target in hops.items():
            assert fleet.positions[v] == target
            assert fleet.distances[v] == pytest.approx(graph.edge_length(start[v], target))
        assert fleet.mission_time > 0  # the boats' own clock advanced
        samples = fleet.take_measurement()
        assert [(m.vehicle, m.node, m.value) for m in samples] == [
            (v, n, float(n)) for v, n in fleet.positions.items()
        ]
        track: list[dict] = []
        wait_for(lambda: track.extend(fleet.track_rows()) or track, 10, "no GPS fix was recorded")
        assert set(track[0]) == {"vehicle", "lat", "lon", "time_s"} and track[0]["time_s"] >= 0
        # a re-sent command may be answered twice (stale/duplicate); nothing else may be dropped
        assert set(fleet.dropped) <= {"stale", "duplicate"}
    finally:
        fleet.close()


def test_reset_sails_to_the_start_nodes_without_counting_it(graph, stack):
    homes = auto_positions(graph, N)
    elsewhere = [n for n in range(graph.n_nodes) if 12 <= graph.distance(homes[0], n) <= 20][::7][:N]
    fleet = make_fleet(graph, stack)
    try:
        fleet.reset(elsewhere)
        assert fleet.positions == dict(enumerate(elsewhere)) and fleet.distances == {0: 0.0, 1: 0.0, 2: 0.0}
        for v, node in enumerate(elsewhere):  # the boats are really there: where they said they arrived
            arrival = fleet.vehicles[v].goto.reply
            x, y = graph.map.projection.to_xy(arrival["lat"], arrival["lon"])
            assert abs(float(x) - graph.x[node]) < 3 and abs(float(y) - graph.y[node]) < 3
        fleet.reset(homes)  # and back, for the next tests
        assert fleet.positions == dict(enumerate(homes)) and fleet.distances == {0: 0.0, 1: 0.0, 2: 0.0}
    finally:
        fleet.close()


def test_a_silent_vehicle_makes_the_hop_time_out_with_a_sentence(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack, hop_timeout=1.0)
    bridge = next(p for p in stack.processes if p.name == "bridge-1")
    try:
        fleet.reset(start)
        target = next(n for n in graph.neighbors(start[1]) if n not in start)
        bridge.signal(signal.SIGSTOP)  # frozen: connected, but answers nothing
        try:
            with pytest.raises(
                GuadalError,
                match=rf"vehicle 1 did not reach node {target} within 1 s "
                r"\(goto seq \d+ never acknowledged, last fix [\d.]+ m from it\)",
            ):
                fleet.move({1: target})
        finally:
            bridge.signal(signal.SIGCONT)
    finally:
        fleet.close()


def test_vehicle_measurements_come_from_the_boats_probes(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack, measurements="vehicle")
    try:
        fleet.reset(start)
        target = next(n for n in graph.neighbors(start[0]) if n not in start)
        drive(fleet, {0: target})
        samples = fleet.take_measurement([0, 2])
        assert [(m.vehicle, m.node, m.value) for m in samples] == [
            (0, target, probe_value(target)),
            (2, start[2], probe_value(start[2])),
        ]
        for m in samples:  # where the boat really was: within the arrival radius of the node
            x, y = graph.map.projection.to_xy(m.lat, m.lon)
            assert abs(float(x) - graph.x[m.node]) < 3 and abs(float(y) - graph.y[m.node]) < 3
            assert m.time_s >= 0
    finally:
        fleet.close()


def test_a_vehicle_in_failsafe_is_done_and_the_others_go_on(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    raw = Inbox(stack.broker_port, login=login(stack, "vehicle-1"))
    try:
        fleet.reset(start)
        status = msg.topic("guadal", 1, "status")
        raw.client.publish(status, signed(stack, status, "status", state="failsafe"), qos=1).wait_for_publish(
            10
        )
        wait_for(lambda: fleet.vehicles[1].problem, 10, "the failsafe status was not taken into account")
        hops = {v: next(n for n in graph.neighbors(start[v]) if n not in start) for v in (0, 1)}
        reached, done = fleet.move(hops)
        assert done == {0: False, 1: True, 2: False} and reached == {0: True, 1: True}
        assert fleet.positions[1] == start[1] and fleet.distances[1] == 0.0
        assert fleet.problems == ["vehicle 1 entered failsafe; it takes no further part in the mission."]
    finally:
        raw.close()
        fleet.close()


def test_bad_payloads_are_counted_and_the_mission_goes_on(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    raw = Inbox(stack.broker_port, login=login(stack, "vehicle-0"))
    try:
        fleet.reset(start)
        ack = msg.topic("guadal", 0, "ack")
        goto = fleet.vehicles[0].goto
        session = fleet.session
        other_key = msg.Codec(b"another fleet's key, 32 bytes ok")
        bad = [
            b"{not json",
            b"x" * 20_000,  # oversized
            signed(stack, ack, "teleport", seq=1),  # unknown type
            signed(stack, ack, "ack", session=session, seq="7", status="reached"),  # wrong field type
            msg.encode("ack", session=session, seq=goto.seq, status="reached"),  # unsigned
            other_key.encode(ack, "ack", session=session, seq=goto.seq, status="reached"),  # wrong key
            signed(
                stack, msg.topic("guadal", 1, "ack"), "ack", session=session, seq=goto.seq, status="reached"
            ),
            signed(stack, ack, "ack", session=session, seq=goto.seq - 1, status="reached"),  # stale seq
            signed(stack, ack, "ack", session=session, seq=goto.seq, status="reached"),  # duplicate
            signed(stack, ack, "ack", session="0123456789abcdef", seq=goto.seq, status="reached"),  # old run
        ]
        before = fleet.dropped.copy()
        for payload in bad:
            raw.client.publish(ack, payload, qos=1).wait_for_publish(10)
        expected = {
            "malformed": 4,
            "unsigned": 1,
            "bad_signature": 2,  # the wrong key, and a tag made for another topic
            "stale": 1,
            "duplicate": 1,
            "foreign_session": 1,
        }
        # (answers to the previous test's last commands may add stale ones: count from here)
        wait_for(
            lambda: all(fleet.dropped[k] - before[k] >= n for k, n in expected.items()),
            10,
            "the bad messages were not all counted",
        )
        assert set(fleet.dropped) <= set(expected)  # no handler error, nothing else
        target = next(n for n in graph.neighbors(start[0]) if n not in start)
        done = drive(fleet, {0: target})
        assert fleet.positions[0] == target and not done[0]
    finally:
        raw.close()
        fleet.close()


def test_broker_restart_mid_mission_loses_no_command(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    # distinct targets 20-30 m away: several hops each
    ring = [n for n in range(graph.n_nodes) if 20 <= graph.distance(start[1], n) <= 30 and n not in start]
    far = dict(enumerate(ring[:: max(1, len(ring) // N)][:N]))
    outcome: dict = {}

    def mission():
        try:
            outcome["done"] = drive(fleet, far)
        except Exception as exc:  # reported by the assertion below
            outcome["error"] = exc

    broker = stack.processes[0]
    try:
        fleet.reset(start)
        runner = threading.Thread(target=mission)
        runner.start()
        wait_for(lambda: all(v.goto.open for v in fleet.vehicles), 10, "the hops did not start")
        broker.popen.kill()  # the broker dies with commands in flight
        broker.popen.wait(5)
        wait_for(lambda: not fleet._connected, 10, "the fleet did not notice the broker's death")
        replacement = start_broker("mosquitto", port=stack.broker_port, secrets=stack.secrets)
        broker.popen = replacement.process  # so the stack stops the new one
        broker.pid = replacement.pid
        runner.join(90)
        assert not runner.is_alive(), "the mission did not finish after the broker came back"
        assert "error" not in outcome, outcome.get("error")
        assert fleet.positions == far
        assert not any(outcome["done"].values())
        for v in range(N):  # every hop was paid for exactly once
            assert fleet.distances[v] == pytest.approx(graph.distance(start[v], far[v]))
    finally:
        fleet.close()


def test_unreachable_broker_is_one_sentence(graph):
    fleet = make_fleet(graph, 1, connect_timeout=1.0)  # nothing listens on port 1
    try:
        with pytest.raises(
            GuadalError, match=r"cannot reach the MQTT broker at mqtt://127\.0\.0\.1:1 within 1 s"
        ):
            fleet.reset(auto_positions(graph, N))
    finally:
        fleet.close()


def test_missing_bridges_are_named(graph):
    broker = start_broker("mosquitto")
    fleet = make_fleet(graph, broker.port, connect_timeout=1.0)
    try:
        with pytest.raises(GuadalError, match=r"vehicles 0, 1, 2 not online .* is a bridge running for each"):
            fleet.reset(auto_positions(graph, N))
    finally:
        fleet.close()
        broker.stop()


def test_a_vehicle_whose_bridge_stops_is_done_with_a_reason(graph, stack):
    """Runs last in the module: it stops bridge 2."""
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    try:
        fleet.reset(start)
        bridge = next(p for p in stack.processes if p.name == "bridge-2")
        bridge.popen.terminate()
        bridge.popen.wait(10)
        wait_for(lambda: fleet.vehicles[2].problem, 10, "the fleet did not notice the bridge going offline")
        target = next(n for n in graph.neighbors(start[0]) if n not in start)
        other = next(n for n in graph.neighbors(start[2]) if n not in start)
        reached, done = fleet.move({0: target, 2: other})
        assert done[2] and reached[2] and not done[0]
        assert fleet.positions[2] == start[2] and fleet.positions[0] == target
        assert fleet.problems == [
            "vehicle 2 went offline (its bridge stopped or lost the broker); it takes no further part in the mission."
        ]
    finally:
        fleet.close()


def test_real_mission_reads_its_password_from_the_environment(monkeypatch):
    from support import ROOT

    from guadal_cli.mission import prepare

    monkeypatch.delenv("GUADAL_MQTT_PASSWORD", raising=False)
    prep = prepare(ROOT / "missions" / "lake_greedy_real.yaml")
    assert prep.backend_config.measurements == "vehicle" and prep.backend_config.tls
    backend = prep.backend_cls(prep.backend_config)
    with pytest.raises(
        GuadalError, match="backend.password_env: environment variable 'GUADAL_MQTT_PASSWORD' is not set"
    ):
        backend.make_fleet(graph=prep.graph, fleet_config=prep.mission.fleet, sensor=None, mission=prep)


def test_a_misspelt_backend_setting_is_named(write_mission):
    from support import base_mission

    from guadal_cli.mission import prepare

    path = write_mission(base_mission(backend={"level": "sitl", "launch": True, "speedupp": 5}))
    with pytest.raises(GuadalError, match=r"backend\.speedupp: unknown key \(allowed: .*speedup"):
        prepare(path)

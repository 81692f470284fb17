"""The command channel under attack, and after restarts: real brokers, bridges and emulator.

Each attack of the field report is replayed by a real MQTT client on a launched stack, once on
Mosquitto and once on the embedded broker. The attacker holds a leaked broker password (the
planner's or a boat's); anonymous clients do not even get in (``test_broker.py``). Without the
fleet key nothing it sends is obeyed, and what it tried is counted in the fleet's health (the
manifest's ``fleet`` section). With the key too (a compromised boat), a forged ``reached`` ack
is still not booked while the boat's own telemetry says it is elsewhere.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading

import pytest
import yaml
from support import LAKE, base_mission, run_cli
from support.fleet import Inbox, login, wait_for

from guadal_cli.channel import protocol as msg
from guadal_cli.channel.broker import mosquitto_binary
from guadal_cli.fleet.remote import RemoteFleet, SitlConfig
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.mission import auto_positions, prepare
from guadal_cli.runner import MissionRunner
from guadal_cli.stack import Stack

N = 2
KINDS = ["embedded"] + (["mosquitto"] if mosquitto_binary() else [])


@pytest.fixture(scope="module")
def graph():
    return NavGraph(load_map(LAKE))


@pytest.fixture(scope="module", params=KINDS)
def stack(request, graph):
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in auto_positions(graph, N)]
    s = Stack.launch(
        map_path=LAKE, vehicles=N, homes=homes, speedup=50, broker_kind=request.param, timeout=60
    )
    yield s
    s.down()


def make_fleet(graph, stack, **overrides) -> RemoteFleet:
    settings = {
        "hop_timeout": 30,
        "reset_timeout": 60,
        "connect_timeout": 20,
        "offline_grace": 20,
        **overrides,
    }
    return RemoteFleet(
        graph, N, 400.0, lambda v, node: float(node), SitlConfig(**stack.planner_backend(), **settings)
    )


def drive(fleet, targets):
    reached = {v: False for v in targets}
    while not all(reached.values()):
        reached, done = fleet.move(targets)
    return done


def away_from(graph, node, start, lo=20, hi=40):
    return next(n for n in range(graph.n_nodes) if lo <= graph.distance(node, n) <= hi and n not in start)


def test_forged_commands_and_statuses_are_refused_and_counted(graph, stack):
    start = auto_positions(graph, N)
    # before the mission: a huge-seq ping on boat 0 (once, it locked the boat out of every planner)
    attacker = Inbox(stack.broker_port, login=login(stack, "planner"))  # a leaked password, no key
    command = msg.topic("guadal", 0, "command")
    attacker.client.publish(
        command, msg.encode("ping", session="x" * 16, seq=10**12), qos=1
    ).wait_for_publish(10)
    fleet = make_fleet(graph, stack)
    try:
        fleet.reset(start)
        session = fleet.session
        lure = away_from(graph, start[0], start)  # where the attacker wants boat 0
        wrong_key = msg.Codec(b"not the fleet key, but 32 bytes!")
        forged = [
            # a goto with a huge seq (once: the boat sailed off and ignored the planner from then on)
            msg.encode(
                "goto",
                session=session,
                seq=10**12,
                node=lure,
                lat=float(graph.lat[lure]),
                lon=float(graph.lon[lure]),
            ),
            # the planner's next seq (once: it collided with the planner's own goto)
            msg.encode(
                "goto",
                session=session,
                seq=fleet.vehicles[0].seq + 1,
                node=lure,
                lat=float(graph.lat[lure]),
                lon=float(graph.lon[lure]),
            ),
            wrong_key.encode(
                command,
                "goto",
                session=session,
                seq=fleet.vehicles[0].seq + 1,
                node=lure,
                lat=float(graph.lat[lure]),
                lon=float(graph.lon[lure]),
            ),
        ]
        for payload in forged:
            attacker.client.publish(command, payload, qos=1).wait_for_publish(10)
        # a retained "offline" on the planner's status (once: the whole fleet went to HOLD)
        planner_status = msg.topic("guadal", None, "status")
        attacker.client.publish(
            planner_status, msg.encode("status", state="offline", session=session), qos=1, retain=True
        ).wait_for_publish(10)

        # the boats obey only the planner: the same nodes and metres as without the attack
        targets = {v: away_from(graph, start[v], start, 15, 25) for v in range(N)}
        done = drive(fleet, targets)
        assert fleet.positions == targets and not any(done.values())
        for v in range(N):
            assert fleet.distances[v] == pytest.approx(graph.distance(start[v], targets[v]))
        assert fleet.problems == [] and fleet.lost == {}
        # and every attempt is in the fleet's health, as the bridge counted it
        wait_for(
            lambda: (
                fleet.health()["bridges"].get(0, {}).get("unsigned", 0) >= 3
                and fleet.health()["bridges"][0].get("bad_signature", 0) >= 1
            ),
            10,
            "the forged commands were not counted",
        )
        for v in range(N):  # the forged planner status reached every boat, and each refused it
            wait_for(
                lambda v=v: fleet.health()["bridges"].get(v, {}).get("unsigned", 0) >= 1,
                10,
                f"boat {v} did not count it",
            )
    finally:
        attacker.client.publish(planner_status, b"", qos=1, retain=True).wait_for_publish(10)  # clear it
        attacker.close()
        fleet.close()


def test_a_forged_reached_ack_is_not_booked_while_the_boat_is_elsewhere(graph, stack):
    """The attacker has boat 0's broker password and the fleet key; the boat is frozen away."""
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    boat = next(p for p in stack.processes if p.name == "bridge-0")
    attacker = Inbox(stack.broker_port, login=login(stack, "vehicle-0"))
    key = msg.Codec(stack.secrets.key_file.read_text().strip().encode())
    outcome: dict = {}
    try:
        fleet.reset(start)
        # a diagonal neighbour, 7 m away: beyond the 4 m arrival radius
        target = next(
            n for n in graph.neighbors(start[0]) if n not in start and graph.edge_length(start[0], n) > 6
        )
        boat.signal(19)  # SIGSTOP: the bridge hears nothing and answers nothing
        runner = threading.Thread(target=lambda: outcome.update(done=drive(fleet, {0: target})))
        runner.start()
        wait_for(lambda: fleet.vehicles[0].goto.node == target, 10, "the hop did not start")
        goto = fleet.vehicles[0].goto
        ack = msg.topic("guadal", 0, "ack")
        claim = dict(session=fleet.session, seq=goto.seq, status="reached", command="goto", node=target)
        attacker.client.publish(
            ack,
            key.encode(ack, "ack", **claim, lat=float(graph.lat[target]), lon=float(graph.lon[target])),
            qos=1,
        ).wait_for_publish(10)
        wait_for(lambda: fleet.dropped["unconfirmed_reach"] >= 1, 10, "the forged ack was not refused")
        assert fleet.positions[0] == start[0] and fleet.distances[0] == 0.0 and runner.is_alive()
    finally:
        boat.signal(18)  # SIGCONT: the real boat sails and arrives
    try:
        runner.join(60)
        assert not runner.is_alive() and fleet.positions[0] == target
        assert fleet.distances[0] == pytest.approx(graph.edge_length(start[0], target))
    finally:
        attacker.close()
        fleet.close()


def test_a_restarted_bridge_and_a_restarted_planner_resynchronise(graph, stack):
    start = auto_positions(graph, N)
    first = make_fleet(graph, stack)
    try:
        first.reset(start)
        far = {v: away_from(graph, start[v], start, 20, 30) for v in range(N)}
        outcome: dict = {}

        def mission():
            try:
                outcome["done"] = drive(first, far)
            except Exception as exc:  # reported below
                outcome["error"] = exc

        runner = threading.Thread(target=mission)
        runner.start()
        wait_for(lambda: first.vehicles[1].goto.count_distance, 10, "the mission did not start")
        stack.restart("bridge-1")  # mid-mission: a new bridge process, with no session
        runner.join(90)
        assert "error" not in outcome, outcome.get("error")
        assert first.positions == far and first.lost == {}
        for v in range(N):
            assert first.distances[v] == pytest.approx(graph.distance(start[v], far[v]))

        # a new planner takes over mid-mission (the old one hung): the boats follow the new session
        second = make_fleet(graph, stack)
        try:
            second.reset([far[v] for v in range(N)])
            assert second.positions == far and second.session != first.session
            drive(second, dict(enumerate(start)))  # and sail them back
            assert second.positions == dict(enumerate(start))
            # the old session's commands are refused from now on
            first.config = first.config.model_copy(update={"hop_timeout": 2.0})
            stale = next(n for n in graph.neighbors(far[0]) if n not in start)
            with pytest.raises(Exception, match="did not reach node"):
                first.move({0: stale})
            wait_for(
                lambda: second.health()["bridges"].get(0, {}).get("foreign_session", 0) >= 1,
                10,
                "the old planner's commands were not counted as foreign",
            )
            assert second.positions == dict(enumerate(start))
        finally:
            second.close()
    finally:
        first.close()


def test_a_killed_planner_is_replaced_by_the_next_run_without_manual_steps(graph, stack, tmp_path):
    """kill -9 of `guadal run` mid-mission: its last will puts the boats in failsafe HOLD; the
    next run's signed session start takes them back."""
    mission = base_mission(backend={**stack.planner_backend(), "offline_grace": 20})
    mission["fleet"].update(vehicles=N, max_distance=400.0)
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    first = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(path), "-o", str(tmp_path / "first"), "-q"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    metrics = tmp_path / "first" / "metrics.csv"
    try:
        wait_for(lambda: metrics.is_file() and len(metrics.read_text().splitlines()) > 3, 60, "no mission")
    finally:
        first.kill()
        first.wait(10)
    mission["fleet"]["max_distance"] = 20.0
    path.write_text(yaml.safe_dump(mission))
    second = run_cli("run", path, "-o", tmp_path / "second")
    assert second.returncode == 0, second.stderr
    manifest = json.loads((tmp_path / "second" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["fleet"]["problems"] == []


def test_operator_controls_reach_the_planner_once_and_only_from_the_operator(graph, stack):
    start = auto_positions(graph, N)
    fleet = make_fleet(graph, stack)
    operator = Inbox(stack.broker_port, login=login(stack, "operator"))
    boat = Inbox(stack.broker_port, login=login(stack, "vehicle-0"))  # may not write controls
    key = msg.Codec(stack.secrets.key_file.read_text().strip().encode())
    control = msg.topic("guadal", None, "control")
    try:
        fleet.reset(start)
        session = fleet.session
        sent = [
            key.encode(control, "control", session=session, id="a", action="pause"),
            key.encode(control, "control", session=session, id="a", action="pause"),  # repeated: once
            key.encode(control, "control", session="0" * 16, id="b", action="abort"),  # an earlier run's
            msg.encode("control", session=session, id="c", action="abort"),  # unsigned
            key.encode(control, "control", session=session, id="d", action="hold", vehicle=9),  # no such boat
            key.encode(control, "control", session=session, id="e", action="hold", vehicle=1),
        ]
        boat.client.publish(
            control, key.encode(control, "control", session=session, id="x", action="abort"), qos=1
        )
        for payload in sent:
            operator.client.publish(control, payload, qos=1).wait_for_publish(10)
        got: list = []
        wait_for(
            lambda: got.extend(fleet.pending_controls()) or len(got) >= 2, 10, "the controls did not arrive"
        )
        assert got == [
            {"action": "pause", "vehicle": None, "id": "a"},
            {"action": "hold", "vehicle": 1, "id": "e"},
        ]
        assert fleet.pending_controls() == []
        dropped = fleet.health()["dropped_messages"]
        assert dropped["foreign_session"] >= 1 and dropped["unsigned"] >= 1 and dropped["malformed"] >= 1
    finally:
        operator.close()
        boat.close()
        fleet.close()


def test_no_secret_reaches_the_logs_the_run_directory_or_the_manifest(graph, stack, tmp_path):
    """`guadal run` against the stack as its planner user, as `guadal stack up` prints it."""
    mission = base_mission(backend={**stack.planner_backend(), "offline_grace": 20})
    mission["fleet"].update(vehicles=N, max_distance=20.0)
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    result = run_cli("run", path, "-o", tmp_path / "run")
    assert result.returncode == 0, result.stderr
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["fleet"]["session"]
    secrets = [stack.secrets.key_file.read_text().strip()] + [
        p.read_text().strip() for p in (stack.secrets.directory / "users").iterdir()
    ]
    texts = [result.stdout, result.stderr] + [
        p.read_text(errors="replace") for p in (tmp_path / "run").rglob("*") if p.is_file()
    ]
    texts += [p.read_text(errors="replace") for p in (stack.state_dir / "logs").glob("*.log")]
    for secret in secrets:
        assert not any(secret in text for text in texts)


def test_a_mission_whose_every_boat_is_lost_ends_aborted(graph, stack, tmp_path):
    """Last in the module: it stops every bridge."""
    mission = base_mission(backend={**stack.planner_backend(), "offline_grace": 1.0})
    mission["fleet"].update(vehicles=N, max_distance=400.0)
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    out = tmp_path / "run"
    runner = MissionRunner(prepare(path), output=out)
    outcome: dict = {}
    thread = threading.Thread(target=lambda: outcome.update(result=runner.run()))
    thread.start()
    wait_for(
        lambda: (out / "metrics.csv").is_file() and len((out / "metrics.csv").read_text().splitlines()) > 2,
        60,
        "the mission did not start",
    )
    for p in stack.processes:
        if p.name.startswith("bridge-"):
            p.signal(15)  # SIGTERM: each bridge holds its boat and says offline
    thread.join(60)
    assert not thread.is_alive() and outcome["result"].status == "aborted"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "aborted"
    assert manifest["stop_reason"].startswith("every vehicle was lost: vehicle 0 went offline")
    assert len(manifest["fleet"]["problems"]) == N

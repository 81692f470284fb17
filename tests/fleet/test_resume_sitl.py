"""`kill -9` of `guadal run` at sitl, then `guadal resume`: the mission completes over MQTT and
MAVLink, with no measurement lost or taken twice.

The proof is the product's equivalence: the resumed sitl run visits the same nodes, covers the
same distances and records the same samples as the same mission at sim, uninterrupted.
"""

from __future__ import annotations

import csv
import json
import signal
import uuid

import yaml
from support import ROOT, run_cli, stop_after_steps
from support.fleet import describe_processes, processes_marked, wait_for

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def rows(run, name, source=None):
    with open(run / name, newline="") as fh:
        return [r for r in csv.DictReader(fh) if source is None or r["source"] == source]


def test_a_sitl_run_killed_mid_mission_resumes_to_the_sim_result(tmp_path, monkeypatch):
    mark = uuid.uuid4().hex
    monkeypatch.setenv("GUADAL_TEST_MARK", mark)  # inherited by every process the runs start
    sitl = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    sitl["map"] = str(ROOT / "maps" / "urban_lake.json")
    sitl["fleet"]["max_distance"] = 60
    sitl["backend"].update(speedup=200)
    sim = {**sitl, "backend": {"level": "sim"}}
    for level, mission in (("sim", sim), ("sitl", sitl)):
        (tmp_path / f"{level}.yaml").write_text(yaml.safe_dump(mission))
    MissionRunner(prepare(tmp_path / "sim.yaml"), output=tmp_path / "run-sim").run()

    out = tmp_path / "run-sitl"
    stop_after_steps(tmp_path / "sitl.yaml", out, 5)
    killed_at = len(rows(out, "metrics.csv")) - 1
    assert json.loads((out / "manifest.json").read_text())["status"] == "running"
    # the killed run's own stack notices and goes down
    try:
        wait_for(lambda: not processes_marked(mark), 60, "the killed run's stack to go down")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; still up: {describe_processes(processes_marked(mark))}") from None

    done = run_cli("resume", out, "--json", timeout=600)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["status"] == "complete"
    sim_out = tmp_path / "run-sim"
    plan = [(r["step"], r["vehicle"], r["node"], r["distance"]) for r in rows(out, "trajectory.csv", "plan")]
    assert plan == [
        (r["step"], r["vehicle"], r["node"], r["distance"]) for r in rows(sim_out, "trajectory.csv", "plan")
    ]
    samples = [(r["step"], r["vehicle"], r["node"], r["value"]) for r in rows(out, "measurements.csv")]
    assert samples == [
        (r["step"], r["vehicle"], r["node"], r["value"]) for r in rows(sim_out, "measurements.csv")
    ]
    assert len(set((s, v) for s, v, _, _ in samples)) == len(samples)  # none taken twice
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete" and manifest["steps"] > killed_at
    assert [r["after_step"] for r in manifest["resumes"]] == [killed_at]
    # nothing left running: the resumed run took its stack down too
    wait_for(lambda: not processes_marked(mark), 60, "the resumed run's stack is still up")


def test_a_resumed_sitl_run_goes_on_with_the_boats_still_alive(tmp_path):
    """A stack that outlives the run (``guadal stack up``); the run is killed, then one boat's
    bridge: resume loses that boat with one sentence and completes with the other two."""
    from guadal_cli.fleet.remote import RemoteFleet, SitlConfig
    from guadal_cli.stack import Stack

    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    mission["map"] = str(ROOT / "maps" / "urban_lake.json")
    mission["fleet"]["max_distance"] = 60
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({**mission, "backend": {"level": "sim"}}))
    prep = prepare(tmp_path / "m.yaml")
    graph = prep.graph
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in prep.initial_nodes]
    stack = Stack.launch(map_path=mission["map"], vehicles=3, homes=homes, speedup=200, timeout=60)
    try:
        mission["backend"] = {**stack.planner_backend(), "connect_timeout": 5}
        (tmp_path / "m.yaml").write_text(yaml.safe_dump(mission))
        out = tmp_path / "run"
        stop_after_steps(tmp_path / "m.yaml", out, 5)
        killed_at = len(rows(out, "metrics.csv")) - 1
        before = [r for r in rows(out, "measurements.csv") if int(r["step"]) <= killed_at]
        bridge = next(p for p in stack.processes if p.name == "bridge-1")
        bridge.signal(signal.SIGKILL)
        assert bridge.wait(10)

        done = run_cli("resume", out, "--json", timeout=600)
        assert done.returncode == 0, done.stderr
        assert json.loads(done.stdout)["status"] == "complete"
        manifest = json.loads((out / "manifest.json").read_text())
        assert [r["after_step"] for r in manifest["resumes"]] == [killed_at]
        lost = [p for p in manifest["fleet"]["problems"] if p.startswith("vehicle 1 ")]
        assert lost == [
            "vehicle 1 did not answer within 5 s when the run resumed (no position); "
            "the mission goes on without it."
        ] or lost == [
            "vehicle 1 did not answer within 5 s when the run resumed "
            "(no live status on guadal/vehicle/1/status); the mission goes on without it."
        ]
        # no sample lost or taken twice; the lost boat takes none after the resume, the others go on
        samples = rows(out, "measurements.csv")
        assert samples[: len(before)] == before
        assert len({(r["step"], r["vehicle"]) for r in samples}) == len(samples)
        after = [r for r in samples if int(r["step"]) > killed_at]
        assert {r["vehicle"] for r in after} == {"0", "2"}
        plan = [r for r in rows(out, "trajectory.csv", "plan") if int(r["step"]) > killed_at]
        assert len({(r["node"], r["distance"]) for r in plan if r["vehicle"] == "1"}) == 1  # stays put
        # the boats' state as their bridges report it, and the lost boat's fault
        state = [r for r in rows(out, "vehicles.csv") if int(r["step"]) > killed_at]
        alive = [r for r in state if r["vehicle"] != "1"]
        assert alive and all(r["mode"] == "GUIDED" and r["armed"] == "1" for r in alive)
        assert all(0 <= float(r["battery"]) <= 100 and 0 <= float(r["link_age_s"]) < 5 for r in alive)
        assert [r["fault"] for r in state if r["vehicle"] == "1"][-1] == lost[0]
        assert {r["vehicle"] for r in rows(out, "targets.csv") if int(r["step"]) > killed_at} <= {"0", "2"}

        # positions at resume come from the boats' GPS, not from the record: told a wrong node,
        # each live boat goes on from the node nearest its fix, its recorded distance kept
        far = max(range(graph.n_nodes), key=lambda n: graph.distance(n, prep.initial_nodes[0]))
        config = SitlConfig(**{**stack.planner_backend(), "connect_timeout": 5})
        fleet = RemoteFleet(graph, 3, 60.0, lambda v, node: float(node), config)
        try:
            fleet.restore({0: far, 1: far, 2: far}, {0: 10.0, 1: 20.0, 2: 30.0}, 50.0)
            for v in (0, 2):
                fix = fleet.vehicles[v].fix
                assert fleet.positions[v] == graph.nearest_node(*fix) != far
            assert fleet.positions[1] == far and set(fleet.lost) == {1}
            assert fleet.distances == {0: 10.0, 1: 20.0, 2: 30.0} and fleet.mission_time >= 50.0
        finally:
            fleet.close()
    finally:
        stack.down()


def test_a_boat_that_answers_but_cannot_reach_its_node_in_time_is_lost_held_and_the_other_goes_on(
    tmp_path, monkeypatch
):
    """At resume each boat is sent to the node nearest its GPS fix; one that answers but does not
    get there within ``backend.reset_timeout`` (here: its node is made 40+ m away, at 4x
    real time) is lost with one sentence and told to HOLD, and the fleet goes on with the other."""
    from guadal_cli.fleet.remote import RemoteFleet, SitlConfig
    from guadal_cli.stack import Stack

    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    mission["map"] = str(ROOT / "maps" / "urban_lake.json")
    mission["fleet"].update(vehicles=2, max_distance=60)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump({**mission, "backend": {"level": "sim"}}))
    prep = prepare(tmp_path / "m.yaml")
    graph, start = prep.graph, [int(n) for n in prep.initial_nodes]
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in start]
    far = max(range(graph.n_nodes), key=lambda n: graph.distance(n, start[0]))
    assert graph.distance(far, start[0]) > 40.0  # 0.5 m/s for 3 s at 4x covers 6 m
    nearest = graph.nearest_node
    monkeypatch.setattr(  # boat 0's fix is taken to be nearest a node it cannot reach in time
        graph, "nearest_node", lambda lat, lon: far if nearest(lat, lon) == start[0] else nearest(lat, lon)
    )
    stack = Stack.launch(map_path=mission["map"], vehicles=2, homes=homes, speedup=4.0, timeout=60)
    try:
        config = SitlConfig(**{**stack.planner_backend(), "connect_timeout": 10, "reset_timeout": 3})
        fleet = RemoteFleet(graph, 2, 60.0, lambda v, node: float(node), config)
        try:
            fleet.restore({0: start[0], 1: start[1]}, {0: 5.0, 1: 6.0}, 10.0)
            assert fleet.lost == {
                0: f"vehicle 0 did not reach node {far} within 3 s when the run resumed; "
                "the mission goes on without it."
            }
            assert fleet.positions[1] == start[1] and fleet.distances[1] == 6.0
            wait_for(lambda: fleet.vehicle_status()[0]["mode"] == "HOLD", 10, "boat 0 told to HOLD")
            # the other boat sails on: one hop to a neighbour, counted on top of its recorded distance
            hop = min(graph.neighbors(start[1]), key=lambda n: graph.distance(n, start[1]))
            reached = {}
            while not reached.get(1):
                reached, _ = fleet.move({1: hop})
            assert fleet.positions[1] == hop and fleet.distances[1] > 6.0
        finally:
            fleet.close()
    finally:
        stack.down()

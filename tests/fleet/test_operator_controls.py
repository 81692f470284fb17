"""At sitl, an operator's signed control on the planner's topic holds a boat and aborts the run.

The same rules apply as for the web console's requests (``tests/web``); here they travel the
fleet's own authenticated channel: the ``operator`` broker user, signed with the fleet key, for
the running planner's session.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import yaml
from support import LAKE, base_mission, start_cli, stop_after_steps
from support.fleet import Inbox, login, wait_for

from guadal_cli.channel import protocol as msg
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map
from guadal_cli.mission import auto_positions
from guadal_cli.stack import Stack

N = 2


@pytest.fixture(scope="module")
def stack():
    graph = NavGraph(load_map(LAKE))
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in auto_positions(graph, N)]
    s = Stack.launch(map_path=LAKE, vehicles=N, homes=homes, speedup=20, broker_kind="embedded", timeout=60)
    yield s
    s.down()


def _rows(path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _events(run_dir) -> list[dict]:
    try:
        return json.loads((run_dir / "manifest.json").read_text()).get("events", [])
    except (OSError, json.JSONDecodeError):
        return []


def _long_mission(stack, tmp_path) -> Path:
    """A mission on ``stack`` long enough to be controlled mid-way; its file."""
    mission = base_mission(backend={**stack.planner_backend(), "offline_grace": 20})
    mission["fleet"].update(vehicles=N, max_distance=3000.0)
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(mission))
    return path


def _operator(stack) -> tuple[Inbox, msg.Codec]:
    """The stack's operator on its broker, and the fleet key that signs controls."""
    operator = Inbox(stack.broker_port, login=login(stack, "operator"))
    return operator, msg.Codec(stack.secrets.key_file.read_text().strip().encode())


def _control(operator, key, session: str, request_id: str, action: str, vehicle: int | None = None) -> None:
    """An operator's signed control on the fleet topic, for the planner session ``session``."""
    control = msg.topic("guadal", None, "control")
    fields = {"vehicle": vehicle} if vehicle is not None else {}
    operator.client.publish(
        control,
        key.encode(control, "control", session=session, id=request_id, action=action, **fields),
        qos=1,
    ).wait_for_publish(10)


def test_signed_controls_on_the_topic_hold_a_boat_then_abort_the_mission(stack, tmp_path):
    path, run_dir = _long_mission(stack, tmp_path), tmp_path / "run"
    proc = start_cli("run", path, "-o", run_dir, "-q")
    operator, key = _operator(stack)
    status_topic = msg.topic("guadal", None, "status")
    try:
        operator.subscribe(status_topic)
        online = operator.wait(
            lambda: [m for m in operator.on(status_topic) if json.loads(m.payload).get("state") == "online"],
            60,
            "the planner's online status",
        )
        session = json.loads(online[-1].payload)["session"]
        wait_for(lambda: len(_rows(run_dir / "metrics.csv")) > 3, 60, "the mission's first steps")

        _control(operator, key, session, "h1", "hold", vehicle=1)
        wait_for(lambda: _events(run_dir), 30, "the hold in the run's events")
        held_from = int(_rows(run_dir / "metrics.csv")[-1]["step"])
        wait_for(
            lambda: int(_rows(run_dir / "metrics.csv")[-1]["step"]) > held_from + 3, 60, "steps while held"
        )
        _control(operator, key, session, "a1", "abort")
        assert proc.wait(timeout=120) == 0, proc.stderr.read()
    finally:
        operator.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["status"] == "interrupted"
    assert manifest["error"] == "aborted by operator operator (control topic)"
    assert [(e["kind"], e["action"], e["vehicle"]) for e in manifest["events"]] == [
        ("control", "hold", 1),
        ("control", "abort", None),
    ]
    plan = [r for r in _rows(run_dir / "trajectory.csv") if r["source"] == "plan"]
    held = {r["node"] for r in plan if r["vehicle"] == "1" and int(r["step"]) > held_from}
    moving = {r["node"] for r in plan if r["vehicle"] == "0" and int(r["step"]) > held_from}
    assert len(held) == 1 and len(moving) > 1


def test_a_resumed_run_takes_controls_on_the_topic(stack, tmp_path):
    """After a kill -9 and ``guadal resume``, the resumed planner's session takes the operator's
    hold (the boat's bridge is told to HOLD) and abort, as a new run's would."""
    path, run_dir = _long_mission(stack, tmp_path), tmp_path / "run"
    operator, key = _operator(stack)
    status_topic = msg.topic("guadal", None, "status")
    boat_status = msg.topic("guadal", 1, "status")
    operator.subscribe(status_topic, boat_status)

    def sessions() -> list[str]:
        online = [json.loads(m.payload) for m in operator.on(status_topic)]
        return list(dict.fromkeys(s["session"] for s in online if s.get("state") == "online"))

    proc = None
    try:
        stop_after_steps(path, run_dir, 4, timeout=60)  # kill -9 once four steps are written
        killed_at = len(_rows(run_dir / "metrics.csv")) - 1
        proc = start_cli("resume", run_dir, "-q")
        wait_for(lambda: len(sessions()) == 2, 60, "the resumed planner's session")
        wait_for(lambda: len(_rows(run_dir / "metrics.csv")) > killed_at + 3, 60, "steps after the resume")
        session = sessions()[-1]
        held_at = len(operator.on(boat_status))
        _control(operator, key, session, "h1", "hold", vehicle=1)
        operator.wait(
            lambda: any(json.loads(m.payload)["state"] == "hold" for m in operator.on(boat_status)[held_at:]),
            30,
            "boat 1's bridge in HOLD",
        )
        _control(operator, key, session, "a1", "abort")
        assert proc.wait(timeout=120) == 0, proc.stderr.read()
    finally:
        operator.close()
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["status"] == "interrupted" and [r["after_step"] for r in manifest["resumes"]] == [
        killed_at
    ]
    assert [(e["kind"], e["action"], e["vehicle"]) for e in manifest["events"]] == [
        ("control", "hold", 1),
        ("control", "abort", None),
    ]

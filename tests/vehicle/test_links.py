"""The bridge over the other wires a boat has: a serial autopilot, a serial probe, a MAVLink router."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.vehicle import Probe, Stack

from guadal_cli.maps.format import haversine_m

RTL, HOLD = 11, 4  # Rover refuses to arm in RTL unless forced


def test_serial_autopilot_that_first_refuses_to_arm_then_drives_and_measures_with_a_serial_probe(
    broker, lake, tmp_path
):
    """A boat on its real wires: autopilot and probe on serial lines; arming refused, reported, retried."""
    master, slave = os.openpty()
    probe = Probe(master, [b"VALUE 12.5\n"])
    probe.start()
    s = Stack(
        broker,
        lake,
        tmp_path,
        home_node=lake[1].node_at(2, 1),
        serial=True,
        speedup=20.0,
        wait_armed=False,
        before_bridge=lambda emulator: emulator.set_mode(RTL),
        bridge_args=["--sensor", f"serial:{os.ttyname(slave)}", "--arm-retry-interval", "0.3"],
    )
    try:
        assert s.emulator.vehicle["serial"].startswith("/dev/")
        status = s.planner.wait_status(
            lambda st: st["arm_error"] and st["counters"]["arm_failed"] >= 2,
            10,
            "arming refusals not reported and retried",
        )
        assert "refused to arm: FAILED" in status["arm_error"] and "Mode not armable" in status["arm_error"]
        assert status["armed"] is False and status["counters"]["command_failed"] >= 2
        s.emulator.set_mode(HOLD)  # someone fixes the cause; the next attempt arms
        s.planner.wait_status(
            lambda st: st["armed"] and st["arm_error"] is None, 10, "not armed after the fix"
        )

        g, p = s.graph, s.planner
        target = g.node_at(4, 3)
        seq = p.goto(target, g)
        reached = p.wait_ack(seq, "reached", 20)
        assert haversine_m(reached["lat"], reached["lon"], g.lat[target], g.lon[target]) <= 2.0
        seq = p.send("measure", node=target)
        p.wait(lambda: p.decoded("measurement"), 5, "no measurement from the serial probe")
        sample = p.decoded("measurement")[-1]
        assert (sample["seq"], sample["node"], sample["value"]) == (seq, target, 12.5)
        assert probe.requests == [b"READ"]
    finally:
        s.close()
        os.close(master)
        os.close(slave)


def mavproxy_binary() -> str | None:
    found = Path(sys.executable).with_name("mavproxy.py")
    return str(found) if found.exists() else shutil.which("mavproxy.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.skipif(mavproxy_binary() is None, reason="MAVProxy is not installed (pip install mavproxy)")
def test_goto_through_mavproxy(broker, lake, tmp_path):
    def through_mavproxy(emulator, workdir):
        port = free_udp_port()
        router = subprocess.Popen(
            [
                sys.executable,
                mavproxy_binary(),
                "--master",
                emulator.tcp,
                "--out",
                f"udp:127.0.0.1:{port}",
                "--daemon",
                "--non-interactive",
            ],
            cwd=workdir,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        return f"udpin:127.0.0.1:{port}", router

    # and with the acknowledged kind of guided target, whose MISSION_ACK must find its way back
    s = Stack(
        broker,
        lake,
        tmp_path,
        home_node=lake[1].node_at(5, 5),
        speedup=20.0,
        route=through_mavproxy,
        bridge_args=["--waypoint-command", "mission_item"],
    )
    try:
        g, p = s.graph, s.planner
        target = g.node_at(1, 7)
        seq = p.goto(target, g)
        reached = p.wait_ack(seq, "reached", 20)
        assert haversine_m(reached["lat"], reached["lon"], g.lat[target], g.lon[target]) <= 2.0
        counters = p.status()["counters"]
        assert counters["mission_ack_error"] == 0
        # MAVProxy asks the autopilot things of its own; their answers pass by but are not ours to count
        assert counters["command_failed"] == 0
    finally:
        s.close()


def test_goto_through_the_embedded_broker(lake, tmp_path):
    """Where Mosquitto is not installed the stack runs guadal's embedded broker: the bridge works with it too."""
    from guadal_cli.channel.broker import start_broker

    broker = start_broker("embedded")
    try:
        s = Stack(broker, lake, tmp_path, home_node=lake[1].node_at(1, 1), speedup=20.0)
        try:
            g, p = s.graph, s.planner
            seq = p.goto(g.node_at(3, 3), g)
            p.wait_ack(seq, "reached", 20)
            seq = p.send("measure", node=g.node_at(3, 3))
            assert "no sensor" in p.wait_ack(seq, "failed", 5)["reason"]
        finally:
            s.close()
    finally:
        broker.stop()

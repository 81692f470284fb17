"""The bridge over the other wires a boat has: a serial autopilot, a serial probe, a MAVLink router."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from guadal_cli.maps.format import haversine_m
from vehicle_support import Probe, Stack


def test_serial_autopilot_and_serial_probe(broker, lake, tmp_path):
    master, slave = os.openpty()
    probe = Probe(master, [b"VALUE 12.5\n"])
    probe.start()
    s = Stack(broker, lake, tmp_path, home_node=lake[1].node_at(2, 1), serial=True, speedup=20.0,
              bridge_args=["--sensor", f"serial:{os.ttyname(slave)}"])
    try:
        assert s.emulator.vehicle["serial"].startswith("/dev/")
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
            [sys.executable, mavproxy_binary(), "--master", emulator.tcp, "--out", f"udp:127.0.0.1:{port}",
             "--daemon", "--non-interactive"],
            cwd=workdir, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        return f"udpin:127.0.0.1:{port}", router

    s = Stack(broker, lake, tmp_path, home_node=lake[1].node_at(5, 5), speedup=20.0, route=through_mavproxy)
    try:
        g, p = s.graph, s.planner
        target = g.node_at(1, 7)
        seq = p.goto(target, g)
        reached = p.wait_ack(seq, "reached", 20)
        assert haversine_m(reached["lat"], reached["lon"], g.lat[target], g.lon[target]) <= 2.0
    finally:
        s.close()

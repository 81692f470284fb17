"""A bridge whose autopilot link or broker dies mid-mission: warnings, HOLD attempts, no traceback.

Once, the failsafe's HOLD written to a dead MAVLink link raised (``BrokenPipeError``, then
``'NoneType' object has no attribute 'connect'`` while pymavlink reconnected) and the bridge
logged a traceback on every tick.
"""

import json
import os
import signal
from pathlib import Path

from fleet_support import Inbox, wait_for
from support import LAKE, run_cli

from guadal_cli.fleet import messages as msg
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import load_map


def test_a_bridge_outlives_its_autopilot_and_its_broker_without_a_traceback(tmp_path):
    state = tmp_path / "stack"
    up = run_cli(
        "stack",
        "up",
        "--map",
        LAKE,
        "--vehicles",
        "1",
        "--failsafe-timeout",
        "1",
        "--state-dir",
        state,
        "--json",
    )
    assert up.returncode == 0, up.stderr
    info = json.loads(up.stdout)
    broker, emulator, bridge = info["pids"]
    log = state / "logs" / "bridge-0.log"
    try:
        graph = NavGraph(load_map(LAKE))
        inbox = Inbox(info["broker"]["port"])
        node = 40
        inbox.client.publish(
            msg.topic("guadal", 0, "command"),
            msg.encode("goto", seq=1, node=node, lat=float(graph.lat[node]), lon=float(graph.lon[node])),
            qos=1,
        ).wait_for_publish(5)
        inbox.close()
        wait_for(lambda: "goto seq 1" in log.read_text(), 20, "the bridge never took the goto")
        os.kill(emulator, signal.SIGKILL)  # the autopilot vanishes mid-goto
        wait_for(lambda: "vehicle to HOLD" in log.read_text(), 30, "no failsafe HOLD")
        wait_for(
            lambda: "writes dropped until it is back" in log.read_text(), 30, "no warning for the dead link"
        )
        os.kill(broker, signal.SIGKILL)
        wait_for(lambda: "lost the broker" in log.read_text(), 30, "the bridge did not notice the broker")
        stat = Path(f"/proc/{bridge}/stat").read_text()  # still serving: alive, not a zombie
        assert stat.rsplit(")", 1)[1].split()[0] != "Z"
    finally:
        run_cli("stack", "down", "--state-dir", state)
    text = log.read_text()
    assert "Traceback" not in text and "internal error" not in text, text[-3000:]

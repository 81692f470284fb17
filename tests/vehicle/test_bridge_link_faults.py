"""A bridge whose autopilot link and broker die mid-goto: warnings, HOLD attempts, no traceback.

Once, the failsafe's HOLD written to a dead MAVLink link raised (``BrokenPipeError``, then
``'NoneType' object has no attribute 'connect'`` while pymavlink reconnected) and the bridge
logged a traceback on every tick.
"""

from support.fleet import wait_for
from support.vehicle import Stack

from guadal_cli.channel.broker import start_broker


def test_a_bridge_outlives_its_autopilot_and_its_broker_without_a_traceback(lake, tmp_path):
    broker = start_broker("auto")  # its own broker: this test kills it
    _, graph, _ = lake
    stack = Stack(
        broker, lake, tmp_path, home_node=graph.node_at(1, 1), bridge_args=["--failsafe-timeout", "1"]
    )
    try:
        seq = stack.planner.goto(graph.node_at(5, 7), graph)
        stack.planner.wait_ack(seq, "accepted", 15)
        stack.planner.stop_pinging()  # the planner goes silent: the failsafe will HOLD
        stack.emulator.proc.kill()  # ... a boat whose autopilot link just died mid-goto
        wait_for(lambda: "vehicle to HOLD" in stack.log(), 30, "no failsafe HOLD")
        wait_for(lambda: "writes dropped until it is back" in stack.log(), 30, "no warning for the dead link")
        broker.kill()
        wait_for(lambda: "lost the broker" in stack.log(), 30, "the bridge did not notice the broker")
        assert stack.bridge.poll() is None  # still serving
    finally:
        stack.close()
        broker.stop()
    log = stack.log_path.read_text()
    assert "Traceback" not in log and "internal error" not in log, log[-3000:]

"""The bridge end to end: planner client <-> Mosquitto <-> guadal bridge <-> MAVLink <-> guadal sitl.

One emulator and one bridge serve the protocol tests of this module (each test starts with a
fresh seq range and a known position); the failsafe tests get their own stack with a short
timeout, so a slow moment elsewhere cannot trip it.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from support.fleet import wait_for
from support.vehicle import Planner, Stack

from guadal_cli.channel import protocol as messages
from guadal_cli.channel.broker import start_broker
from guadal_cli.maps.format import haversine_m

MANUAL, HOLD, GUIDED = 0, 4, 15


@pytest.fixture(scope="module")
def own_broker():
    """This module's broker: one test restarts it."""
    holder = {"broker": start_broker("auto")}
    yield holder
    holder["broker"].stop()


@pytest.fixture(scope="module")
def shared(own_broker, lake, tmp_path_factory):
    broker = own_broker["broker"]
    m, g, _ = lake
    truth = tmp_path_factory.mktemp("truth") / "truth.csv"
    # a distinct value per cell: 10*row + col
    np.savetxt(truth, np.add.outer(10.0 * np.arange(m.shape[0]), np.arange(m.shape[1])), delimiter=",")
    s = Stack(
        broker,
        lake,
        tmp_path_factory.mktemp("bridge"),
        home_node=g.node_at(1, 1),
        speedup=20.0,
        telemetry_hz=20,
        bridge_args=["--sensor", f"synthetic:{truth}", "--failsafe-timeout", "120"],
    )
    yield s
    s.close()


@pytest.fixture
def planner(shared):
    """A fresh seq range for each test (seqs only grow, by less than the bridge's limit on
    jumps), with the message log cleared."""
    p = shared.planner
    p.seq = max(p.seq, shared_status(shared)["last_seq"]) + 50
    p.forget()
    return p


def shared_status(s) -> dict:
    return s.planner.wait_status(lambda st: True, 5, "no status")


def on_water(m, lat, lon) -> bool:
    cell = m.rowcol_of(lat, lon)
    return cell is not None and bool(m.mask[cell])


def test_goto_is_accepted_then_reached_at_the_target(shared, planner):
    g = shared.graph
    target = g.node_at(5, 3)
    seq = planner.goto(target, g)
    accepted = planner.wait_ack(seq, "accepted", 5)
    assert accepted["node"] == target
    reached = planner.wait_ack(seq, "reached", 20)
    assert haversine_m(reached["lat"], reached["lon"], g.lat[target], g.lon[target]) <= 2.0
    # the autopilot's own GPS, reported after the ack, says the boat is there
    seen = len(planner.decoded("telemetry"))
    planner.wait(lambda: len(planner.decoded("telemetry")) > seen + 2, 5, "no telemetry after arrival")
    for fix in planner.decoded("telemetry")[seen:]:
        assert haversine_m(fix["lat"], fix["lon"], g.lat[target], g.lon[target]) <= 2.5
        assert fix["mode"] == "GUIDED" and fix["armed"] is True and isinstance(fix["t"], float)


def test_path_around_the_land_tongue_never_crosses_land(shared, planner):
    m, g = shared.map, shared.graph
    start, target = g.node_at(1, 2), g.node_at(1, 6)  # the straight line crosses the tongue
    planner.wait_ack(planner.goto(start, g), "reached", 20)
    planner.forget()
    seq = planner.goto(target, g)
    planner.wait_ack(seq, "reached", 20)
    fixes = [(f["lat"], f["lon"]) for f in planner.decoded("telemetry")]
    assert len(fixes) >= 10, "too few GPS fixes to judge the route"
    for (a_lat, a_lon), (b_lat, b_lon) in zip(fixes, fixes[1:]):
        assert on_water(m, a_lat, a_lon), f"GPS fix {a_lat},{a_lon} is on land"
        # fixes a couple of metres apart: the chord between them is the track, and stays on water too
        if haversine_m(a_lat, a_lon, b_lat, b_lon) <= 3.0:
            assert on_water(m, (a_lat + b_lat) / 2, (a_lon + b_lon) / 2), (
                "the boat crossed land between two fixes"
            )
    # it went round the southern tip: the only water joining the basins is row 5
    assert max(m.rowcol_of(lat, lon)[0] for lat, lon in fixes) == 5


def test_targets_off_the_water_are_rejected_with_a_reason(shared, planner):
    m, g = shared.map, shared.graph
    node = g.node_at(2, 2)
    land = planner.send("goto", node=node, lat=float(m.lat[2, 4]), lon=float(m.lon[2, 4]))
    off_map = planner.send("goto", node=node, lat=float(m.lat[0, 0]) + 0.01, lon=float(m.lon[0, 0]))
    other = g.node_at(2, 6)
    mismatch = planner.send("goto", node=node, lat=float(g.lat[other]), lon=float(g.lon[other]))
    assert "on land" in planner.wait_ack(land, "rejected", 5)["reason"]
    assert "outside the map" in planner.wait_ack(off_map, "rejected", 5)["reason"]
    assert f"not the node {node}" in planner.wait_ack(mismatch, "rejected", 5)["reason"]
    # the same command again (a retransmission) gets the same answer
    planner.send("goto", seq=mismatch, node=node, lat=float(g.lat[other]), lon=float(g.lon[other]))
    planner.wait(
        lambda: len(planner.acks(mismatch, "rejected")) == 2, 5, "duplicate of a rejected goto not answered"
    )
    assert not planner.acks(status="accepted")


def test_duplicate_seq_repeats_the_answer_without_restarting(shared, planner):
    g = shared.graph
    target = g.node_at(3, 2)
    seq = planner.goto(target, g)
    planner.send("goto", seq=seq, node=target, lat=float(g.lat[target]), lon=float(g.lon[target]))
    planner.wait(
        lambda: len(planner.acks(seq, "accepted")) == 2, 5, "the duplicate was not answered 'accepted'"
    )
    first = planner.wait_ack(seq, "reached", 20)
    before = shared_status(shared)["counters"]["duplicate_seq"]
    planner.send("goto", seq=seq, node=target, lat=float(g.lat[target]), lon=float(g.lon[target]))
    planner.wait(
        lambda: len(planner.acks(seq, "reached")) == 2, 5, "the duplicate was not answered 'reached'"
    )
    again = planner.acks(seq, "reached")[-1]
    # the same arrival, reported again: nothing was re-planned or re-driven
    assert (again["lat"], again["lon"]) == (first["lat"], first["lon"])
    assert len(planner.acks(seq, "accepted")) == 2
    planner.wait_status(lambda st: st["counters"]["duplicate_seq"] == before + 1, 5, "duplicate not counted")


def test_older_seq_is_ignored_and_counted(shared, planner):
    g = shared.graph
    here = g.node_at(3, 2)
    newest = planner.goto(here, g)
    planner.wait_ack(newest, "reached", 20)
    before = shared_status(shared)["counters"]["stale_seq"]
    far = g.node_at(5, 7)
    planner.send("goto", seq=newest - 5, node=far, lat=float(g.lat[far]), lon=float(g.lon[far]))
    planner.wait_status(lambda st: st["counters"]["stale_seq"] == before + 1, 5, "stale seq not counted")
    assert not planner.acks(newest - 5)
    assert shared_status(shared)["goal"] == {"seq": newest, "node": here, "status": "reached"}


def test_a_ping_never_makes_an_outstanding_command_look_old(shared, planner):
    """The planner pings while it waits, then asks its last goto again to read the boat's clock."""
    g = shared.graph
    target = g.node_at(3, 2)
    seq = planner.goto(target, g)
    planner.wait_ack(seq, "reached", 20)
    before = shared_status(shared)["counters"]["stale_seq"]
    planner.send("ping", seq=seq)  # as the planner's keep-alive does
    planner.send("ping", seq=seq + 5)  # even a ping ahead of the last command moves nothing
    planner.send("goto", seq=seq, node=target, lat=float(g.lat[target]), lon=float(g.lon[target]))
    planner.wait(lambda: len(planner.acks(seq, "reached")) == 2, 5, "the repeated goto was not answered")
    status = shared_status(shared)
    assert status["last_seq"] == seq and status["counters"]["stale_seq"] == before


def test_other_sessions_and_far_ahead_seqs_are_refused_and_counted(shared, planner):
    g = shared.graph
    lure = g.node_at(5, 7)
    where = {"node": lure, "lat": float(g.lat[lure]), "lon": float(g.lon[lure])}
    before = shared_status(shared)["counters"]
    planner.send("goto", seq=planner.seq + 10**9, **where)  # once, a huge seq took the boat for good
    planner.send("goto", session="f" * 16, seq=planner.seq + 1, **where)  # another planner's
    planner.send("start", session="e" * 16)  # an unsigned new session while this one is active
    planner.wait_status(
        lambda st: (
            st["counters"]["seq_ahead"] == before["seq_ahead"] + 1
            and st["counters"]["foreign_session"] == before["foreign_session"] + 2
        ),
        5,
        "the refused commands were not counted",
    )
    assert not planner.acks(status="accepted")
    assert shared_status(shared)["session"] == planner.session
    home = g.node_at(3, 2)
    planner.wait_ack(planner.goto(home, g), "reached", 20)  # the planner is obeyed as before


def test_bad_payloads_are_counted_and_the_bridge_keeps_answering(shared, planner):
    before = shared_status(shared)["counters"]
    planner.raw(b"{not json")
    planner.raw(b'{"v":1,"type":"goto","seq":1,"node":0,"lat":37.4,"pad":"' + b"x" * 20_000 + b'"}')
    planner.raw(messages.encode("dance", seq=planner.seq + 1))
    planner.raw(json.dumps({"v": 2, "type": "ping", "seq": planner.seq + 1}).encode())
    planner.raw(messages.encode("ping", session=planner.session, seq=planner.seq, vehicle=7))
    planner.wait_status(
        lambda st: (
            st["counters"]["bad_payload"] == before["bad_payload"] + 4
            and st["counters"]["wrong_vehicle"] == before["wrong_vehicle"] + 1
        ),
        5,
        "bad payloads not counted",
    )
    log = shared.log()
    assert "exceeds the 16384-byte limit" in log and "unknown message type 'dance'" in log
    seq = planner.send("measure", node=0)
    planner.wait(lambda: planner.decoded("measurement"), 5, "no measurement after the bad payloads")
    assert planner.decoded("measurement")[-1]["seq"] == seq


def test_measure_reads_the_synthetic_truth_where_the_boat_is(shared, planner):
    m, g = shared.map, shared.graph
    target = g.node_at(2, 3)
    planner.wait_ack(planner.goto(target, g), "reached", 20)
    seq = planner.send("measure", node=target)
    planner.wait(lambda: planner.decoded("measurement"), 5, "no measurement")
    sample = planner.decoded("measurement")[-1]
    assert sample["seq"] == seq and sample["node"] == target
    assert sample["value"] == 23.0  # the truth grid holds 10*row + col
    assert m.rowcol_of(sample["lat"], sample["lon"]) == (2, 3)
    assert sample["t"] > 0


def test_status_is_retained_with_counters(shared, own_broker):
    from support.fleet import Inbox

    late = Inbox(own_broker["broker"].port)  # a planner that connects later still learns the vehicle's state
    try:
        late.subscribe(f"{shared.fleet}/vehicle/0/status")
        late.wait(lambda: late.messages, 5, "no retained status")
        status = json.loads(late.messages[0].payload)
        assert late.messages[0].retain and status["state"] == "online"
        assert set(status["counters"]) >= {
            "bad_payload",
            "stale_seq",
            "duplicate_seq",
            "command_failed",
            "failsafe",
        }
    finally:
        late.close()


def test_hold_stops_the_boat_and_the_next_goto_resumes(shared, planner):
    g = shared.graph
    far = g.node_at(5, 7)
    seq = planner.goto(far, g)
    planner.wait_ack(seq, "accepted", 5)
    hold = planner.send("hold")
    planner.wait_ack(hold, "accepted", 5)
    assert planner.wait_ack(seq, "failed", 5)["reason"] == "interrupted by a hold command; vehicle in HOLD."
    shared.emulator.heartbeat(lambda hb: hb.custom_mode == HOLD, 5, "no HOLD after the hold command")
    planner.wait_status(lambda st: st["state"] == "hold", 5, "status does not say hold")
    # a planner that ends cleanly (hold, then offline) is not a comms loss: no failsafe
    planner.publish_status("offline")
    wait_for(lambda: "vehicle already in HOLD" in shared.log(), 5, "planner offline not noticed")
    assert planner.status()["state"] == "hold"
    planner.publish_status("online")
    seq = planner.goto(g.node_at(3, 2), g)
    planner.wait_ack(seq, "reached", 20)
    assert planner.status()["state"] == "online"


def test_a_pilot_taking_over_ends_the_goto_and_is_not_overruled(shared, planner):
    g = shared.graph
    seq = planner.goto(g.node_at(5, 7), g)
    planner.wait_ack(seq, "accepted", 5)
    shared.emulator.heartbeat(lambda hb: hb.custom_mode == GUIDED, 5, "not driving in GUIDED")
    shared.emulator.set_mode(MANUAL)  # the RC switch
    assert "left GUIDED (now MANUAL)" in planner.wait_ack(seq, "failed", 5)["reason"]
    # the bridge leaves the pilot in control: the boat stays in MANUAL (ten heartbeats, half a second)
    planner.wait_status(lambda st: st["mode"] == "MANUAL", 5, "the bridge did not see MANUAL")
    for _ in range(10):
        assert shared.emulator.heartbeat(lambda hb: True, 5, "no heartbeat").custom_mode == MANUAL
    seq = planner.goto(g.node_at(3, 2), g)  # the planner's next goto takes it back
    planner.wait_ack(seq, "reached", 20)


def test_bridge_comes_back_after_a_broker_restart(shared, own_broker, planner):
    old = own_broker["broker"]
    old.kill()
    own_broker["broker"] = start_broker(old.kind, port=old.port)
    # a new broker knows nothing: the bridge must subscribe again and re-publish its retained status
    planner.close()
    shared.planner = fresh = Planner(own_broker["broker"], shared.fleet)
    fresh.wait_status(lambda st: st["state"] == "online", 15, "the bridge did not re-publish its status")
    fresh.session, fresh.seq = planner.session, fresh.status()["last_seq"]  # the same planner, reconnected
    g = shared.graph
    seq = fresh.goto(g.node_at(2, 2), g)
    fresh.wait_ack(seq, "reached", 20)


def test_sigterm_stops_cleanly_with_offline_status_and_hold(shared, planner):
    """Last test on the shared stack: it stops the bridge."""
    shared.bridge.send_signal(signal.SIGTERM)
    assert shared.bridge.wait(10) == 0
    status = planner.wait_status(lambda st: st["state"] == "offline", 5, "no offline status after SIGTERM")
    assert status["vehicle"] == 0
    shared.emulator.heartbeat(lambda hb: hb.custom_mode == HOLD, 5, "the boat was not put in HOLD on exit")
    log = shared.log()
    assert "Traceback" not in log and "bridge for vehicle 0 stopped" in log


def test_a_wp_radius_larger_than_the_arrival_radius_ends_every_hop(stack, lake):
    """ArduPilot stops within WP_RADIUS (3 m here) and says MISSION_ITEM_REACHED; the bridge
    (arrival radius 2 m) reads WP_RADIUS and accepts that arrival instead of re-sending forever."""
    g = lake[1]
    s = stack(g.node_at(1, 1), before_bridge=lambda emu: emu.set_param("WP_RADIUS", 3.0))
    p = s.planner
    for node in (g.node_at(1, 3), g.node_at(3, 3), g.node_at(3, 1)):  # 10 m hops, a corner between
        seq = p.goto(node, g)
        reached = p.wait_ack(seq, "reached", 20)
        gap = haversine_m(reached["lat"], reached["lon"], float(g.lat[node]), float(g.lon[node]))
        assert gap <= 3.0 + 0.2
    assert "WP_RADIUS is 3.0 m, larger than the bridge's arrival radius 2.0 m" in s.log()


# --- failsafe --------------------------------------------------------------------------------------
PLANNER_WITH_WILL = textwrap.dedent(
    """
    import sys, time
    import paho.mqtt.client as mqtt
    from guadal_cli.channel import protocol as messages
    port, fleet, session = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    topic = messages.topic(fleet, None, "status")
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    c.will_set(topic, messages.encode("status", state="offline", session=session), qos=1, retain=True)
    c.connect("127.0.0.1", port, keepalive=5)
    c.loop_start()
    status = messages.encode("status", state="online", session=session)
    c.publish(topic, status, qos=1, retain=True).wait_for_publish(5)
    print("up", flush=True)
    time.sleep(60)
    """
)


def test_failsafe_holds_on_silence_and_on_the_planners_last_will(broker, lake, tmp_path):
    # a slow boat (5 m/s of wall time), so it is still driving when the planner falls silent
    s = Stack(
        broker,
        lake,
        tmp_path,
        home_node=lake[1].node_at(5, 1),
        speedup=10.0,
        max_speed=0.5,
        bridge_args=["--failsafe-timeout", "2.5"],
    )
    try:
        g, p = s.graph, s.planner
        target = g.node_at(5, 7)  # 30 m away: 6 s
        seq = p.goto(target, g)
        p.wait_ack(seq, "accepted", 5)
        s.emulator.heartbeat(lambda hb: hb.custom_mode == GUIDED, 5, "the emulator never entered GUIDED")
        status = p.wait_status(lambda st: st["state"] == "failsafe", 8, "no failsafe after planner silence")
        assert "no planner message" in status["failsafe_reason"]
        s.emulator.heartbeat(
            lambda hb: hb.custom_mode == HOLD, 5, "the emulator is not in HOLD after the failsafe"
        )
        assert "interrupted by the failsafe (no planner message" in p.acks(seq, "failed")[-1]["reason"]

        # the next goto resumes: GUIDED again, and it gets there (the planner is alive again: it pings)
        target = g.node_at(5, 3)  # near where it stopped
        seq = p.goto(target, g)
        p.keep_alive(0.3)
        p.wait_ack(seq, "accepted", 5)
        p.wait_status(lambda st: st["state"] == "online", 5, "goto did not resume from failsafe")
        s.emulator.heartbeat(lambda hb: hb.custom_mode == GUIDED, 5, "no GUIDED after resuming")
        p.wait_ack(seq, "reached", 20)

        # a planner process that dies without a word: the broker publishes its last will
        dying = subprocess.Popen(
            [sys.executable, "-c", PLANNER_WITH_WILL, str(broker.port), s.fleet, p.session],
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert dying.stdout.readline().strip() == "up"
            dying.kill()
        finally:
            dying.wait(5)
        status = p.wait_status(
            lambda st: st["state"] == "failsafe", 12, "no failsafe after the planner's last will"
        )
        assert status["failsafe_reason"] == "the planner went offline"
        s.emulator.heartbeat(
            lambda hb: hb.custom_mode == HOLD, 5, "the emulator is not in HOLD after the last will"
        )
        assert status["counters"]["failsafe"] == 2
        assert "FAILSAFE" in s.log()
    finally:
        s.close()

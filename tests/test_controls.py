"""Operator controls as the runner applies them, fed by a plain in-memory inbox."""

from __future__ import annotations

import threading

import pytest

from guadal_cli.controls import ControlRequest, MissionAborted, OperatorControls


class ListInbox:
    """Requests handed over by a test; answers kept for inspection."""

    def __init__(self):
        self.pending: list[ControlRequest] = []
        self.answers: dict = {}
        self.lock = threading.Lock()

    def send(self, action, vehicle=None):
        with self.lock:
            self.pending.append(
                ControlRequest(len(self.answers) + len(self.pending), action, vehicle, "ana", "t")
            )

    def poll(self):
        with self.lock:
            out, self.pending = self.pending, []
        return out

    def answer(self, request, outcome):
        self.answers[request.id] = outcome


def _controls():
    inbox, events = ListInbox(), []
    controls = OperatorControls([inbox], lambda *event: events.append(event), n_vehicles=3)
    return inbox, events, controls


def test_hold_and_release_one_boat_are_recorded_with_who_and_when():
    inbox, events, controls = _controls()
    inbox.send("hold", 1)
    controls.check(12.5, active=[0, 1, 2])
    assert controls.held == {1} and not controls.paused
    inbox.send("release", 1)
    inbox.send("hold", 7)
    controls.check(13.0, active=[0, 1, 2])
    assert controls.held == set()
    assert [e[:4] for e in events] == [
        ("control", 1, 12.5, "hold vehicle 1 by ana"),
        ("control", 1, 13.0, "release vehicle 1 by ana"),
    ]
    assert events[0][4] == {"action": "hold", "who": "ana", "at": "t"}
    assert list(inbox.answers.values()) == ["applied", "applied", "refused: the mission has no vehicle 7"]


def test_a_paused_mission_waits_until_resumed():
    inbox, events, controls = _controls()
    inbox.send("pause")
    timer = threading.Timer(0.3, inbox.send, ("resume",))
    timer.start()
    controls.check(0.0, active=[0, 1, 2])  # returns only once the resume arrived
    timer.join()
    assert not controls.paused and [e[4]["action"] for e in events] == ["pause", "resume"]


def test_a_mission_whose_every_active_boat_is_held_waits_and_abort_ends_it():
    inbox, events, controls = _controls()
    inbox.send("hold", 0)
    controls.check(0.0, active=[0, 1])
    timer = threading.Timer(0.3, inbox.send, ("abort",))
    timer.start()
    inbox.send("hold", 1)
    with pytest.raises(MissionAborted, match="aborted by operator ana"):
        controls.check(1.0, active=[0, 1])
    timer.join()
    assert [e[4]["action"] for e in events] == ["hold", "hold", "abort"]
    assert set(inbox.answers.values()) == {"applied"}


def test_without_an_inbox_the_check_costs_nothing():
    controls = OperatorControls([], lambda *e: None, n_vehicles=2)
    controls.check(0.0, active=[0, 1])
    assert not controls.paused and controls.held == set()

"""An operator's say over a running mission: pause, resume, abort, hold or release one boat.

Requests arrive in inboxes (any object with ``poll()`` and ``answer()``): the mission database's,
filled by ``guadal serve --control``, and at remote levels the fleet's signed control topic
(``docs/protocol.md``). The runner calls :meth:`OperatorControls.check`
between hops, so a request takes effect at the next node: boats never stop between nodes, and
at sim level a paused mission simply waits. Every request that is applied is recorded as a fleet
event naming who asked and when.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

#: what an operator may ask of a running mission; hold and release name a vehicle
ACTIONS = ("pause", "resume", "abort", "hold", "release")
VEHICLE_ACTIONS = ("hold", "release")
#: how long a paused mission sleeps between looks at its inboxes
PAUSED_POLL_S = 0.1


class MissionAborted(Exception):
    """An operator ended the mission; the run ends ``interrupted`` with everything it recorded."""


@dataclass(frozen=True)
class ControlRequest:
    """One operator's request: ``action`` is pause, resume, abort, hold or release (these two name a
    ``vehicle``); ``requested_at`` is ISO 8601 UTC."""

    id: int | str
    action: str
    vehicle: int | None
    who: str
    requested_at: str


class Inbox(Protocol):
    """Where requests come from: new ones at each ``poll()``; ``answer()`` says what became of one."""

    def poll(self) -> list[ControlRequest]: ...

    def answer(self, request: ControlRequest, outcome: str) -> None: ...


class FleetInbox:
    """Controls signed by the ``operator`` broker user on the planner's control topic (remote levels)."""

    def __init__(self, fleet):
        self.fleet = fleet

    def poll(self) -> list[ControlRequest]:
        controls = self.fleet.pending_controls()
        now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds") if controls else ""
        return [
            ControlRequest(c["id"], c["action"], c.get("vehicle"), "operator (control topic)", now)
            for c in controls
        ]

    def answer(self, request: ControlRequest, outcome: str) -> None:
        """The topic has no reply; the fleet event is the record."""


class OperatorControls:
    """The state operators set: ``paused``, the ``held`` boats, and who aborted, if anyone."""

    def __init__(
        self,
        inboxes: list[Inbox],
        record_event: Callable[..., None],
        n_vehicles: int,
        hold: Callable[[list[int] | None], None] = lambda vehicles: None,
    ):
        self.inboxes = inboxes
        self.record_event = record_event
        self.n_vehicles = n_vehicles
        self.hold = hold  # stops boats where they are: the fleet's own HOLD at remote levels
        self.paused = False
        self.held: set[int] = set()

    def check(self, mission_time: float, active: list[int]) -> None:
        """Apply pending requests; wait while paused or while every active boat is held.

        Raises :class:`MissionAborted` when an operator aborts.
        """
        if not self.inboxes:
            return
        while True:
            for inbox in self.inboxes:
                for request in inbox.poll():
                    try:
                        outcome = self._apply(request, mission_time)
                    except MissionAborted:
                        inbox.answer(request, "applied")
                        raise
                    inbox.answer(request, outcome)
            stalled = bool(active) and all(v in self.held for v in active)
            if not (self.paused or stalled):
                return
            time.sleep(PAUSED_POLL_S)

    def _apply(self, request: ControlRequest, mission_time: float) -> str:
        action, vehicle, who = request.action, request.vehicle, request.who
        if action in VEHICLE_ACTIONS and not (isinstance(vehicle, int) and 0 <= vehicle < self.n_vehicles):
            return f"refused: the mission has no vehicle {vehicle!r}"
        target = f"vehicle {vehicle}" if action in VEHICLE_ACTIONS else "the mission"
        message = f"{action} {target} by {who}"
        self.record_event(
            "control",
            vehicle if action in VEHICLE_ACTIONS else None,
            mission_time,
            message,
            {"action": action, "who": who, "at": request.requested_at},
        )
        if action == "pause":
            self.paused = True
            self.hold(None)
        elif action == "resume":
            self.paused = False
        elif action == "hold":
            self.held.add(vehicle)
            self.hold([vehicle])
        elif action == "release":
            self.held.discard(vehicle)
        elif action == "abort":
            self.hold(None)
            raise MissionAborted(f"aborted by operator {who}")
        return "applied"

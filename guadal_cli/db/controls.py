"""Operator controls through the database: the console asks, the running mission answers.

The database is the one place both always reach, at every level and on either engine: the
console (``guadal serve --control``) inserts a request after checking its operator's login;
the mission polls its own run's pending requests a few times a second, applies them between
hops, and marks each one with what it did. Nothing else can write a request without write
access to the database itself.
"""

from __future__ import annotations

import datetime as _dt
import time

from sqlalchemy import select, update

from ..controls import ACTIONS, VEHICLE_ACTIONS, ControlRequest
from ..errors import GuadalError
from .models import Control, Run


class ControlRefused(GuadalError):
    """A well-formed request the run cannot take now (it is not running)."""


def _now() -> _dt.datetime:
    """UTC without a zone: how both engines store and compare the database's times."""
    return _dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None)


def check_request(body, vehicles: int) -> tuple[str, int | None]:
    """``(action, vehicle)`` from a request body, or one sentence on what is wrong."""
    if not isinstance(body, dict):
        raise GuadalError('a control request is a JSON object like {"action": "pause"}.')
    unknown = sorted(set(body) - {"action", "vehicle"})
    if unknown:
        raise GuadalError(
            f"a control request has only 'action' and 'vehicle'; '{unknown[0]}' is not allowed."
        )
    action = body.get("action")
    if action not in ACTIONS:
        raise GuadalError(f"control action {action!r} is not known; use one of {', '.join(ACTIONS)}.")
    vehicle = body.get("vehicle")
    if action in VEHICLE_ACTIONS:
        if isinstance(vehicle, bool) or not isinstance(vehicle, int) or not 0 <= vehicle < vehicles:
            raise GuadalError(
                f"'{action}' needs a vehicle number from 0 to {vehicles - 1} (got {vehicle!r})."
            )
    elif vehicle is not None:
        raise GuadalError(f"'{action}' applies to the whole mission; leave out 'vehicle'.")
    return action, vehicle


def request_control(engine, run_id: int, body, who: str, origin: str | None = None) -> dict:
    """Queue an operator's request for a running run; LookupError if there is no such run."""
    with engine.begin() as conn:
        run = conn.execute(select(Run.status, Run.vehicles).where(Run.id == run_id)).first()
        if run is None:
            raise LookupError(run_id)
        action, vehicle = check_request(body, int(run.vehicles or 0))
        if run.status != "running":
            raise ControlRefused(f"run {run_id} is {run.status}; only a running mission takes controls.")
        requested = _now()
        new_id = conn.execute(
            Control.__table__.insert().values(
                run_id=run_id, action=action, vehicle=vehicle, who=who, origin=origin, requested_at=requested
            )
        ).inserted_primary_key[0]
    return {
        "id": new_id,
        "action": action,
        "vehicle": vehicle,
        "who": who,
        "requested_at": requested.replace(tzinfo=_dt.timezone.utc).isoformat(),
    }


class ControlInbox:
    """The mission's side: its run's pending requests, looked up at most every ``every_s``."""

    def __init__(self, engine, run_uid: str, every_s: float = 0.2):
        self.engine = engine
        self.run_uid = run_uid
        self.every_s = every_s
        self._next_poll = 0.0
        self.failures_ = 0

    def poll(self) -> list[ControlRequest]:
        now = time.monotonic()
        if now < self._next_poll:
            return []
        self._next_poll = now + self.every_s
        stmt = (
            select(Control.id, Control.action, Control.vehicle, Control.who, Control.requested_at)
            .join(Run, Run.id == Control.run_id)
            .where(Run.uid == self.run_uid, Control.applied_at.is_(None))
            .order_by(Control.id)
        )
        try:
            with self.engine.connect() as conn:
                rows = conn.execute(stmt).all()
        except Exception:  # an unreachable database never stops the mission; it only delays controls
            self.failures_ += 1
            return []
        return [
            ControlRequest(r.id, r.action, r.vehicle, r.who, r.requested_at.isoformat() + "+00:00")
            for r in rows
        ]

    def answer(self, request: ControlRequest, outcome: str) -> None:
        """Mark a request applied (or refused), with what the mission did."""
        try:
            with self.engine.begin() as conn:
                conn.execute(
                    update(Control).where(Control.id == request.id).values(applied_at=_now(), outcome=outcome)
                )
        except Exception:
            self.failures_ += 1

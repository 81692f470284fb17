"""Sessions and sequence numbers: which command a bridge obeys. The rules live here only.

A planner run has a random session id. A bridge follows one session at a time: it takes a new
one only from a ``start`` command, and only when that start is signed with the fleet key or
when the bridge is idle (never had a session, or its failsafe or a hold left the boat in HOLD
with nothing to do). A session once left is never taken again, so replaying an old start does
nothing. Within a session, ``seq`` increases per vehicle: a repeated seq is answered again, an
older one is stale, and one more than :data:`MAX_SEQ_AHEAD` past the last is refused, so no
number can lock a boat out. A ``ping`` is contact only: it never moves the last seq, so it can
never make an outstanding command look old. Nothing here ever prefers a larger number.
"""

from __future__ import annotations

import secrets
from collections import deque
from dataclasses import dataclass, field

MAX_SEQ_AHEAD = 100
#: sessions a bridge remembers having left (replayed starts of these are refused)
REMEMBERED_SESSIONS = 64


def new_session_id() -> str:
    return secrets.token_hex(8)


@dataclass
class Follower:
    """A bridge's side: the session it follows and the last seq it took."""

    session: str | None = None
    last_seq: int = -1
    left: deque = field(default_factory=lambda: deque(maxlen=REMEMBERED_SESSIONS))

    def judge(self, data: dict, *, signed: bool, idle: bool) -> tuple[str, str]:
        """``(verdict, why)`` for a decoded command. Verdicts: ``adopt`` (a start to take),
        ``new`` (a command to carry out), ``duplicate`` (answer it again), ``contact`` (a ping),
        ``stale``, ``ahead`` and ``foreign`` (refused, count them)."""
        kind, session, seq = data["type"], data["session"], data["seq"]
        if kind == "start":
            if session == self.session:
                if seq == self.last_seq:
                    return "duplicate", ""
                if seq < self.last_seq:
                    return "stale", f"start seq {seq} is older than the last command (seq {self.last_seq})"
                return "adopt", "the planner re-synchronises its session"
            if session in self.left:
                return "foreign", f"session {session} has ended here; its start is not taken again"
            if signed or idle or self.session is None:
                return "adopt", f"new planner session {session}"
            return "foreign", (
                f"a start for session {session} while following {self.session}; without a fleet key a "
                "new session is taken only when the boat is idle"
            )
        if session != self.session:
            following = f"session {self.session}" if self.session else "no session yet"
            return "foreign", f"{kind} seq {seq} belongs to session {session}, not to {following}"
        if seq > self.last_seq + MAX_SEQ_AHEAD:
            return (
                "ahead",
                f"{kind} seq {seq} is more than {MAX_SEQ_AHEAD} past the last command ({self.last_seq})",
            )
        if kind == "ping":
            return "contact", ""
        if seq < self.last_seq:
            return "stale", f"{kind} seq {seq} is older than the last command (seq {self.last_seq})"
        if seq == self.last_seq:
            return "duplicate", ""
        return "new", ""

    def take(self, data: dict) -> None:
        """Record an adopted start or a new command."""
        if data["session"] != self.session:
            if self.session is not None:
                self.left.append(self.session)
            self.session = data["session"]
        self.last_seq = data["seq"]

"""Which vehicle states go to the run directory (``vehicles.csv``) and the database, and when.

Operators watch each boat's mode, arming, battery, link age and last fault; a row per boat per
hop would swamp a long mission, so a boat gets a row at most once a second of *mission* time
(the same clock at every level, so ``sim`` rows stay byte-identical between runs), and at once
when its mode, arming or fault changes. The fleet says what its vehicles report
(:meth:`~guadal_cli.fleet.base.Fleet.vehicle_status`); the runner samples it after every hop.
"""

from __future__ import annotations

import math

#: at most one row per vehicle per this many seconds of mission time, changes aside
STATUS_EVERY_S = 1.0


class StatusSampler:
    """Turns the fleet's vehicle states into ``VEHICLE_COLUMNS`` rows, when each is due."""

    def __init__(self, every_s: float = STATUS_EVERY_S):
        self.every_s = every_s
        self._last: dict[int, tuple[float, tuple]] = {}  # vehicle -> (time_s, (mode, armed, fault))

    def rows(self, step: int, fleet) -> list[list]:
        now = float(fleet.mission_time)
        remaining = fleet.remaining()
        out = []
        for v, s in sorted(fleet.vehicle_status().items()):
            key = (s.get("mode"), s.get("armed"), s.get("fault") or "")
            last = self._last.get(v)
            if last is not None and last[1] == key and now - last[0] < self.every_s - 1e-9:
                continue
            self._last[v] = (now, key)
            out.append(
                [
                    step,
                    v,
                    now,
                    max(0.0, float(remaining[v])),
                    s.get("mode") or "",
                    s.get("armed"),
                    _number(s.get("battery")),
                    _number(s.get("link_age_s")),
                    s.get("fault") or "",
                ]
            )
        return out


def _number(value) -> float | None:
    """A reported number, or None (an empty cell) for one that is missing or not finite."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)

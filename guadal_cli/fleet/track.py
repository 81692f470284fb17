"""GPS tracks at a fixed rate in the vehicle's own clock, whatever the emulator's speed-up.

A bridge sees fixes as fast as its autopilot sends them; a run directory keeps one fix per
``1 / rate`` seconds of the *vehicle's* clock (simulated time at ``sitl``, the boat's time at
``real``). The same sampler decides what a bridge publishes and what the planner records, so
the track in ``trajectory.csv`` has the rate the manifest states.
"""

from __future__ import annotations

import math

#: fixes per second of the vehicle's clock, unless the mission says otherwise
DEFAULT_TRACK_RATE_HZ = 1.0


class TrackSampler:
    """Keeps the first fix at or after each multiple of ``1 / rate`` seconds of vehicle time."""

    def __init__(self, rate_hz: float = DEFAULT_TRACK_RATE_HZ):
        if not rate_hz > 0:
            raise ValueError(f"track rate must be positive (got {rate_hz})")
        self.rate_hz = rate_hz
        self.next_t_: float | None = None

    def take(self, t: float) -> bool:
        """Should the fix stamped ``t`` (vehicle seconds) be kept?"""
        if self.next_t_ is not None and t < self.next_t_:
            return False
        # the next slot is the first multiple of the period after t: a late fix does not shift the grid
        self.next_t_ = (math.floor(t * self.rate_hz + 1e-9) + 1) / self.rate_hz
        return True

    def reset(self) -> None:
        self.next_t_ = None

"""A small boat on flat water: position, heading and speed under speed, turn-rate and
acceleration limits, pushed by a water current.

The autopilot (``vehicle.py``) decides *what* the boat wants (a speed and a heading); this module
decides what the hull can actually do in a time step.  Positions are metres east/north of the
vehicle's home, converted to lat/lon with ArduPilot's flat-earth scaling so distances agree with
what a real autopilot reports over the few hundred metres of a lake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: metres per 1e-7 degree of latitude, as ArduPilot's ``LOCATION_SCALING_FACTOR``
_METRES_PER_E7 = 0.011131884502145034
METRES_PER_DEGREE = _METRES_PER_E7 * 1e7

#: the largest simulated time step the integrator takes (s): small enough that a boat at full
#: speed moves a fraction of the 2 m arrival radius and turns a few degrees per step
MAX_SUBSTEP_S = 0.2


def wrap_pi(angle: float) -> float:
    """An angle in radians folded into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class HullLimits:
    """What the hull can do; defaults describe the paper's small ASV (0.5 m/s top speed)."""

    max_speed: float = 0.5  # m/s through the water
    max_turn_rate: float = math.radians(30.0)  # rad/s
    max_accel: float = 0.25  # m/s^2 when speeding up
    max_decel: float = 0.5  # m/s^2 when slowing down (drag helps)


class GeoFrame:
    """Flat-earth conversion between lat/lon and metres east/north of an origin."""

    def __init__(self, lat: float, lon: float):
        self.lat0 = lat
        self.lon0 = lon
        self._lon_scale = max(math.cos(math.radians(lat)), 0.01)

    def to_local(self, lat: float, lon: float) -> tuple[float, float]:
        east = (lon - self.lon0) * METRES_PER_DEGREE * self._lon_scale
        north = (lat - self.lat0) * METRES_PER_DEGREE
        return east, north

    def to_global(self, east: float, north: float) -> tuple[float, float]:
        lat = self.lat0 + north / METRES_PER_DEGREE
        lon = self.lon0 + east / (METRES_PER_DEGREE * self._lon_scale)
        return lat, lon


class Hull:
    """The boat's true state; ``step`` integrates it towards a commanded speed and heading."""

    def __init__(self, limits: HullLimits, current_en: tuple[float, float] = (0.0, 0.0)):
        self.limits = limits
        self.current_e, self.current_n = current_en
        self.east = 0.0
        self.north = 0.0
        self.heading = 0.0  # rad, clockwise from north
        self.speed = 0.0  # m/s through the water, forward
        self.yaw_rate = 0.0  # rad/s of the last step
        self.odometer = 0.0  # metres travelled over ground

    @property
    def at_rest(self) -> bool:
        return self.speed == 0.0 and self.current_e == 0.0 and self.current_n == 0.0

    def ground_velocity(self) -> tuple[float, float]:
        """(east, north) m/s over ground: own speed plus the water current."""
        return (
            self.speed * math.sin(self.heading) + self.current_e,
            self.speed * math.cos(self.heading) + self.current_n,
        )

    def step(self, dt: float, want_speed: float, want_heading: float | None) -> None:
        """Advance ``dt`` seconds, turning towards ``want_heading`` (None: keep course) and
        accelerating towards ``want_speed`` within the hull limits."""
        lim = self.limits
        if want_heading is not None:
            error = wrap_pi(want_heading - self.heading)
            turn = max(-lim.max_turn_rate * dt, min(lim.max_turn_rate * dt, error))
            self.heading = wrap_pi(self.heading + turn)
            self.yaw_rate = turn / dt if dt > 0 else 0.0
            # a boat pointing the wrong way slows to turn rather than driving off sideways
            want_speed *= max(0.2, math.cos(min(abs(error), math.pi / 2)))
        else:
            self.yaw_rate = 0.0
        target = max(0.0, min(want_speed, lim.max_speed))
        if target > self.speed:
            self.speed = min(target, self.speed + lim.max_accel * dt)
        else:
            self.speed = max(target, self.speed - lim.max_decel * dt)
        ve, vn = self.ground_velocity()
        self.east += ve * dt
        self.north += vn * dt
        self.odometer += math.hypot(ve, vn) * dt

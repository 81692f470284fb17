"""The hull model on its own: the limits a boat cannot break, whatever the autopilot asks."""

from __future__ import annotations

import math

import pytest

from guadal_cli.sitl.physics import GeoFrame, Hull, HullLimits


def _run(hull: Hull, seconds: float, speed: float, heading: float | None, dt: float = 0.2):
    trace = []
    for _ in range(round(seconds / dt)):
        hull.step(dt, speed, heading)
        trace.append((hull.speed, hull.heading))
    return trace


def test_speed_ramps_at_the_acceleration_limit_and_stops_at_max_speed():
    hull = Hull(HullLimits(max_speed=0.5, max_accel=0.25))
    trace = _run(hull, 1.0, speed=5.0, heading=0.0)
    assert trace[-1][0] == pytest.approx(0.25)  # 1 s at 0.25 m/s²
    trace = _run(hull, 10.0, speed=5.0, heading=0.0)
    assert max(s for s, _ in trace) == pytest.approx(0.5)
    # 0.125 m in the first second, 0.375 m speeding up to 0.5 m/s, then 9 s at 0.5 m/s
    assert hull.north == pytest.approx(5.0, abs=0.05)


def test_a_u_turn_takes_at_least_the_turn_rate_limit():
    hull = Hull(HullLimits(max_turn_rate=math.radians(30)))
    trace = _run(hull, 10.0, speed=0.5, heading=math.pi)
    turned_at = next(i for i, (_, h) in enumerate(trace) if abs(abs(h) - math.pi) < 1e-9)
    assert (turned_at + 1) * 0.2 == pytest.approx(6.0)  # 180° at 30°/s
    # while pointing the wrong way it crawls instead of driving off sideways
    assert trace[0][0] <= 0.2 * 0.5 + 1e-9


def test_water_current_drifts_a_boat_with_no_thrust():
    hull = Hull(HullLimits(), current_en=(0.1, -0.05))
    _run(hull, 20.0, speed=0.0, heading=None)
    assert (hull.east, hull.north) == pytest.approx((2.0, -1.0))
    assert hull.speed == 0.0 and hull.odometer == pytest.approx(math.hypot(2.0, 1.0))


def test_geo_frame_round_trip_and_scale():
    frame = GeoFrame(37.41795, -5.98345)
    lat, lon = frame.to_global(30.0, -40.0)
    assert frame.to_local(lat, lon) == pytest.approx((30.0, -40.0))
    assert (lat - 37.41795) * 111319.49 == pytest.approx(-40.0, rel=1e-4)

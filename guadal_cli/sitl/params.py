"""The few autopilot parameters the emulator honours, with ArduPilot's names and types."""

from __future__ import annotations

from dataclasses import dataclass

REAL32 = 9  # MAV_PARAM_TYPE_REAL32
INT8 = 2  # MAV_PARAM_TYPE_INT8


@dataclass
class Param:
    name: str
    value: float
    kind: int

    def coerce(self, value: float) -> float:
        """Integer parameters keep whole values, as the autopilot stores them."""
        if self.kind == INT8:
            return float(max(-128, min(127, round(value))))
        return float(value)


def default_params(max_speed: float) -> dict[str, Param]:
    """Parameters in the order PARAM_REQUEST_LIST reports them (that order is the index).

    WP_SPEED and CRUISE_SPEED default to the hull's top speed rather than ArduPilot's 2 m/s: a
    boat that cannot exceed ``max_speed`` would otherwise report a speed it never reaches.
    """
    table = [
        Param("CRUISE_SPEED", max_speed, REAL32),
        Param("CRUISE_THROTTLE", 50.0, INT8),
        Param("FRAME_CLASS", 2.0, INT8),  # 1 rover, 2 boat
        Param("LOIT_RADIUS", 2.0, REAL32),
        Param("RTL_SPEED", 0.0, REAL32),  # 0: use WP_SPEED
        Param("WP_RADIUS", 2.0, REAL32),
        Param("WP_SPEED", max_speed, REAL32),
    ]
    return {p.name: p for p in table}

"""The few autopilot parameters the emulator honours, with ArduPilot's names and types."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError

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


#: SITL models ``--model`` accepts, and the frame class each one implies
MODELS = {"motorboat": 2, "boat": 2, "sailboat": 2, "rover": 1}


def read_param_files(paths: list[str]) -> dict[str, float]:
    """``--defaults`` files as ArduPilot reads them: ``NAME VALUE`` (or ``NAME,VALUE``) per line,
    ``#`` comments; later files override earlier ones. Parameters the emulator does not model are
    kept too (and ignored), as ArduPilot's own files set hundreds."""
    values: dict[str, float] = {}
    for path in paths:
        try:
            lines = Path(path).read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise GuadalError(f"--defaults: cannot read parameter file '{path}' ({exc}).") from None
        for number, line in enumerate(lines, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            parts = text.replace(",", " ").split()
            try:
                name, value = parts[0], float(parts[1])
            except (IndexError, ValueError):
                raise GuadalError(
                    f"--defaults: '{path}' line {number} must be NAME VALUE, e.g. 'WP_RADIUS 1' (got '{text[:40]}')."
                ) from None
            if len(parts) > 2 or not math.isfinite(value):
                raise GuadalError(
                    f"--defaults: '{path}' line {number} must be NAME VALUE with a finite number (got '{text[:40]}')."
                )
            values[name.upper()] = value
    return values


def apply_defaults(params: dict[str, Param], values: dict[str, float]) -> None:
    """Set the parameters the emulator models; the others are ArduPilot's business."""
    for name, value in values.items():
        if name in params:
            params[name].value = params[name].coerce(value)

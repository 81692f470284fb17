"""Which pixels of an image are water: a reference colour, a channel threshold, or the default.

Channels are read on a 0-255 scale (16-bit images are scaled down):

- ``red``, ``green``, ``blue``;
- ``gray``: luminance, ``0.299 R + 0.587 G + 0.114 B``;
- ``index``: the water index ``(B - R) / (B + R)`` in [-1, 1] (0 where B + R = 0). Clear and
  dark water reflects more blue than red; vegetation, soil, roads and roofs reflect as much red
  as blue or more, so they score near zero or below.

The default rule needs no option: a grey image (a mask) is water where it is white
(``gray >= 128``); a colour image (a satellite photo) is water where ``index > 0.1``.
Transparent pixels are never water.
"""

from __future__ import annotations

import operator
import re
from dataclasses import dataclass

import numpy as np

from ..errors import GuadalError

CHANNELS = ("red", "green", "blue", "gray", "index")
_ALIASES = {
    "r": "red",
    "g": "green",
    "b": "blue",
    "grey": "gray",
    "luminance": "gray",
    "water_index": "index",
}
_OPS = {"<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge}
_THRESHOLD = re.compile(r"^\s*([a-zA-Z_]+)\s*(<=|>=|<|>)\s*([-+]?(?:\d+\.?\d*|\.\d+))\s*$")

DEFAULT_GREY = "gray>=128"
DEFAULT_COLOUR = "index>0.1"


def channel(rgb: np.ndarray, name: str) -> np.ndarray:
    """One named channel of an (H, W, 3) float array on the 0-255 scale."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    if name == "red":
        return r
    if name == "green":
        return g
    if name == "blue":
        return b
    if name == "gray":
        return 0.299 * r + 0.587 * g + 0.114 * b
    total = b + r
    return np.divide(b - r, total, out=np.zeros_like(total), where=total > 0)


@dataclass(frozen=True)
class Threshold:
    channel: str
    op: str
    value: float

    def __str__(self) -> str:
        return f"{self.channel}{self.op}{self.value:g}"


def parse_threshold(text: str) -> Threshold:
    """``"blue>120"``, ``"gray <= 40"``, ``"index>0.2"`` -> :class:`Threshold`."""
    match = _THRESHOLD.match(text or "")
    if not match:
        raise GuadalError(
            f"'{text}' is not a rule: write CHANNEL OP VALUE, e.g. 'blue>120' or 'index>0.1' "
            f"(channels: {', '.join(CHANNELS)}; operators: <, <=, >, >=).",
            field="threshold",
        )
    name = _ALIASES.get(match.group(1).lower(), match.group(1).lower())
    if name not in CHANNELS:
        raise GuadalError(
            f"names an unknown channel '{match.group(1)}' (allowed: {', '.join(CHANNELS)}).",
            field="threshold",
        )
    return Threshold(name, match.group(2), float(match.group(3)))


def parse_colour(text: str) -> tuple[float, float, float]:
    """``"40,90,110"`` or ``"#285a6e"`` -> (R, G, B) on 0-255."""
    text = (text or "").strip()
    if re.fullmatch(r"#?[0-9a-fA-F]{6}", text):
        h = text.lstrip("#")
        return tuple(float(int(h[i : i + 2], 16)) for i in (0, 2, 4))  # type: ignore[return-value]
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(0 <= v <= 255 for v in values):
        raise GuadalError(
            f"'{text}' must be R,G,B with each value in 0-255 (e.g. 40,90,110) or #RRGGBB.",
            field="water_color",
        )
    return values  # type: ignore[return-value]


@dataclass(frozen=True)
class WaterRule:
    """How to tell water from land in an image: a colour (with a tolerance) or a threshold rule."""

    colour: tuple[float, float, float] | None = None
    tolerance: float = 40.0
    threshold: Threshold | None = None
    invert: bool = False

    @classmethod
    def from_options(
        cls, water_color: str | None, tolerance: float, threshold: str | None, invert: bool
    ) -> WaterRule:
        if water_color and threshold:
            raise GuadalError(
                "cannot be combined with a water colour; give one rule or the other.", field="threshold"
            )
        if not tolerance >= 0:
            raise GuadalError(f"must be zero or more (got {tolerance:g}).", field="tolerance")
        return cls(
            colour=parse_colour(water_color) if water_color else None,
            tolerance=float(tolerance),
            threshold=parse_threshold(threshold) if threshold else None,
            invert=invert,
        )

    def resolve(self, is_grey: bool) -> WaterRule:
        """The rule actually applied: the default depends on whether the image is grey."""
        if self.colour is not None or self.threshold is not None:
            return self
        default = parse_threshold(DEFAULT_GREY if is_grey else DEFAULT_COLOUR)
        return WaterRule(threshold=default, tolerance=self.tolerance, invert=self.invert)

    def describe(self) -> str:
        if self.colour is not None:
            r, g, b = (int(round(v)) for v in self.colour)
            text = f"colour within {self.tolerance:g} of ({r},{g},{b})"
        elif self.threshold is not None:
            text = str(self.threshold)
        else:
            text = "default"
        return f"not ({text})" if self.invert else text

    def apply(self, rgb: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
        """Boolean water mask of an (H, W, 3) float image; call on a resolved rule."""
        if self.colour is not None:
            distance = np.sqrt(((rgb - np.asarray(self.colour)) ** 2).sum(axis=-1))
            water = distance <= self.tolerance
        elif self.threshold is not None:
            t = self.threshold
            water = _OPS[t.op](channel(rgb, t.channel), t.value)
        else:  # pragma: no cover - callers resolve first
            raise ValueError("resolve() the rule before applying it")
        if self.invert:
            water = ~water
        if alpha is not None:
            water &= alpha > 0
        return water

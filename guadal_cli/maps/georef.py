"""Where a north-up image lies on Earth: corner bounds or a world file beside it.

Both give the outer edges of the image (not pixel centres) in degrees. World files are the
six-line text files (``.pgw``, ``.jgw``, ``.tfw``, ``.wld``) that many GIS exports write: pixel
width, two rotation terms, pixel height (negative for north-up), then the lon/lat of the centre
of the top-left pixel. guadal reads them in lon/lat degrees only, without rotation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError
from .format import EARTH_RADIUS_M

WORLD_FILE_SUFFIXES = {
    ".png": (".pgw", ".pngw"),
    ".jpg": (".jgw", ".jpgw"),
    ".jpeg": (".jgw", ".jpegw"),
    ".tif": (".tfw", ".tifw"),
    ".tiff": (".tfw", ".tiffw"),
}


@dataclass(frozen=True)
class Bounds:
    """Outer edges of a north-up area in degrees."""

    north: float
    south: float
    east: float
    west: float

    def __post_init__(self) -> None:
        for name in ("north", "south"):
            value = getattr(self, name)
            if not (math.isfinite(value) and -90 <= value <= 90):
                raise GuadalError(f"bounds: {name} must be a latitude in [-90, 90] (got {value:g}).")
        for name in ("east", "west"):
            value = getattr(self, name)
            if not (math.isfinite(value) and -180 <= value <= 180):
                raise GuadalError(f"bounds: {name} must be a longitude in [-180, 180] (got {value:g}).")
        if not self.north > self.south:
            raise GuadalError(
                f"bounds contradict each other: north ({self.north:g}) must be greater than south ({self.south:g})."
            )
        if not self.east > self.west:
            raise GuadalError(
                f"bounds contradict each other: east ({self.east:g}) must be greater than west ({self.west:g}); "
                "areas across the 180th meridian are not supported."
            )

    @classmethod
    def parse(cls, text: str) -> Bounds:
        """``"north,south,east,west"`` in decimal degrees."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) != 4:
            raise GuadalError(
                f"'{text}' must be four numbers north,south,east,west in decimal degrees "
                "(e.g. 37.4200,37.4164,-5.9780,-5.9830).",
                field="bounds",
            )
        return cls(*values)

    @property
    def centre(self) -> tuple[float, float]:
        return (self.north + self.south) / 2, (self.east + self.west) / 2

    def metres_per_degree(self) -> tuple[float, float]:
        """(east-west, north-south) metres per degree at the centre latitude."""
        ns = math.radians(1) * EARTH_RADIUS_M
        return ns * math.cos(math.radians(self.centre[0])), ns

    def largest_gap_m(self, other: Bounds) -> tuple[float, str]:
        """The edge on which two bounds differ most, and by how many metres."""
        ew, ns = self.metres_per_degree()
        gaps = {
            "north": abs(self.north - other.north) * ns,
            "south": abs(self.south - other.south) * ns,
            "east": abs(self.east - other.east) * ew,
            "west": abs(self.west - other.west) * ew,
        }
        edge = max(gaps, key=gaps.get)
        return gaps[edge], edge

    def text(self) -> str:
        return f"{self.north:.6f},{self.south:.6f},{self.east:.6f},{self.west:.6f}"


def find_world_file(image: Path) -> Path | None:
    """The world file beside ``image`` (same name, world-file suffix), if there is one."""
    for suffix in (*WORLD_FILE_SUFFIXES.get(image.suffix.lower(), ()), ".wld"):
        for candidate in (image.with_suffix(suffix), image.with_suffix(suffix.upper())):
            if candidate.is_file():
                return candidate
    return None


def read_world_file(path: Path, width: int, height: int) -> Bounds:
    """Bounds of a ``width`` x ``height`` image from its world file."""
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        a, d, b, e, c, f = (float(v) for v in lines)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise GuadalError(
            f"world file '{path.name}' is not readable: it must hold six numbers, one per line "
            "(pixel width, rotation, rotation, pixel height, lon and lat of the top-left pixel centre)."
        ) from exc
    if d != 0 or b != 0:
        raise GuadalError(
            f"world file '{path.name}' rotates the image; guadal reads north-up images only (rotation terms must be 0)."
        )
    if not (a > 0 and e < 0):
        raise GuadalError(
            f"world file '{path.name}' must give a positive pixel width and a negative pixel height "
            f"(north-up); it gives {a:g} and {e:g}."
        )
    if not (-180 <= c <= 180 and -90 <= f <= 90):
        raise GuadalError(
            f"world file '{path.name}' places the image at ({c:g}, {f:g}), which is not lon/lat in degrees; "
            "guadal reads world files in lon/lat degrees only."
        )
    west, north = c - a / 2, f - e / 2
    return Bounds(north=north, south=north + e * height, east=west + a * width, west=west)


def image_bounds(image: Path, width: int, height: int, bounds: Bounds | None) -> tuple[Bounds, str]:
    """The image's bounds from ``--bounds`` and/or its world file, checked against each other."""
    world = find_world_file(image)
    from_world = read_world_file(world, width, height) if world else None
    if from_world is None and bounds is None:
        raise GuadalError(
            f"'{image.name}' has no georeference: give its corners with --bounds north,south,east,west "
            f"or put a world file beside it ({' or '.join(WORLD_FILE_SUFFIXES.get(image.suffix.lower(), ('.wld',)))})."
        )
    if from_world is None:
        return bounds, "--bounds"  # type: ignore[return-value]
    if bounds is None:
        return from_world, f"world file {world.name}"
    ew, ns = from_world.metres_per_degree()
    pixel_m = max(
        (from_world.east - from_world.west) / width * ew, (from_world.north - from_world.south) / height * ns
    )
    gap, edge = from_world.largest_gap_m(bounds)
    if gap > pixel_m:
        raise GuadalError(
            f"the world file '{world.name}' and --bounds disagree: their {edge} edges are {gap:.1f} m apart "
            f"(world file: {from_world.text()}; --bounds: {bounds.text()}); give one, or make them agree."
        )
    return bounds, f"--bounds (agrees with {world.name})"

"""The guadal map: a boolean water mask plus a georeference, in one JSON file.

Format (version 1), documented for users in ``docs/map-format.md``::

    {
      "format": "guadal-map", "version": 1,
      "name": "...", "description": "...",
      "cell_size_m": 5.0,
      "reference": {"row": 15, "col": 24, "lat": 37.4176, "lon": -5.9812},
      "mask": ["0011100", "0111110", ...],      # one string per row, north first; 1 = water
      "latlon": {"lat": [[...]], "lon": [[...]]} # optional: cell-centre coordinates per cell
    }

Rows run north to south and columns west to east. Without ``latlon`` the grid is north-up with
square cells of ``cell_size_m`` and the reference cell's centre at the given lat/lon. With
``latlon`` every cell centre is given (cells need not be square); ``cell_size_m`` is then the
nominal size, and metric positions come from projecting the coordinates.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import GuadalError

EARTH_RADIUS_M = 6_371_008.8
FORMAT_NAME = "guadal-map"
FORMAT_VERSION = 1
#: cell sizes guadal maps are made of: a sampling grid on a pond to one on a large lake
MIN_CELL_SIZE_M, MAX_CELL_SIZE_M = 0.1, 1000.0
#: cells in one grid (2000 x 2000): the mask, coordinates and metric grids stay in memory
MAX_GRID_CELLS = 4_000_000
#: bytes of a map file (a 2000 x 2000 grid with its coordinates fits)
MAX_MAP_BYTES = 256 * 1024 * 1024
#: water nodes a mission's graph may have by default; the environment variable raises it
DEFAULT_MAX_NODES = 50_000
MAX_NODES_ENV = "GUADAL_MAX_NODES"


def checked_path(path, what: str) -> str:
    """``path`` as messages show it, after refusing names no filesystem takes."""
    text = str(path)
    shown = text if len(text) <= 120 else f"{text[:60]}...{text[-40:]}"
    if "\x00" in text:
        shown = shown.replace("\x00", "\\0")
        raise GuadalError(f"{what} '{shown}' holds a NUL character, which no file name may.")
    if len(text.encode()) > 4096 or any(len(part.encode()) > 255 for part in Path(text).parts):
        raise GuadalError(
            f"{what} '{shown}' is too long for a file name (at most 255 bytes per name, 4096 in all)."
        )
    return shown


def max_nodes() -> int:
    """The node-count limit: :data:`DEFAULT_MAX_NODES`, or ``GUADAL_MAX_NODES`` where set."""
    raw = os.environ.get(MAX_NODES_ENV, "").strip()
    if not raw:
        return DEFAULT_MAX_NODES
    try:
        value = int(raw)
    except ValueError:
        value = 0
    if value < 1:
        raise GuadalError(f"{MAX_NODES_ENV} must be a whole number of nodes above 0 (got '{raw[:40]}').")
    return value


def check_node_limit(map_: Map) -> None:
    """Refuse a map whose graph would not fit in memory before building it."""
    limit = max_nodes()
    if map_.water_nodes > limit:
        raise GuadalError(
            f"map '{map_.name or map_.source}' has {map_.water_nodes:,} water nodes; guadal builds graphs of at most "
            f"{limit:,} (set {MAX_NODES_ENV} to raise the limit, memory permitting, or discretize with larger cells)."
        )


@dataclass(frozen=True)
class LocalProjection:
    """Equirectangular projection around an origin: accurate to centimetres over a lake."""

    lat0: float
    lon0: float

    def to_xy(self, lat, lon):
        lat = np.asarray(lat, dtype=float)
        lon = np.asarray(lon, dtype=float)
        x = np.radians(lon - self.lon0) * EARTH_RADIUS_M * math.cos(math.radians(self.lat0))
        y = np.radians(lat - self.lat0) * EARTH_RADIUS_M
        return x, y

    def to_latlon(self, x, y):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        lat = self.lat0 + np.degrees(y / EARTH_RADIUS_M)
        lon = self.lon0 + np.degrees(x / (EARTH_RADIUS_M * math.cos(math.radians(self.lat0))))
        return lat, lon


def haversine_m(lat1, lon1, lat2, lon2):
    """Great-circle distance in metres (for checks against GPS, not for the graph)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dphi = p2 - p1
    dlmb = np.radians(np.asarray(lon2) - np.asarray(lon1))
    a = np.sin(dphi / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlmb / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(a))


@dataclass
class Map:
    """A water mask with coordinates for every cell centre.

    ``lat``/``lon`` and ``x``/``y`` (metres east/north of the reference cell) are full grids of
    the mask's shape, so every consumer reads positions the same way whichever georeference
    the file used.
    """

    mask: np.ndarray  # bool, (rows, cols), True = water
    cell_size_m: float
    reference: dict  # {"row", "col", "lat", "lon"}
    name: str = ""
    description: str = ""
    latlon_grid: tuple[np.ndarray, np.ndarray] | None = None
    source: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        self.mask = np.asarray(self.mask, dtype=bool)
        if self.mask.ndim != 2 or self.mask.size == 0:
            raise GuadalError("a map's mask must be a non-empty 2-D grid.")
        if self.mask.size > MAX_GRID_CELLS:
            raise GuadalError(
                f"a map's grid is {self.mask.shape[0]}x{self.mask.shape[1]}; maps are at most {MAX_GRID_CELLS:,} cells."
            )
        if not MIN_CELL_SIZE_M <= self.cell_size_m <= MAX_CELL_SIZE_M:  # False for NaN too
            raise GuadalError(
                f"a map's cell_size_m must be between {MIN_CELL_SIZE_M:g} and {MAX_CELL_SIZE_M:g} metres "
                f"(got {self.cell_size_m:g})."
            )
        self.projection = LocalProjection(float(self.reference["lat"]), float(self.reference["lon"]))
        rows, cols = self.mask.shape
        if self.latlon_grid is None:
            rr, cc = np.mgrid[0:rows, 0:cols]
            self.x = (cc - self.reference["col"]) * self.cell_size_m
            self.y = -(rr - self.reference["row"]) * self.cell_size_m
            self.lat, self.lon = self.projection.to_latlon(self.x, self.y)
        else:
            self.lat = np.asarray(self.latlon_grid[0], dtype=float)
            self.lon = np.asarray(self.latlon_grid[1], dtype=float)
            if self.lat.shape != self.mask.shape or self.lon.shape != self.mask.shape:
                raise GuadalError(
                    f"a map's latlon grid has shape {self.lat.shape}, but its mask is {self.mask.shape}; "
                    "they must match."
                )
            self._check_range()
            self.x, self.y = self.projection.to_xy(self.lat, self.lon)
            self._check_spacing()
        self._check_range()

    @classmethod
    def from_grids(cls, mask, lat, lon, name: str = "", description: str = "") -> Map:
        """A map whose cells are exactly the mask's (1 or True = water), each centred at the given
        ``lat``/``lon`` matrices: a discretization made elsewhere, taken as it is (no resampling).
        The nominal cell size is the median spacing of neighbouring centres."""
        mask = np.asarray(mask)
        if mask.dtype != bool:
            if mask.size and not np.isin(mask, (0, 1)).all():
                raise GuadalError("a map's mask must hold 0 (land) and 1 (water) only.")
            mask = mask.astype(bool)
        lat, lon = np.asarray(lat, dtype=float), np.asarray(lon, dtype=float)
        if lat.shape != mask.shape or lon.shape != mask.shape:
            raise GuadalError(
                f"the lat and lon matrices must have the mask's shape {mask.shape} (got {lat.shape} and {lon.shape})."
            )
        gaps = [haversine_m(lat[:, :-1], lon[:, :-1], lat[:, 1:], lon[:, 1:]).ravel()]
        gaps.append(haversine_m(lat[:-1], lon[:-1], lat[1:], lon[1:]).ravel())
        gaps_m = np.concatenate(gaps) if any(g.size for g in gaps) else np.array([MIN_CELL_SIZE_M])
        row, col = mask.shape[0] // 2, mask.shape[1] // 2
        return cls(
            mask=mask,
            cell_size_m=float(np.median(gaps_m)),
            reference={"row": row, "col": col, "lat": float(lat[row, col]), "lon": float(lon[row, col])},
            name=name,
            description=description,
            latlon_grid=(lat, lon),
        )

    def _check_range(self) -> None:
        if not (np.all(np.abs(self.lat) <= 90) and np.all(np.abs(self.lon) <= 180)):  # NaN fails too
            raise GuadalError(
                "a map's cells must lie at latitudes in [-90, 90] and longitudes in [-180, 180]; "
                "this grid reaches beyond (check the reference and cell_size_m, or the latlon grid)."
            )

    def _check_spacing(self) -> None:
        """Neighbouring cell centres of a latlon grid must be a cell apart, not collapsed or flung away."""
        low, high = MIN_CELL_SIZE_M / 2, MAX_CELL_SIZE_M * 2
        for axis in (0, 1):
            if self.mask.shape[axis] < 2:
                continue
            gap = np.hypot(np.diff(self.x, axis=axis), np.diff(self.y, axis=axis))
            bad = ~((gap >= low) & (gap <= high))
            if bad.any():
                r, c = (int(i) for i in np.argwhere(bad)[0])
                raise GuadalError(
                    f"a map's latlon grid puts neighbouring cells {float(gap[r, c]):.3g} m apart (near row {r}, col {c}); "
                    f"cells must be {MIN_CELL_SIZE_M:g} to {MAX_CELL_SIZE_M:g} m across "
                    "(a grid collapsed to one point, or a wrong coordinate?)."
                )

    # --- derived facts -------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.mask.shape)  # type: ignore[return-value]

    @property
    def water_nodes(self) -> int:
        return int(self.mask.sum())

    def cell_area_m2(self) -> np.ndarray:
        """Area of every cell; from neighbour spacing when the grid gives coordinates."""
        if self.latlon_grid is None:
            return np.full(self.mask.shape, self.cell_size_m**2)
        dx = (
            np.abs(np.gradient(self.x, axis=1))
            if self.mask.shape[1] > 1
            else np.full(self.mask.shape, self.cell_size_m)
        )
        dy = (
            np.abs(np.gradient(self.y, axis=0))
            if self.mask.shape[0] > 1
            else np.full(self.mask.shape, self.cell_size_m)
        )
        return dx * dy

    def summary(self) -> dict:
        water = self.mask
        return {
            "name": self.name,
            "shape": list(self.shape),
            "water_nodes": self.water_nodes,
            "cell_size_m": round(float(self.cell_size_m), 6),
            "area_m2": round(float(self.cell_area_m2()[water].sum()), 3),
            "lat_bounds": [float(self.lat[water].min()), float(self.lat[water].max())]
            if water.any()
            else None,
            "lon_bounds": [float(self.lon[water].min()), float(self.lon[water].max())]
            if water.any()
            else None,
        }

    def rowcol_of(self, lat: float, lon: float) -> tuple[int, int] | None:
        """The cell whose centre is nearest to (lat, lon), or None if it lies off the grid."""
        x, y = self.projection.to_xy(lat, lon)
        if self.latlon_grid is None:
            col = int(round(float(x) / self.cell_size_m + self.reference["col"]))
            row = int(round(-float(y) / self.cell_size_m + self.reference["row"]))
            if 0 <= row < self.mask.shape[0] and 0 <= col < self.mask.shape[1]:
                return row, col
            return None
        d2 = (self.x - x) ** 2 + (self.y - y) ** 2
        row, col = np.unravel_index(int(np.argmin(d2)), d2.shape)
        if math.sqrt(float(d2[row, col])) > self.cell_size_m:
            return None
        return int(row), int(col)

    # --- file I/O ------------------------------------------------------------------------
    def to_dict(self) -> dict:
        data = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "name": self.name,
            "description": self.description,
            "cell_size_m": float(self.cell_size_m),
            "reference": {
                "row": int(self.reference["row"]),
                "col": int(self.reference["col"]),
                "lat": float(self.reference["lat"]),
                "lon": float(self.reference["lon"]),
            },
            "mask": ["".join("1" if v else "0" for v in row) for row in self.mask],
        }
        if self.latlon_grid is not None:
            data["latlon"] = {
                "lat": [[round(float(v), 9) for v in row] for row in self.lat],
                "lon": [[round(float(v), 9) for v in row] for row in self.lon],
            }
        return data

    def save(self, path: str | Path) -> None:
        """Write atomically, so a crash never leaves half a map behind."""
        path = Path(path)
        tmp = path.with_name(path.name + ".partial")
        tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        tmp.replace(path)


def load_map(path: str | Path) -> Map:
    """Read and check a map file; every problem is one :class:`GuadalError` sentence."""
    path = Path(path)
    shown = checked_path(path, "map file")
    try:
        if not path.is_file():
            raise GuadalError(f"map file '{shown}' does not exist.")
        size = path.stat().st_size
        if size > MAX_MAP_BYTES:
            raise GuadalError(
                f"map file '{shown}' is {size:,} bytes; map files are at most {MAX_MAP_BYTES:,} bytes."
            )
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, ValueError) as exc:  # ValueError: not UTF-8, not JSON, numbers past 4300 digits
        reason = getattr(exc, "strerror", None) or exc
        raise GuadalError(f"map file '{shown}' is not readable JSON ({reason}).") from exc
    except RecursionError as exc:
        raise GuadalError(f"map file '{shown}' nests its JSON too deeply to be a guadal map.") from exc
    return map_from_dict(data, path)


def _whole(value) -> int | None:
    """An integer given as a JSON number (``15`` or ``15.0``), else None."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return None


def _number(value) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def map_from_dict(data: dict, path: Path | str = "<map>") -> Map:
    where = f"map file '{path}'"
    if not isinstance(data, dict) or data.get("format") != FORMAT_NAME:
        raise GuadalError(f"{where} is not a guadal map: 'format' must be '{FORMAT_NAME}'.")
    version = data.get("version")
    if _whole(version) != FORMAT_VERSION:
        shown = repr(version) if not isinstance(version, (dict, list)) else type(version).__name__
        raise GuadalError(f"{where} has version {shown[:40]}; this guadal reads version {FORMAT_VERSION}.")
    rows = data.get("mask")
    if not isinstance(rows, list) or not rows or not all(isinstance(r, str) for r in rows):
        raise GuadalError(f"{where}: 'mask' must be a list of strings of 0 and 1, one per row.")
    width = len(rows[0])
    if len(rows) * width > MAX_GRID_CELLS:
        raise GuadalError(
            f"{where}: the mask is {len(rows)}x{width}; maps are at most {MAX_GRID_CELLS:,} cells "
            "(discretize with larger cells)."
        )
    for i, row in enumerate(rows):
        if len(row) != width or set(row) - {"0", "1"}:
            raise GuadalError(f"{where}: mask row {i} must be {width} characters of 0 (land) and 1 (water).")
    mask = np.array([[c == "1" for c in row] for row in rows], dtype=bool)
    if not mask.any():
        raise GuadalError(f"{where}: the mask has no water cell.")
    ref = data.get("reference")
    needed = {"row", "col", "lat", "lon"}
    if not isinstance(ref, dict) or not needed <= set(ref):
        raise GuadalError(f"{where}: 'reference' must give row, col, lat and lon of one cell.")
    lat, lon = _number(ref["lat"]), _number(ref["lon"])
    if lat is None or lon is None or not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise GuadalError(f"{where}: reference lat must be a number in [-90, 90] and lon one in [-180, 180].")
    ref_row, ref_col = _whole(ref["row"]), _whole(ref["col"])
    if ref_row is None or ref_col is None or not (0 <= ref_row < mask.shape[0] and 0 <= ref_col < width):
        raise GuadalError(
            f"{where}: reference row and col must be whole numbers naming a cell of the grid "
            f"(rows 0..{mask.shape[0] - 1}, cols 0..{width - 1})."
        )
    cell = _number(data.get("cell_size_m"))
    if cell is None or not MIN_CELL_SIZE_M <= cell <= MAX_CELL_SIZE_M:
        raise GuadalError(
            f"{where}: 'cell_size_m' must be a number of metres between {MIN_CELL_SIZE_M:g} and {MAX_CELL_SIZE_M:g}."
        )
    latlon = None
    if "latlon" in data:
        grids = data["latlon"]
        try:
            if not isinstance(grids, dict):
                raise TypeError
            latlon = tuple(np.array(grids[k], dtype=float) for k in ("lat", "lon"))
        except (KeyError, TypeError, ValueError, RecursionError) as exc:
            raise GuadalError(f"{where}: 'latlon' must hold 'lat' and 'lon' grids of numbers.") from exc
        if any(g.shape != mask.shape for g in latlon):
            raise GuadalError(
                f"{where}: 'latlon' grids must have the mask's shape {mask.shape[0]}x{width} "
                f"(got {'x'.join(map(str, latlon[0].shape))} and {'x'.join(map(str, latlon[1].shape))})."
            )
        if not all(np.isfinite(g).all() for g in latlon):
            raise GuadalError(
                f"{where}: 'latlon' holds NaN or infinite coordinates; every cell needs a position."
            )
    try:
        return Map(
            mask=mask,
            cell_size_m=cell,
            reference={"row": ref_row, "col": ref_col, "lat": lat, "lon": lon},
            name=str(data.get("name", ""))[:200],
            description=str(data.get("description", ""))[:2000],
            latlon_grid=latlon,
            source=Path(path) if not isinstance(path, Path) else path,
        )
    except GuadalError as exc:
        raise GuadalError(f"{where}: {exc}") from exc

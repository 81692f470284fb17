"""What ``guadal discretize`` reads: images, grid masks and lake outlines, behind one interface.

Every source answers the same questions, in lon/lat degrees so that no source needs to know the
output grid: where its water lies (``water_bounds``), how much water it holds
(``water_area_m2``), and whether each point of a lon/lat lattice is water
(``water_on_lattice``). The output grid's sub-cell samples form such a lattice because the
local projection maps latitude and longitude independently.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.path import Path as PolyPath
from scipy.spatial import cKDTree

from ..errors import GuadalError
from .format import EARTH_RADIUS_M, MAX_GRID_CELLS, LocalProjection
from .georef import Bounds, image_bounds
from .water_rules import WaterRule

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
GRID_SUFFIXES = (".csv", ".txt")
OUTLINE_SUFFIXES = (".geojson", ".json")


def _mask_bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows = np.nonzero(mask.any(axis=1))[0]
    cols = np.nonzero(mask.any(axis=0))[0]
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


@dataclass
class RasterSource:
    """A north-up raster whose pixels are water or not: an image, or a grid mask with bounds."""

    path: Path
    kind: str
    water: np.ndarray  # (H, W) bool, row 0 = north
    bounds: Bounds
    rule: str
    georef: str
    background: np.ndarray | None = None  # (H, W, 3) uint8, for the preview
    default_cell_size_m: float | None = None

    def __post_init__(self) -> None:
        h, w = self.water.shape
        self.dlat = (self.bounds.north - self.bounds.south) / h
        self.dlon = (self.bounds.east - self.bounds.west) / w

    @property
    def water_area_m2(self) -> float:
        ns = math.radians(1) * EARTH_RADIUS_M
        row_lat = self.bounds.north - (np.arange(self.water.shape[0]) + 0.5) * self.dlat
        pixel_area = (self.dlon * ns * np.cos(np.radians(row_lat))) * (self.dlat * ns)
        return float((self.water.sum(axis=1) * pixel_area).sum())

    def water_bounds(self) -> Bounds:
        r0, r1, c0, c1 = _mask_bbox(self.water)
        b = self.bounds
        return Bounds(
            north=b.north - r0 * self.dlat,
            south=b.north - (r1 + 1) * self.dlat,
            east=b.west + (c1 + 1) * self.dlon,
            west=b.west + c0 * self.dlon,
        )

    def water_on_lattice(self, lats: np.ndarray, lons: np.ndarray) -> np.ndarray:
        h, w = self.water.shape
        rows = np.floor((self.bounds.north - lats) / self.dlat).astype(int)
        cols = np.floor((lons - self.bounds.west) / self.dlon).astype(int)
        ok_r = (rows >= 0) & (rows < h)
        ok_c = (cols >= 0) & (cols < w)
        out = np.zeros((len(lats), len(lons)), dtype=bool)
        out[np.ix_(ok_r, ok_c)] = self.water[np.ix_(rows[ok_r], cols[ok_c])]
        return out

    def draw(self, ax) -> None:
        b = self.bounds
        image = self.background
        if image is None:
            image = np.where(
                self.water[..., None],
                np.array([156, 195, 230], np.uint8),
                np.array([235, 230, 215], np.uint8),
            )
        ax.imshow(image, extent=(b.west, b.east, b.south, b.north), interpolation="nearest", origin="upper")


def corners_from_centres(centres: np.ndarray) -> np.ndarray:
    """Cell corners of a structured grid of centres: midpoints inside, linear extrapolation at the edges."""
    padded = np.pad(centres, 1, mode="reflect", reflect_type="odd")
    return 0.25 * (padded[:-1, :-1] + padded[1:, :-1] + padded[:-1, 1:] + padded[1:, 1:])


#: how far (fraction of a cell) a regular grid's centres may stray from their row, column and spacing
_REGULAR_TOLERANCE = 0.1


def _regular_spacing(cx: np.ndarray, cy: np.ndarray) -> tuple[float, float] | None:
    """(east, north) spacing in metres of cell centres on north-up rows and columns, else None."""
    rows, cols = cx.shape
    if rows < 2 or cols < 2:
        return None
    width = float(cx[:, -1].mean() - cx[:, 0].mean()) / (cols - 1)
    height = float(cy[0].mean() - cy[-1].mean()) / (rows - 1)
    if not (width > 0 and height > 0):
        return None
    slack_x, slack_y = _REGULAR_TOLERANCE * width, _REGULAR_TOLERANCE * height
    straight = np.ptp(cy, axis=1).max() <= slack_y and np.ptp(cx, axis=0).max() <= slack_x
    even = (
        np.abs(np.diff(cx, axis=1) - width).max() <= slack_x
        and np.abs(np.diff(cy, axis=0) + height).max() <= slack_y
    )
    return (width, height) if straight and even else None


@dataclass
class CoordinateGridSource:
    """A grid mask with a lat/lon for every cell centre or corner; cells need not be square."""

    path: Path
    water: np.ndarray  # (R, C) bool
    corner_lat: np.ndarray  # (R+1, C+1)
    corner_lon: np.ndarray
    rule: str
    georef: str
    kind: str = "grid mask"

    def __post_init__(self) -> None:
        self.centre_lat = 0.25 * (
            self.corner_lat[:-1, :-1]
            + self.corner_lat[1:, :-1]
            + self.corner_lat[:-1, 1:]
            + self.corner_lat[1:, 1:]
        )
        self.centre_lon = 0.25 * (
            self.corner_lon[:-1, :-1]
            + self.corner_lon[1:, :-1]
            + self.corner_lon[:-1, 1:]
            + self.corner_lon[1:, 1:]
        )
        self.projection = LocalProjection(float(self.centre_lat.mean()), float(self.centre_lon.mean()))
        cx, cy = self.projection.to_xy(self.centre_lat, self.centre_lon)
        self._tree = cKDTree(np.column_stack([cx.ravel(), cy.ravel()]))
        kx, ky = self.projection.to_xy(self.corner_lat, self.corner_lon)
        ring = np.concatenate(
            [
                np.column_stack([kx[0, :], ky[0, :]]),
                np.column_stack([kx[1:, -1], ky[1:, -1]]),
                np.column_stack([kx[-1, -2::-1], ky[-1, -2::-1]]),
                np.column_stack([kx[-2:0:-1, 0], ky[-2:0:-1, 0]]),
            ]
        )
        self._outline = PolyPath(ring)
        self._edge_cell = np.zeros(self.water.shape, dtype=bool)
        self._edge_cell[[0, -1], :] = self._edge_cell[:, [0, -1]] = True
        # true size of each cell, from its corners
        ex = np.hypot(np.diff(kx, axis=1), np.diff(ky, axis=1))  # (R+1, C) edges along rows
        ey = np.hypot(np.diff(kx, axis=0), np.diff(ky, axis=0))  # (R, C+1) edges along columns
        self.cell_width_m = float(np.median(ex))
        self.cell_height_m = float(np.median(ey))
        if not (self.cell_width_m > 0 and self.cell_height_m > 0):
            raise GuadalError(
                f"{self.georef}: the coordinates give cells of zero size; neighbouring points must differ."
            )
        self.cell_area_m2 = 0.5 * np.abs(
            (kx[1:, 1:] - kx[:-1, :-1]) * (ky[1:, :-1] - ky[:-1, 1:])
            - (ky[1:, 1:] - ky[:-1, :-1]) * (kx[1:, :-1] - kx[:-1, 1:])
        )
        self.spacing_m = _regular_spacing(cx, cy)

    @property
    def regular(self) -> bool:
        """North-up rows and columns at an even spacing (to within rounding of the coordinates)."""
        return self.spacing_m is not None

    @property
    def default_cell_size_m(self) -> float:
        """The square cell of the same area as the source's typical cell.

        On a regular grid the mean spacing is used: coordinates written with few decimals make
        single cells uneven, and a median cell would drift across the grid.
        """
        width, height = self.spacing_m or (self.cell_width_m, self.cell_height_m)
        return math.sqrt(width * height)

    def nearest_centre(self, lat: float, lon: float) -> tuple[float, float]:
        """The source cell centre nearest to a point: output cells placed on it repeat the source's cells."""
        x, y = self.projection.to_xy(lat, lon)
        _, i = self._tree.query([float(x), float(y)])
        return float(self.centre_lat.ravel()[i]), float(self.centre_lon.ravel()[i])

    @property
    def bounds(self) -> Bounds:
        return Bounds(
            float(self.corner_lat.max()),
            float(self.corner_lat.min()),
            float(self.corner_lon.max()),
            float(self.corner_lon.min()),
        )

    @property
    def water_area_m2(self) -> float:
        return float(self.cell_area_m2[self.water].sum())

    def water_bounds(self) -> Bounds:
        r0, r1, c0, c1 = _mask_bbox(self.water)
        lat = self.corner_lat[r0 : r1 + 2, c0 : c1 + 2]
        lon = self.corner_lon[r0 : r1 + 2, c0 : c1 + 2]
        return Bounds(float(lat.max()), float(lat.min()), float(lon.max()), float(lon.min()))

    def water_on_lattice(self, lats: np.ndarray, lons: np.ndarray) -> np.ndarray:
        """The nearest cell centre decides; points beyond the grid's outline are land.

        Only points nearest to an edge cell can lie outside the grid, so only those are tested
        against the outline (a polygon test on every point would cost points x edge cells).
        """
        lat, lon = np.meshgrid(lats, lons, indexing="ij")
        x, y = self.projection.to_xy(lat.ravel(), lon.ravel())
        points = np.column_stack([x, y])
        _, idx = self._tree.query(points)
        out = self.water.ravel()[idx]
        near_edge = self._edge_cell.ravel()[idx] & out
        if near_edge.any():
            out[near_edge] = self._outline.contains_points(points[near_edge])
        return out.reshape(len(lats), len(lons))

    def draw(self, ax) -> None:
        from matplotlib.colors import ListedColormap

        ax.pcolormesh(
            self.corner_lon,
            self.corner_lat,
            self.water.astype(float),
            cmap=ListedColormap(["#ebe6d7", "#9cc3e6"]),
            vmin=0,
            vmax=1,
            edgecolors="#d0ccc0",
            linewidth=0.2,
        )


@dataclass
class OutlineSource:
    """Lake outlines: polygons of lon/lat rings (first ring the shore, the others islands)."""

    path: Path
    polygons: list[list[np.ndarray]]
    rule: str = "inside the polygons"
    georef: str = "lon/lat coordinates in the file"
    kind: str = "outline"
    default_cell_size_m: float | None = None
    _edges: list[tuple[np.ndarray, ...]] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        everything = np.concatenate([ring for polygon in self.polygons for ring in polygon])
        if np.ptp(everything[:, 0]) == 0 or np.ptp(everything[:, 1]) == 0:
            raise GuadalError(f"no water found: the polygons of outline '{self.path.name}' enclose no area.")
        self.bounds = Bounds(
            float(everything[:, 1].max()),
            float(everything[:, 1].min()),
            float(everything[:, 0].max()),
            float(everything[:, 0].min()),
        )
        self.projection = LocalProjection(*self.bounds.centre)
        for polygon in self.polygons:
            x1 = np.concatenate([ring[:-1, 0] for ring in polygon])
            y1 = np.concatenate([ring[:-1, 1] for ring in polygon])
            x2 = np.concatenate([ring[1:, 0] for ring in polygon])
            y2 = np.concatenate([ring[1:, 1] for ring in polygon])
            keep = y1 != y2  # horizontal edges never cross a scanline
            self._edges.append((x1[keep], y1[keep], x2[keep], y2[keep]))

    @property
    def water_area_m2(self) -> float:
        total = 0.0
        for polygon in self.polygons:
            areas = []
            for ring in polygon:
                x, y = self.projection.to_xy(ring[:, 1], ring[:, 0])
                areas.append(0.5 * abs(float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))))
            total += areas[0] - sum(areas[1:])
        return total

    def water_bounds(self) -> Bounds:
        return self.bounds

    def water_on_lattice(self, lats: np.ndarray, lons: np.ndarray) -> np.ndarray:
        """Even-odd rule per polygon on each latitude scanline; polygons are then united."""
        out = np.zeros((len(lats), len(lons)), dtype=bool)
        for x1, y1, x2, y2 in self._edges:
            if x1.size == 0:
                continue
            rows = np.nonzero((lats >= min(y1.min(), y2.min())) & (lats <= max(y1.max(), y2.max())))[0]
            for i in rows:
                lat = lats[i]
                crossing = (y1 <= lat) != (y2 <= lat)
                if not crossing.any():
                    continue
                xs = x1[crossing] + (lat - y1[crossing]) * (x2[crossing] - x1[crossing]) / (
                    y2[crossing] - y1[crossing]
                )
                xs.sort()
                out[i] |= (np.searchsorted(xs, lons, side="left") % 2) == 1
        return out

    def draw(self, ax) -> None:
        for polygon in self.polygons:
            for k, ring in enumerate(polygon):
                ax.fill(ring[:, 0], ring[:, 1], color="#9cc3e6" if k == 0 else "#ebe6d7", linewidth=0)
                ax.plot(ring[:, 0], ring[:, 1], color="#1d3f6e", linewidth=1.0)


# --- readers ------------------------------------------------------------------------------
def load_image(path: Path) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """(RGB on 0-255 as float32, alpha or None, whether the image is grey)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            img.load()
            mode = img.mode
            if mode.startswith("I;16") or mode in ("I", "F"):
                grey = np.asarray(img, dtype=np.float32)
                if mode.startswith("I;16"):
                    grey = grey / 257.0
                elif grey.size and float(grey.max()) <= 1.0:
                    grey = grey * 255.0  # a 0/1 mask
                grey = np.clip(grey, 0, 255)
                return np.repeat(grey[..., None], 3, axis=2), None, True
            has_alpha = "A" in mode or (mode == "P" and "transparency" in img.info)
            rgba = np.asarray(img.convert("RGBA" if has_alpha else "RGB"))
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, ValueError) as exc:
        raise GuadalError(f"cannot read image '{path.name}': {exc}.") from exc
    rgb = rgba[..., :3].astype(np.float32)
    alpha = rgba[..., 3] if has_alpha else None
    is_grey = bool(np.all(rgb[..., 0] == rgb[..., 1]) and np.all(rgb[..., 1] == rgb[..., 2]))
    return rgb, alpha, is_grey


#: text files larger than this are not grid masks or outlines a spreadsheet or GIS would write
MAX_TEXT_BYTES = 256 * 1024 * 1024
#: what --delimiter accepts, and the separators a grid mask's first row is sniffed for
DELIMITERS = {",": ",", ";": ";", "tab": "\t", "\\t": "\t", "\t": "\t", "space": None, "whitespace": None}


def _read_text(path: Path, what: str) -> str:
    """UTF-8 (with or without a byte-order mark) or UTF-16 with its mark, as spreadsheets save text."""
    try:
        size = path.stat().st_size
        if size > MAX_TEXT_BYTES:
            raise GuadalError(
                f"{what} '{path.name}' is {size:,} bytes; text sources are at most {MAX_TEXT_BYTES:,}."
            )
        raw = path.read_bytes()
    except OSError as exc:
        raise GuadalError(f"cannot read {what} '{path.name}': {exc.strerror or exc}.") from exc
    try:
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
            return raw.decode("utf-16")
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = None
    if text is None or "\x00" in text:
        raise GuadalError(
            f"cannot read {what} '{path.name}': it is not text (guadal reads UTF-8, or UTF-16 with a byte-order mark)."
        )
    return text


def _split(line: str, delimiter: str | None) -> list[str]:
    """Cells of one row; a decimal comma is read as a point when cells are not comma-separated."""
    cells = line.split() if delimiter is None else line.split(delimiter)
    cells = [c.strip().strip("\"'") for c in cells]
    if delimiter != ",":
        cells = [c.replace(",", ".") for c in cells]
    return [c for c in cells if c != ""]


def _sniff(line: str) -> str | None:
    """The separator of a row: ';', tab or ',' if present (in that order), else whitespace."""
    for candidate in (";", "\t", ","):
        if candidate in line:
            return candidate
    return None


def parse_delimiter(text: str | None) -> str | None:
    """``--delimiter`` as a separator (None: sniff from the first row)."""
    if text is None:
        return None
    if text not in DELIMITERS:
        raise GuadalError(
            f"--delimiter '{text[:20]}' is not one guadal reads (allowed: ',', ';', 'tab', 'space')."
        )
    return DELIMITERS[text] or " "


def read_grid_mask(path: Path, water_value: float, delimiter: str | None = None) -> np.ndarray:
    """A grid of numbers -> water where the value equals ``water_value``.

    Cells are separated by commas, semicolons, tabs or spaces: ``delimiter`` (``" "`` for any
    whitespace), or sniffed from the first row. One header row of non-numbers is skipped, as are
    blank lines and ``#`` comments.
    """
    rows = []
    sep = None if delimiter == " " else delimiter
    sniffed = delimiter is not None
    header_seen = False
    for number, line in enumerate(_read_text(path, "grid mask").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if not sniffed:
            sep, sniffed = _sniff(line), True
        cells = _split(line, sep)
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            if not rows and not header_seen:
                header_seen = True  # column names above the grid
                continue
            shown = {None: "spaces", ",": "','", ";": "';'", "\t": "tabs"}[sep]
            raise GuadalError(
                f"grid mask '{path.name}' line {number}: every cell must be a number (got '{line[:40]}'); "
                f"cells were split at {shown} (choose the separator with --delimiter)."
            ) from None
        if not all(math.isfinite(v) for v in rows[-1]):
            raise GuadalError(
                f"grid mask '{path.name}' line {number}: cells must be finite numbers, not NaN or inf."
            )
        if len(rows[-1]) != len(rows[0]):
            raise GuadalError(
                f"grid mask '{path.name}' line {number} has {len(rows[-1])} cells but the first row has {len(rows[0])}; "
                "every row must have the same number of cells."
            )
        if len(rows) * len(rows[0]) > MAX_GRID_CELLS:
            raise GuadalError(f"grid mask '{path.name}' has more than {MAX_GRID_CELLS:,} cells.")
    if not rows or not rows[0]:
        raise GuadalError(f"grid mask '{path.name}' holds no rows of numbers.")
    values = np.array(rows, dtype=float)
    water = np.isclose(values, water_value)
    if not water.any():
        found = ", ".join(f"{v:g}" for v in np.unique(values)[:6])
        raise GuadalError(
            f"no water found: no cell of '{path.name}' equals the water value {water_value:g} (values found: {found}); "
            "use --water-value to say which value is water."
        )
    return water


def read_latlon_grid(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``"lat,lon"`` strings separated by ``;`` -> (lat, lon) grids."""
    lat_rows, lon_rows = [], []
    for number, line in enumerate(_read_text(path, "coordinate grid").splitlines(), start=1):
        if not line.strip():
            continue
        lats, lons = [], []
        for token in line.strip().rstrip(";").split(";"):
            parts = token.strip().strip("\"'").split(",")
            try:
                lat, lon = (float(p) for p in parts)
            except ValueError:
                raise GuadalError(
                    f"coordinate grid '{path.name}' line {number}: '{token.strip()[:40]}' is not \"lat,lon\"; "
                    "each row holds \"lat,lon\" strings separated by ';'."
                ) from None
            if not (-90 <= lat <= 90 and -180 <= lon <= 180):
                raise GuadalError(
                    f"coordinate grid '{path.name}' line {number}: ({lat:g}, {lon:g}) is not a lat/lon in degrees."
                )
            lats.append(lat)
            lons.append(lon)
        if lat_rows and len(lats) != len(lat_rows[0]):
            raise GuadalError(
                f"coordinate grid '{path.name}' line {number} has {len(lats)} points but the first row has {len(lat_rows[0])}."
            )
        lat_rows.append(lats)
        lon_rows.append(lons)
    if not lat_rows:
        raise GuadalError(f"coordinate grid '{path.name}' holds no \"lat,lon\" rows.")
    return np.array(lat_rows), np.array(lon_rows)


def _rings(coords, where: str) -> list[np.ndarray]:
    rings = []
    for ring in coords:
        try:
            arr = np.array([[float(p[0]), float(p[1])] for p in ring], dtype=float)
        except (TypeError, ValueError, IndexError):
            raise GuadalError(f"{where}: every position must be [lon, lat] numbers.") from None
        if len(arr) and not np.array_equal(arr[0], arr[-1]):
            arr = np.vstack([arr, arr[:1]])
        if len(arr) < 4:
            raise GuadalError(f"{where}: a polygon ring needs at least three distinct positions.")
        if np.abs(arr[:, 0]).max() > 180 or np.abs(arr[:, 1]).max() > 90:
            raise GuadalError(
                f"{where}: positions must be [lon, lat] in degrees, as GeoJSON requires (found values beyond ±180/±90)."
            )
        rings.append(arr)
    if not rings:
        raise GuadalError(f"{where}: a polygon needs at least its outer ring.")
    return rings


def read_outline(path: Path) -> list[list[np.ndarray]]:
    """Polygons (lists of rings) from GeoJSON: Polygon, MultiPolygon, Feature(Collection), GeometryCollection."""
    try:
        data = json.loads(_read_text(path, "outline"))
    except json.JSONDecodeError as exc:
        raise GuadalError(
            f"cannot read outline '{path.name}': not valid JSON ({exc.msg} at line {exc.lineno})."
        ) from exc
    where = f"outline '{path.name}'"
    if isinstance(data, dict) and data.get("format") == "guadal-map":
        raise GuadalError(
            f"'{path.name}' is a guadal map already: 'guadal map info' and 'guadal map show' read it."
        )
    polygons: list[list[np.ndarray]] = []

    def visit(obj) -> None:
        kind = obj.get("type") if isinstance(obj, dict) else None
        if kind == "FeatureCollection":
            for feature in obj.get("features") or []:
                visit(feature)
        elif kind == "Feature":
            if obj.get("geometry") is not None:
                visit(obj["geometry"])
        elif kind == "GeometryCollection":
            for geometry in obj.get("geometries") or []:
                visit(geometry)
        elif kind == "Polygon":
            polygons.append(_rings(obj.get("coordinates") or [], where))
        elif kind == "MultiPolygon":
            for coords in obj.get("coordinates") or []:
                polygons.append(_rings(coords, where))
        else:
            raise GuadalError(
                f"{where} holds a {kind or 'non-GeoJSON object'}; guadal reads Polygon and MultiPolygon lake outlines "
                "(alone, in a Feature, a FeatureCollection or a GeometryCollection)."
            )

    visit(data)
    if not polygons:
        raise GuadalError(f"no water found: {where} holds no polygon.")
    return polygons


# --- one entry point ----------------------------------------------------------------------
def open_source(
    path: Path,
    *,
    bounds: str | None = None,
    rule: WaterRule | None = None,
    water_value: float | None = None,
    latlon_grid: Path | None = None,
    delimiter: str | None = None,
    image_only_options: tuple[str, ...] = (),
) -> RasterSource | CoordinateGridSource | OutlineSource:
    """Read ``path`` by its suffix, with the options that apply to its kind, and find its water."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise GuadalError(f"cannot read '{path}': no such file.")
    kinds = {"image": IMAGE_SUFFIXES, "grid mask": GRID_SUFFIXES, "outline": OUTLINE_SUFFIXES}
    kind = next((k for k, suffixes in kinds.items() if suffix in suffixes), None)
    if kind is None:
        allowed = ", ".join(s for suffixes in kinds.values() for s in suffixes)
        raise GuadalError(f"cannot read '{path.name}': unknown kind of file '{suffix}' (allowed: {allowed}).")
    a_kind = {"image": "an image", "grid mask": "a grid mask", "outline": "an outline"}[kind]
    if kind != "image" and image_only_options:
        raise GuadalError(
            f"{', '.join(image_only_options)} apply to images only, and '{path.name}' is {a_kind}."
        )
    for flag, given in (
        ("--latlon-grid", latlon_grid is not None),
        ("--water-value", water_value is not None),
        ("--delimiter", delimiter is not None),
    ):
        if kind != "grid mask" and given:
            raise GuadalError(
                f"{flag} applies to grid masks (.csv, .txt) only, and '{path.name}' is {a_kind}."
            )
    parsed_bounds = Bounds.parse(bounds) if bounds is not None else None

    if kind == "image":
        return _open_image(path, parsed_bounds, rule or WaterRule())
    if kind == "outline":
        if parsed_bounds is not None:
            raise GuadalError(
                f"--bounds does not apply to outlines: '{path.name}' carries its own lon/lat coordinates."
            )
        return OutlineSource(path, read_outline(path))
    return _open_grid(
        path,
        parsed_bounds,
        1.0 if water_value is None else water_value,
        latlon_grid,
        parse_delimiter(delimiter),
    )


def _open_image(path: Path, bounds: Bounds | None, rule: WaterRule) -> RasterSource:
    rgb, alpha, is_grey = load_image(path)
    height, width = rgb.shape[:2]
    georef_bounds, georef = image_bounds(path, width, height, bounds)
    applied = rule.resolve(is_grey)
    water = applied.apply(rgb, alpha)
    described = applied.describe()
    if applied != rule:
        described += f" (default for a {'grey' if is_grey else 'colour'} image)"
    if not water.any():
        raise GuadalError(
            f"no water found in '{path.name}': no pixel matches the rule {applied.describe()}; "
            "choose another rule with --water-color, --threshold or --invert."
        )
    return RasterSource(
        path,
        "image",
        water,
        georef_bounds,
        described,
        georef,
        background=np.clip(rgb, 0, 255).astype(np.uint8),
    )


def _open_grid(
    path: Path, bounds: Bounds | None, water_value: float, latlon_grid: Path | None, delimiter: str | None
):
    water = read_grid_mask(path, water_value, delimiter)
    rule = f"value == {water_value:g}"
    if latlon_grid is None:
        if bounds is None:
            raise GuadalError(
                f"grid mask '{path.name}' has no georeference: give --latlon-grid FILE (cell centres or corners) "
                "or --bounds north,south,east,west."
            )
        return RasterSource(path, "grid mask", water, bounds, rule, "--bounds")
    if bounds is not None:
        raise GuadalError("give either --latlon-grid or --bounds for a grid mask, not both.")
    lat, lon = read_latlon_grid(latlon_grid)
    rows, cols = water.shape
    if lat.shape == (rows + 1, cols + 1):
        corner_lat, corner_lon, role = lat, lon, "corners"
    elif lat.shape == (rows, cols):
        if rows < 2 or cols < 2:
            raise GuadalError(
                f"coordinate grid '{latlon_grid.name}' gives centres of a {rows}x{cols} mask; cells can be sized from "
                "centres only with at least 2 rows and 2 columns (give corners instead)."
            )
        corner_lat, corner_lon, role = corners_from_centres(lat), corners_from_centres(lon), "centres"
    else:
        raise GuadalError(
            f"coordinate grid '{latlon_grid.name}' is {lat.shape[0]}x{lat.shape[1]} but the mask '{path.name}' is "
            f"{rows}x{cols}; it must be {rows}x{cols} (cell centres) or {rows + 1}x{cols + 1} (cell corners)."
        )
    return CoordinateGridSource(
        path, water, corner_lat, corner_lon, rule, f"cell {role} from {latlon_grid.name}"
    )

"""Turn a water source into a guadal map of square cells.

The output grid covers the source's water plus one cell of land all round, north-up, with
square cells of ``cell_size_m`` in the map's own local projection (the reference cell is the
projection origin, exactly as :class:`~guadal_cli.maps.format.Map` reads it back). Each cell
is split into ``supersample`` x ``supersample`` samples; the source says which samples are
water, and a cell is water when at least ``min_fraction`` of its samples are.

Then, in this order:

1. ``fill_holes_m2``: land pockets enclosed by water and smaller than this area become water
   (on the samples, before the fraction). By default (None) pockets under half a cell are filled:
   such a speck (a sun glint, a boat in the picture) cannot make a cell land on its own, but it
   would otherwise count as shore for the margin;
2. ``margin_m``: a cell stays water only if its centre is at least this far from land,
   measured on the samples (to within one sample); the grid's edge counts as land;
3. ``largest_body``: only the largest 8-connected body of water cells is kept (the graph's
   connectivity), after the margin so that a channel the margin closes splits the lake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..errors import GuadalError
from .format import MAX_CELL_SIZE_M, MAX_GRID_CELLS, MIN_CELL_SIZE_M, LocalProjection, Map

MAX_CELLS = MAX_GRID_CELLS
MAX_SAMPLES = 16_000_000
_CHUNK_SAMPLES = 1_000_000
_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True)
class DiscretizeOptions:
    cell_size_m: float | None = None
    min_fraction: float = 0.5
    supersample: int = 8
    margin_m: float = 0.0
    fill_holes_m2: float | None = None  # None: half a cell
    largest_body: bool = False

    def __post_init__(self) -> None:
        self.check()  # refuse impossible options where they are made

    def check(self) -> None:
        if self.cell_size_m is not None and not MIN_CELL_SIZE_M <= self.cell_size_m <= MAX_CELL_SIZE_M:
            raise GuadalError(
                f"must be between {MIN_CELL_SIZE_M:g} and {MAX_CELL_SIZE_M:g} metres (got {self.cell_size_m:g}).",
                field="cell_size_m",
            )
        if not (0 < self.min_fraction <= 1):
            raise GuadalError(f"must be in (0, 1] (got {self.min_fraction:g}).", field="min_fraction")
        if not (1 <= self.supersample <= 32):
            raise GuadalError(
                f"must be between 1 and 32 samples per cell side (got {self.supersample}).",
                field="supersample",
            )
        if not self.margin_m >= 0:
            raise GuadalError(f"must be zero or more metres (got {self.margin_m:g}).", field="margin_m")
        if self.fill_holes_m2 is not None and not self.fill_holes_m2 >= 0:
            raise GuadalError(
                f"must be zero or more square metres (got {self.fill_holes_m2:g}).", field="fill_holes_m2"
            )


@dataclass
class Discretized:
    """The map, and what it took to make it (for the summary and the preview)."""

    map: Map
    fraction: np.ndarray  # water fraction of every cell, before margin and largest-body
    source: object
    supersample: int
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        _, bodies = ndimage.label(self.map.mask, structure=_EIGHT)
        data = self.map.summary()
        data.update(
            {
                "bodies": int(bodies),
                "source": self.source.path.name,
                "source_kind": self.source.kind,
                "water_rule": self.source.rule,
                "georeference": self.source.georef,
                "source_water_m2": round(float(self.source.water_area_m2), 1),
                "samples_per_cell": self.supersample**2,
            }
        )
        return data


def _grid_for(source, cell: float) -> tuple[int, int, dict]:
    """Shape and reference of the grid over the source's water, with one cell of land around it."""
    wb = source.water_bounds()
    centre = LocalProjection(*wb.centre)
    x_w, y_n = centre.to_xy(wb.north, wb.west)
    x_e, y_s = centre.to_xy(wb.south, wb.east)
    # a span a hair over a whole number of cells (rounding in the georeference) adds no column
    cols = int(math.ceil(float(x_e - x_w) / cell - 1e-3)) + 2
    rows = int(math.ceil(float(y_n - y_s) / cell - 1e-3)) + 2
    if rows * cols > MAX_CELLS:
        raise GuadalError(
            f"{cell:g} m over {float(x_e - x_w):.0f} x {float(y_n - y_s):.0f} m of water makes a "
            f"{rows}x{cols} grid (more than {MAX_CELLS:,} cells); choose a larger cell size.",
            field="cell_size_m",
        )
    ref_row, ref_col = rows // 2, cols // 2
    # the grid is centred on the water; the reference cell's centre is the map's origin
    x_ref = (ref_col + 0.5) * cell - cols * cell / 2
    y_ref = rows * cell / 2 - (ref_row + 0.5) * cell
    lat, lon = centre.to_latlon(x_ref, y_ref)
    return rows, cols, {"row": ref_row, "col": ref_col, "lat": float(lat), "lon": float(lon)}


def sample_water(source, rows: int, cols: int, reference: dict, cell: float, k: int) -> np.ndarray:
    """Water at k x k samples per cell: a (rows*k, cols*k) boolean grid, north first."""
    projection = LocalProjection(reference["lat"], reference["lon"])
    offsets = ((np.arange(k) + 0.5) / k - 0.5) * cell
    x = ((np.arange(cols) - reference["col"]) * cell)[:, None] + offsets[None, :]
    y = (-(np.arange(rows) - reference["row"]) * cell)[:, None] - offsets[None, :]
    _, lons = projection.to_latlon(x.ravel(), np.zeros(x.size))
    lats, _ = projection.to_latlon(np.zeros(y.size), y.ravel())
    fine = np.zeros((lats.size, lons.size), dtype=bool)
    step = max(1, _CHUNK_SAMPLES // max(1, lons.size))
    for start in range(0, lats.size, step):
        fine[start : start + step] = source.water_on_lattice(lats[start : start + step], lons)
    return fine


def fill_small_holes(fine: np.ndarray, max_area_m2: float, sample_m: float) -> np.ndarray:
    """Fill land pockets (4-connected, not touching the edge) smaller than ``max_area_m2``."""
    labels, count = ndimage.label(~fine)
    if count == 0:
        return fine
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    small = sizes * sample_m**2 < max_area_m2
    small[0] = False
    small[edge] = False
    return fine | small[labels]


def centre_clearance(fine: np.ndarray, rows: int, cols: int, k: int, sample_m: float) -> np.ndarray:
    """Distance (m) from every cell's centre to the nearest land, to within one sample."""
    padded = np.pad(fine, 1, constant_values=False)
    distance = ndimage.distance_transform_edt(padded, sampling=sample_m)[1:-1, 1:-1]
    # a land sample's own distance is 0; the shore lies half a sample beyond the last water sample
    shore = np.maximum(distance - sample_m / 2, 0.0)
    middle = [k // 2 - 1, k // 2] if k % 2 == 0 else [k // 2]
    blocks = shore.reshape(rows, k, cols, k)[:, middle][:, :, :, middle]
    return blocks.min(axis=(1, 3))


def largest_body_only(mask: np.ndarray) -> np.ndarray:
    labels, count = ndimage.label(mask, structure=_EIGHT)
    if count <= 1:
        return mask
    sizes = np.bincount(labels.ravel())[1:]
    return labels == int(np.argmax(sizes)) + 1


def discretize(source, options: DiscretizeOptions, name: str = "", description: str = "") -> Discretized:
    """Square-cell map of ``source``; every impossible request is one :class:`GuadalError`."""
    options.check()
    cell = options.cell_size_m if options.cell_size_m is not None else source.default_cell_size_m
    if cell is None:
        raise GuadalError(
            f"is required for a {source.kind} (the size of the map's square cells, in metres).",
            field="cell_size_m",
        )
    cell = float(cell)
    water_m2 = float(source.water_area_m2)
    if water_m2 < cell**2:
        raise GuadalError(
            f"{cell:g} m ({cell**2:,.0f} m² per cell) is larger than the lake: '{source.path.name}' "
            f"holds {water_m2:,.0f} m² of water; choose a smaller cell size.",
            field="cell_size_m",
        )
    rows, cols, reference = _grid_for(source, cell)
    if options.cell_size_m is None and getattr(source, "regular", False):
        # the source's own cells, repeated: its water cells become the map's water cells one for one
        reference["lat"], reference["lon"] = source.nearest_centre(reference["lat"], reference["lon"])
    notes = []
    k = options.supersample
    while k > 1 and rows * cols * k * k > MAX_SAMPLES:
        k -= 1
    if k != options.supersample:
        notes.append(
            f"{k}x{k} samples per cell instead of {options.supersample}x{options.supersample}, to bound memory"
        )
    sample_m = cell / k

    fine = sample_water(source, rows, cols, reference, cell, k)
    fill_m2 = cell**2 / 2 if options.fill_holes_m2 is None else options.fill_holes_m2
    if fill_m2 > 0:
        fine = fill_small_holes(fine, fill_m2, sample_m)
    fraction = fine.reshape(rows, k, cols, k).mean(axis=(1, 3))
    mask = fraction >= options.min_fraction - 1e-12
    if not mask.any():
        raise GuadalError(
            f"the cell size ({cell:g} m) is larger than the lake: no cell is at least {options.min_fraction:.0%} water; "
            "choose a smaller --cell-size or a lower --min-fraction."
        )
    if options.margin_m > 0:
        clearance = centre_clearance(fine, rows, cols, k, sample_m)
        kept = mask & (clearance >= options.margin_m)
        if not kept.any():
            widest = float(clearance[mask].max())
            raise GuadalError(
                f"a margin of {options.margin_m:g} m leaves no water: no cell centre is farther than {widest:.1f} m "
                "from the shore; choose a smaller --margin."
            )
        mask = kept
    if options.largest_body:
        mask = largest_body_only(mask)
    result = Map(mask=mask, cell_size_m=cell, reference=reference, name=name, description=description)
    return Discretized(map=result, fraction=fraction, source=source, supersample=k, notes=notes)

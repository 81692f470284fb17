"""PNG previews: a map's water cells, drawn over the source they came from when there is one.

Axes are longitude and latitude, with the aspect that makes metres square at the map's latitude.
Figures are drawn with the Agg canvas directly (no global backend switch) and written to a
temporary file first, so a failed drawing never leaves half a PNG.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from ..errors import GuadalError
from .format import Map
from .sources import corners_from_centres

_WATER = ListedColormap(["#1f6fb4"])
_GRID_LINES_UP_TO = 150  # cells per side; beyond, lines would hide the water
_CELLS_DRAWN_UP_TO = 400  # cells per side: about the figure's width in pixels


def _cell_edges(map_: Map) -> tuple[np.ndarray, np.ndarray]:
    """Lon/lat of cell corners, (rows+1, cols+1), for square grids and coordinate grids alike."""
    if map_.latlon_grid is not None and min(map_.shape) >= 2:
        return corners_from_centres(map_.lon), corners_from_centres(map_.lat)
    rows, cols = map_.shape
    half = map_.cell_size_m / 2
    cc, rr = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1))
    x = (cc - map_.reference["col"]) * map_.cell_size_m - half
    y = -(rr - map_.reference["row"]) * map_.cell_size_m + half
    lat, lon = map_.projection.to_latlon(x, y)
    return lon, lat


def _coarsen(lon_e: np.ndarray, lat_e: np.ndarray, mask: np.ndarray, factor: int):
    """Blocks of ``factor`` x ``factor`` cells drawn as one, water if any cell in it is."""
    rows, cols = mask.shape
    r, c = -(-rows // factor), -(-cols // factor)
    padded = np.zeros((r * factor, c * factor), dtype=bool)
    padded[:rows, :cols] = mask
    coarse = padded.reshape(r, factor, c, factor).any(axis=(1, 3))
    keep = np.ix_(np.minimum(np.arange(r + 1) * factor, rows), np.minimum(np.arange(c + 1) * factor, cols))
    return lon_e[keep], lat_e[keep], coarse


def _draw_map(ax, map_: Map, alpha: float) -> None:
    """Water cells filled, every cell outlined (when there are few enough), node centres dotted.

    A grid with more cells per side than the image has pixels is drawn in blocks: a
    million-cell quad mesh cost most of ``discretize``'s time and memory for the same picture.
    """
    lon_e, lat_e = _cell_edges(map_)
    factor = -(-max(map_.shape) // _CELLS_DRAWN_UP_TO)
    mask = map_.mask
    if factor > 1:
        lon_e, lat_e, mask = _coarsen(lon_e, lat_e, mask, factor)
    water = np.ma.masked_where(~mask, np.ones(mask.shape))
    ax.pcolormesh(lon_e, lat_e, water, cmap=_WATER, vmin=0, vmax=1, alpha=alpha, linewidth=0)
    if max(map_.shape) <= _GRID_LINES_UP_TO:
        lines = [np.column_stack([lon_e[i], lat_e[i]]) for i in range(lon_e.shape[0])]
        lines += [np.column_stack([lon_e[:, j], lat_e[:, j]]) for j in range(lon_e.shape[1])]
        ax.add_collection(LineCollection(lines, colors="#0b3954", linewidths=0.3, alpha=0.6))
    if map_.water_nodes <= 4000:
        ax.plot(map_.lon[map_.mask], map_.lat[map_.mask], ".", color="#0b3954", markersize=1.5)


def _finish(fig: Figure, ax, map_: Map, title: str, path: Path) -> None:
    lat0 = float(map_.reference["lat"])
    ax.set_aspect(1 / max(math.cos(math.radians(lat0)), 1e-6))
    ax.set_xlabel("longitude (°)")
    ax.set_ylabel("latitude (°)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(axis="x", labelrotation=30)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    write_figure(fig, path)


def write_figure(fig: Figure, path: Path) -> None:
    """Save ``fig`` as PNG at ``path`` atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    if not path.parent.is_dir():
        raise GuadalError(f"cannot write preview '{path}': folder '{path.parent}' does not exist.")
    FigureCanvasAgg(fig)
    tmp = path.with_name(path.name + ".partial")
    try:
        fig.savefig(tmp, format="png", dpi=130)
        os.replace(tmp, path)
    except OSError as exc:
        raise GuadalError(f"cannot write preview '{path}': {exc.strerror or exc}.") from exc
    finally:
        if tmp.exists():
            tmp.unlink()


def _title(map_: Map) -> str:
    s = map_.summary()
    return (
        f"{s['name'] or 'map'}: {s['shape'][0]}x{s['shape'][1]} cells of {s['cell_size_m']:g} m, "
        f"{s['water_nodes']} water nodes, {s['area_m2']:,.0f} m²"
    )


def preview_discretized(result, path: Path) -> None:
    """The new grid's water cells over the source image, mask or outline."""
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot()
    result.source.draw(ax)
    _draw_map(ax, result.map, alpha=0.45)
    lon_e, lat_e = _cell_edges(result.map)
    ax.set_xlim(lon_e.min(), lon_e.max())
    ax.set_ylim(lat_e.min(), lat_e.max())
    _finish(fig, ax, result.map, _title(result.map) + f"\nover {result.source.path.name}", path)


def preview_map(map_: Map, path: Path) -> None:
    """Any guadal map on its own: water cells, cell outlines, node centres."""
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot()
    ax.set_facecolor("#ebe6d7")
    _draw_map(ax, map_, alpha=1.0)
    lon_e, lat_e = _cell_edges(map_)
    ax.set_xlim(lon_e.min(), lon_e.max())
    ax.set_ylim(lat_e.min(), lat_e.max())
    _finish(fig, ax, map_, _title(map_), path)

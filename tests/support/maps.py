"""Lakes of known geometry, drawn as images, grid masks with coordinate grids, and outlines.

Every shape is a function of (x, y) in metres east/north of a fixed centre, so tests know the
true area, shore and coordinates of what they discretize.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from guadal_cli.maps.format import LocalProjection

LAT0, LON0 = 37.4180, -5.9805
CENTRE = LocalProjection(LAT0, LON0)


def latlon(x, y):
    """Lat/lon of a point given in metres from the centre."""
    return CENTRE.to_latlon(x, y)


def bounds_of(half_width: float, half_height: float) -> tuple[float, float, float, float]:
    """(north, south, east, west) of a box centred on the centre."""
    north, east = latlon(half_width, half_height)
    south, west = latlon(-half_width, -half_height)
    return float(north), float(south), float(east), float(west)


def bounds_text(b) -> str:
    return ",".join(f"{v:.12f}" for v in b)


def disc(radius, cx=0.0, cy=0.0):
    return lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 <= radius**2


def box(west, east, south, north):
    return lambda x, y: (x >= west) & (x <= east) & (y >= south) & (y <= north)


def union(*shapes):
    return lambda x, y: np.logical_or.reduce([s(x, y) for s in shapes])


def minus(shape, hole):
    return lambda x, y: shape(x, y) & ~hole(x, y)


# An L: a vertical arm 30 m wide, a horizontal arm 30 m tall, each 100 m long; the notch is land.
L_WEST, L_EAST, L_SOUTH, L_NORTH, L_ARM = -47.3, 52.7, -51.1, 48.9, 30.0
L_SHAPE = union(box(L_WEST, L_WEST + L_ARM, L_SOUTH, L_NORTH), box(L_WEST, L_EAST, L_SOUTH, L_SOUTH + L_ARM))
L_AREA = 2 * 100 * L_ARM - L_ARM**2


def draw_image(
    path: Path, shape, half: float = 100.0, pixel: float = 0.5, water=(255, 255, 255), land=(0, 0, 0)
):
    """A north-up PNG of ``shape`` over a square of side 2*half metres; returns its bounds."""
    n = int(round(2 * half / pixel))
    centres = (np.arange(n) + 0.5) * pixel - half
    x, y = np.meshgrid(centres, -centres)  # row 0 = north
    inside = shape(x, y)
    image = np.where(inside[..., None], np.array(water, np.uint8), np.array(land, np.uint8))
    Image.fromarray(image.astype(np.uint8)).save(path)
    return bounds_of(half, half)


def draw_grid(
    path: Path,
    shape,
    dx: float,
    dy: float,
    half_w: float,
    half_h: float,
    water_value: int = 1,
    delimiter: str = ",",
    south_first: bool = False,
):
    """A grid mask of dx x dy cells (value = water_value where the cell centre is in the shape).

    Returns (centre_lat, centre_lon, corner_lat, corner_lon) of the cells as written.
    """
    cols, rows = int(round(2 * half_w / dx)), int(round(2 * half_h / dy))
    xc = (np.arange(cols) + 0.5) * dx - half_w
    yc = half_h - (np.arange(rows) + 0.5) * dy
    xk = np.arange(cols + 1) * dx - half_w
    yk = half_h - np.arange(rows + 1) * dy
    X, Y = np.meshgrid(xc, yc)
    inside = shape(X, Y)
    values = np.where(inside, water_value, 1 - water_value)
    clat, clon = latlon(*np.meshgrid(xc, yc))
    klat, klon = latlon(*np.meshgrid(xk, yk))
    if south_first:
        values, clat, clon, klat, klon = (a[::-1] for a in (values, clat, clon, klat, klon))
    path.write_text("\n".join(delimiter.join(str(int(v)) for v in row) for row in values) + "\n")
    return clat, clon, klat, klon, inside


def write_latlon_grid(path: Path, lat: np.ndarray, lon: np.ndarray) -> None:
    path.write_text(
        "\n".join(";".join(f'"{a:.9f},{b:.9f}"' for a, b in zip(r1, r2)) for r1, r2 in zip(lat, lon)) + "\n"
    )


def circle_ring(radius, cx=0.0, cy=0.0, n=256):
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    lat, lon = latlon(cx + radius * np.cos(t), cy + radius * np.sin(t))
    ring = [[float(a), float(b)] for a, b in zip(lon, lat)]
    return ring + ring[:1]


def polygon_area(radius, n=256):
    return 0.5 * n * radius**2 * math.sin(2 * math.pi / n)


def write_geojson(path: Path, geometry: dict) -> None:
    path.write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [{"type": "Feature", "properties": {}, "geometry": geometry}],
            }
        )
    )


def metres(map_, lat, lon):
    """Metres east/north of the centre for lat/lon arrays (to compare with known geometry)."""
    return CENTRE.to_xy(lat, lon)

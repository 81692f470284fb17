"""Regenerate the shipped maps: ``python maps/generate.py``.

Both lakes are synthetic outlines drawn by this script (smooth random shapes, thresholded),
not surveys: they have the scale of real lakes so missions behave realistically.
"""

from pathlib import Path

import numpy as np
from scipy import ndimage

from guadal_cli.maps.format import Map

HERE = Path(__file__).parent


def blob(shape, water_cells, seed, holes=0, smooth=6.0):
    """A connected lake of exactly ``water_cells`` cells, with optional islands."""
    rng = np.random.default_rng(seed)
    rows, cols = shape
    rr, cc = np.mgrid[0:rows, 0:cols]
    # an elongated basin plus smooth noise gives a natural, lobed shoreline
    # a gently curved, elongated basin (like a park lake) ...
    bend = 0.25 * rows * np.sin(np.pi * cc / cols)
    basin = -(
        ((rr - rows / 2 + bend - 0.12 * rows) / (rows / 2.2)) ** 2 + ((cc - cols / 2) / (cols / 2.1)) ** 2
    )
    # ... with a lobed shoreline from smooth noise
    noise = ndimage.gaussian_filter(rng.standard_normal(shape), smooth)
    field = basin + 0.35 * noise / noise.std()
    for _ in range(holes):
        r0, c0 = rows * rng.uniform(0.35, 0.65), cols * rng.uniform(0.3, 0.7)
        field -= 3.0 * np.exp(-(((rr - r0) / (rows * 0.06)) ** 2 + ((cc - c0) / (cols * 0.05)) ** 2))
    field[[0, -1], :] = field[:, [0, -1]] = -np.inf  # shore all round
    order = np.sort(field.ravel())[::-1]
    _lo, _hi = 0, len(order) - 1
    # grow the threshold until the largest connected body has exactly water_cells cells
    for k in range(water_cells, len(order)):
        mask = field >= order[k - 1]
        labels, n = ndimage.label(mask, structure=np.ones((3, 3)))
        sizes = np.bincount(labels.ravel())[1:]
        if sizes.max() >= water_cells:
            body = labels == (np.argmax(sizes) + 1)
            if body.sum() == water_cells:
                return body
            # trim the weakest cells of the body until the count is exact
            vals = np.where(body, field, np.inf)
            drop = np.argsort(vals.ravel())[: body.sum() - water_cells]
            trimmed = body.copy().ravel()
            trimmed[drop] = False
            trimmed = trimmed.reshape(shape)
            labels, _ = ndimage.label(trimmed, structure=np.ones((3, 3)))
            sizes = np.bincount(labels.ravel())[1:]
            body = labels == (np.argmax(sizes) + 1)
            if body.sum() == water_cells:
                return body
    raise RuntimeError("could not shape the lake")


def main():
    small = blob((30, 49), 351, seed=11, smooth=3.0)
    Map(
        mask=small,
        cell_size_m=5.0,
        reference={"row": 15, "col": 24, "lat": 37.41795, "lon": -5.98345},
        name="urban_lake",
        description=(
            "Synthetic urban park lake at the scale of the GuadalPlanner paper's field site: 30x49 grid, "
            "351 water cells of 5 m (about 25 m2 each). Outline drawn by maps/generate.py, not surveyed."
        ),
    ).save(HERE / "urban_lake.json")
    large = blob((80, 110), 5200, seed=5, holes=2, smooth=8.0)
    Map(
        mask=large,
        cell_size_m=5.0,
        reference={"row": 40, "col": 55, "lat": 37.40210, "lon": -5.97100},
        name="reservoir",
        description=(
            "Synthetic reservoir with islands: 80x110 grid, 5,200 water cells of 5 m. "
            "Outline drawn by maps/generate.py, not surveyed; for scaling tests and benchmarks."
        ),
    ).save(HERE / "reservoir.json")


if __name__ == "__main__":
    main()

"""Draw ``examples/lake_satellite.png``: a synthetic north-up "satellite" picture of a park lake.

Run ``python examples/make_example_image.py`` to regenerate it (deterministic). The picture is
drawn, not photographed: blue-green water with depth shading, ripples and sun glints, an island,
a small separate pond, reeds along the shore, grass, bare soil and a footpath. At about one metre
per pixel it covers:

    north 37.4200, south 37.4164, east -5.9780, west -5.9830   (442 x 400 px, ~442 x 400 m)

which is what ``--bounds`` says in the README example.
"""

from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

HERE = Path(__file__).parent
WIDTH, HEIGHT = 442, 400
BOUNDS = (37.4200, 37.4164, -5.9780, -5.9830)  # north, south, east, west


def smooth_noise(rng, sigma, shape=(HEIGHT, WIDTH)):
    field = ndimage.gaussian_filter(rng.standard_normal(shape), sigma)
    return field / field.std()


def lake_shape(rng):
    """Signed field: > 0 on the lake, with a lobed shore, an island and a separate pond."""
    rr, cc = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    bend = 30 * np.sin(np.pi * cc / WIDTH * 1.4)
    basin = 1 - (((rr - 205 + bend) / 95) ** 2 + ((cc - 215) / 150) ** 2)
    lake = basin + 0.18 * smooth_noise(rng, 18)
    island = ((rr - 215) / 14) ** 2 + ((cc - 250) / 20) ** 2 < 1
    lake[island] = -1
    pond = 1 - (((rr - 345) / 14) ** 2 + ((cc - 385) / 18) ** 2)
    return np.maximum(lake, pond), island


def main() -> None:
    rng = np.random.default_rng(2024)
    field, island = lake_shape(rng)
    water = field > 0
    depth = np.clip(ndimage.distance_transform_edt(water) / 40.0, 0, 1)  # 0 at the shore, 1 deep

    # land: grass with patches of bare soil, a footpath ring, reeds right at the shore
    grass = np.array([78, 122, 52]) + 14 * smooth_noise(rng, 6)[..., None] * np.array([0.6, 1.0, 0.5])
    soil = np.array([146, 118, 84]) + 10 * smooth_noise(rng, 3)[..., None]
    soil_mix = np.clip((smooth_noise(rng, 25) - 0.6) * 1.5, 0, 1)[..., None]
    land = grass * (1 - soil_mix) + soil * soil_mix
    shore_distance = ndimage.distance_transform_edt(~water)
    reeds = (shore_distance > 0) & (shore_distance < 6) & ~island
    land[reeds] = np.array([58, 96, 40]) + 10 * rng.standard_normal((reeds.sum(), 1))
    path = (np.abs(shore_distance - 22) < 2.2) & ~island
    land[path] = np.array([168, 160, 146]) + 6 * rng.standard_normal((path.sum(), 1))
    land[island] = np.array([62, 104, 48]) + 12 * smooth_noise(rng, 2)[island][:, None]

    # water: turquoise shallows to dark blue-green depths, ripples, a few sun glints
    shallow, deep = np.array([72, 138, 132]), np.array([24, 70, 92])
    colour = shallow * (1 - depth[..., None]) + deep * depth[..., None]
    rr, cc = np.mgrid[0:HEIGHT, 0:WIDTH]
    ripples = np.sin(cc / 3.1 + 2.0 * smooth_noise(rng, 12)) * np.sin(rr / 9.0)
    colour = colour + (4 * ripples + 4 * smooth_noise(rng, 1.5))[..., None]
    glints = water & (rng.random(water.shape) < 0.002)
    colour[glints] = np.array([190, 205, 210])

    image = np.where(water[..., None], colour, land)
    Image.fromarray(np.clip(image, 0, 255).astype(np.uint8)).save(HERE / "lake_satellite.png", optimize=True)


if __name__ == "__main__":
    main()

"""Every kind of source: grid masks with coordinate grids, world files, outlines, colour rules."""

import math

import numpy as np
import pytest
from PIL import Image
from support.maps import (
    L_SHAPE,
    bounds_text,
    circle_ring,
    disc,
    draw_grid,
    draw_image,
    latlon,
    metres,
    polygon_area,
    write_geojson,
    write_latlon_grid,
)

from guadal_cli.errors import GuadalError
from guadal_cli.maps.discretize import DiscretizeOptions, discretize
from guadal_cli.maps.sources import open_source
from guadal_cli.maps.water_rules import WaterRule


def water_extent(m):
    x, y = metres(m, m.lat, m.lon)
    return x[m.mask].min(), x[m.mask].max(), y[m.mask].min(), y[m.mask].max()


# --- grid masks ----------------------------------------------------------------------------
@pytest.mark.parametrize("role", ["centres", "corners"])
@pytest.mark.parametrize("south_first", [False, True])
def test_inverted_csv_with_coordinate_grid_of_non_square_cells(tmp_path, role, south_first):
    # 5 m wide x 2.5 m tall source cells; 0 = water (the inverted files)
    mask_path, grid_path = tmp_path / "lake.csv", tmp_path / "lake_latlon.txt"
    clat, clon, klat, klon, inside = draw_grid(
        mask_path, L_SHAPE, dx=5.0, dy=2.5, half_w=60, half_h=60, water_value=0, south_first=south_first
    )
    write_latlon_grid(grid_path, *((clat, clon) if role == "centres" else (klat, klon)))
    source = open_source(mask_path, water_value=0, latlon_grid=grid_path)
    assert source.cell_width_m == pytest.approx(5.0, rel=1e-4)  # coordinates are written to 1e-9 degrees
    assert source.cell_height_m == pytest.approx(2.5, rel=1e-4)
    assert source.water_area_m2 == pytest.approx(inside.sum() * 12.5, rel=1e-4)

    # default cell size: the square of the same area as a source cell
    m = discretize(source, DiscretizeOptions()).map
    assert m.cell_size_m == pytest.approx(math.sqrt(12.5), rel=1e-4)
    cell = 2.0
    m = discretize(source, DiscretizeOptions(cell_size_m=cell)).map
    # source cells are water by their centre, so the lake's true edges are those cells' edges
    rows, cols = np.nonzero(inside)
    edges = {
        "west": -60 + cols.min() * 5.0,
        "east": -60 + (cols.max() + 1) * 5.0,
        "north": 60 - rows.min() * 2.5,
        "south": 60 - (rows.max() + 1) * 2.5,
    }
    assert abs(m.summary()["area_m2"] - inside.sum() * 12.5) < 0.5 * cell * 400
    west, east, south, north = water_extent(m)
    # the outermost water cell centres lie within half a cell of half a cell inside each edge
    assert abs(west - (edges["west"] + cell / 2)) <= cell / 2 + 1e-3
    assert abs(east - (edges["east"] - cell / 2)) <= cell / 2 + 1e-3
    assert abs(south - (edges["south"] + cell / 2)) <= cell / 2 + 1e-3
    assert abs(north - (edges["north"] - cell / 2)) <= cell / 2 + 1e-3


def test_water_up_to_the_coordinate_grid_edge_stops_there(tmp_path):
    mask_path, grid_path = tmp_path / "all.csv", tmp_path / "grid.txt"
    _, _, klat, klon, inside = draw_grid(mask_path, lambda x, y: x == x, dx=6.0, dy=3.0, half_w=30, half_h=30)
    write_latlon_grid(grid_path, klat, klon)
    m = discretize(open_source(mask_path, latlon_grid=grid_path), DiscretizeOptions(cell_size_m=2.0)).map
    assert inside.all()
    assert m.summary()["area_m2"] == pytest.approx(
        60 * 60, abs=1.0
    )  # the 60 x 60 m grid, not the cells beyond it


def test_whitespace_delimited_mask_with_bounds(tmp_path):
    path = tmp_path / "lake.txt"
    draw_grid(path, disc(40.0), dx=2.0, dy=2.0, half_w=50, half_h=50, delimiter=" ")
    from support.maps import bounds_of

    source = open_source(path, bounds=bounds_text(bounds_of(50, 50)))
    m = discretize(source, DiscretizeOptions(cell_size_m=4.0)).map
    assert abs(m.summary()["area_m2"] - math.pi * 1600) < 0.25 * 4.0 * 2 * math.pi * 40


def test_coordinate_grid_of_the_wrong_shape_is_refused(tmp_path):
    mask_path, grid_path = tmp_path / "lake.csv", tmp_path / "grid.txt"
    clat, clon, *_ = draw_grid(mask_path, disc(20.0), dx=5.0, dy=5.0, half_w=30, half_h=30)
    write_latlon_grid(grid_path, clat[:-2], clon[:-2])
    with pytest.raises(
        GuadalError,
        match=r"is 10x12 but the mask 'lake.csv' is 12x12; it must be 12x12 \(cell centres\) or 13x13",
    ):
        open_source(mask_path, latlon_grid=grid_path)


def test_grid_mask_without_the_water_value_is_refused(tmp_path):
    path = tmp_path / "lake.csv"
    path.write_text("0,0,0\n0,0,0\n")
    with pytest.raises(GuadalError, match="no water found.*equals the water value 1"):
        open_source(path, bounds="37.42,37.41,-5.97,-5.98")


def test_ragged_grid_mask_names_the_line(tmp_path):
    path = tmp_path / "lake.csv"
    path.write_text("1,1,0\n1,0\n")
    with pytest.raises(GuadalError, match="line 2 has 2 cells but the first row has 3"):
        open_source(path, bounds="37.42,37.41,-5.97,-5.98")


# --- images and their georeference ---------------------------------------------------------
def world_file_for(path, bounds, pixels):
    north, south, east, west = bounds
    a, e = (east - west) / pixels, -(north - south) / pixels
    path.write_text(f"{a!r}\n0\n0\n{e!r}\n{west + a / 2!r}\n{north + e / 2!r}\n")


def test_world_file_georeferences_like_bounds_and_must_agree_with_them(tmp_path):
    image = tmp_path / "lake.png"
    bounds = draw_image(image, L_SHAPE, half=100.0, pixel=0.5)
    with_bounds = discretize(
        open_source(image, bounds=bounds_text(bounds)), DiscretizeOptions(cell_size_m=5.0)
    ).map
    world_file_for(tmp_path / "lake.pgw", bounds, 400)
    with_world = discretize(open_source(image), DiscretizeOptions(cell_size_m=5.0)).map
    assert np.array_equal(with_world.mask, with_bounds.mask)
    assert np.allclose(with_world.lat, with_bounds.lat, atol=1e-9) and np.allclose(
        with_world.lon, with_bounds.lon, atol=1e-9
    )
    assert open_source(image, bounds=bounds_text(bounds)).georef == "--bounds (agrees with lake.pgw)"
    shifted = (bounds[0] + 0.0002, bounds[1] + 0.0002, bounds[2], bounds[3])  # 22 m north
    with pytest.raises(
        GuadalError, match="world file 'lake.pgw' and --bounds disagree: their north edges are 22.2 m apart"
    ):
        open_source(image, bounds=bounds_text(shifted))


def test_rotated_world_file_is_refused(tmp_path):
    image = tmp_path / "lake.png"
    draw_image(image, disc(30.0))
    (tmp_path / "lake.pgw").write_text("0.00001\n0.000001\n0\n-0.00001\n-5.98\n37.42\n")
    with pytest.raises(GuadalError, match="rotates the image"):
        open_source(image)


@pytest.mark.parametrize(
    "bounds, message",
    [
        ("37.41,37.42,-5.97,-5.98", r"north \(37.41\) must be greater than south \(37.42\)"),
        ("37.42,37.41,-5.98,-5.97", r"east \(-5.98\) must be greater than west \(-5.97\)"),
        ("97.42,37.41,-5.97,-5.98", r"north must be a latitude in \[-90, 90\]"),
        ("37.42,37.41,-5.97", "must be four numbers north,south,east,west"),
    ],
)
def test_contradictory_bounds_are_refused(tmp_path, bounds, message):
    image = tmp_path / "lake.png"
    draw_image(image, disc(30.0))
    with pytest.raises(GuadalError, match=message):
        open_source(image, bounds=bounds)


@pytest.mark.parametrize("suffix, mode", [(".jpg", "RGB"), (".tif", "L"), (".tif", "I;16"), (".png", "1")])
def test_jpeg_and_tiff_masks_read_like_png(tmp_path, suffix, mode):
    png = tmp_path / "lake.png"
    bounds = draw_image(png, disc(50.0), half=80.0, pixel=1.0)
    grey = Image.open(png).convert("L")
    other = tmp_path / f"other{suffix}"
    if mode == "I;16":
        Image.fromarray((np.asarray(grey) > 127).astype(np.uint16) * 65535).save(other)
    else:
        grey.convert(mode).save(other, quality=95) if suffix == ".jpg" else grey.convert(mode).save(other)
    reference = discretize(
        open_source(png, bounds=bounds_text(bounds)), DiscretizeOptions(cell_size_m=8.0)
    ).map
    m = discretize(open_source(other, bounds=bounds_text(bounds)), DiscretizeOptions(cell_size_m=8.0)).map
    assert abs(m.water_nodes - reference.water_nodes) <= 2


# --- colour rules --------------------------------------------------------------------------
SATELLITE_WATER, GRASS, SOIL, ROAD = (30, 90, 110), (80, 125, 50), (150, 115, 80), (160, 160, 160)


def satellite(tmp_path, water=SATELLITE_WATER):
    """A colour picture: a disc of water (r 40) on grass, with soil and a road in the land."""
    path = tmp_path / "photo.png"
    bounds = draw_image(path, disc(40.0), half=60.0, pixel=1.0, water=water, land=GRASS)
    pixels = np.asarray(Image.open(path)).copy()
    pixels[:15] = SOIL
    pixels[:, :6] = ROAD
    Image.fromarray(pixels).save(path)
    return path, bounds


@pytest.mark.parametrize(
    "rule",
    [
        WaterRule(),  # default for colour: index > 0.1
        WaterRule(colour=(30, 90, 110), tolerance=20),
        WaterRule.from_options(None, 40, "index>0.3", False),
        WaterRule.from_options(None, 40, "red>=60", True),
    ],
)
def test_colour_rules_find_the_drawn_water(tmp_path, rule):
    path, bounds = satellite(tmp_path)
    source = open_source(path, bounds=bounds_text(bounds), rule=rule)
    assert source.water_area_m2 == pytest.approx(math.pi * 40**2, rel=0.03)


def test_water_index_formula_and_default_rule_for_grey_masks(tmp_path):
    from guadal_cli.maps.water_rules import channel

    rgb = np.array([[SATELLITE_WATER, GRASS, SOIL, ROAD, (0, 0, 0)]], dtype=float)
    assert channel(rgb, "index")[0] == pytest.approx([80 / 140, -30 / 130, -70 / 230, 0.0, 0.0])
    assert WaterRule().resolve(is_grey=True).describe() == "gray>=128"
    assert WaterRule().resolve(is_grey=False).describe() == "index>0.1"


def test_black_water_masks_need_invert(tmp_path):
    path = tmp_path / "mask.png"
    bounds = draw_image(path, disc(30.0), half=50.0, water=(0, 0, 0), land=(255, 255, 255))
    inverted = open_source(path, bounds=bounds_text(bounds), rule=WaterRule(invert=True))
    assert inverted.water_area_m2 == pytest.approx(math.pi * 900, rel=0.02)


def test_transparent_pixels_are_never_water(tmp_path):
    path = tmp_path / "mask.png"
    bounds = draw_image(path, disc(30.0), half=50.0)
    rgba = np.asarray(Image.open(path).convert("RGBA")).copy()
    rgba[:, :100, 3] = 0  # the western half is no-data
    Image.fromarray(rgba).save(path)
    source = open_source(path, bounds=bounds_text(bounds))
    assert source.water_area_m2 == pytest.approx(math.pi * 900 / 2, rel=0.03)


def test_no_water_in_an_image_is_refused(tmp_path):
    path, bounds = satellite(tmp_path, water=GRASS)
    with pytest.raises(
        GuadalError, match=r"no water found in 'photo.png': no pixel matches the rule index>0.1"
    ):
        open_source(path, bounds=bounds_text(bounds))


@pytest.mark.parametrize(
    "text, message",
    [
        ("blue=>3", "is not a rule"),
        ("cyan>3", "an unknown channel 'cyan'"),
    ],
)
def test_bad_threshold_rules(text, message):
    with pytest.raises(GuadalError, match=message):
        WaterRule.from_options(None, 40, text, False)


# --- outlines ------------------------------------------------------------------------------
@pytest.mark.parametrize("cell", [4.0, 10.0])
def test_geojson_polygon_with_an_island(tmp_path, cell):
    path = tmp_path / "lake.geojson"
    write_geojson(
        path, {"type": "Polygon", "coordinates": [circle_ring(60.0), circle_ring(15.0, cx=20.0)[::-1]]}
    )
    source = open_source(path)
    true_area = polygon_area(60.0) - polygon_area(15.0)
    assert source.water_area_m2 == pytest.approx(true_area, rel=1e-3)
    m = discretize(source, DiscretizeOptions(cell_size_m=cell)).map
    assert abs(m.summary()["area_m2"] - true_area) < 0.25 * cell * 2 * math.pi * 75
    x, y = metres(m, m.lat, m.lon)
    assert not m.mask[np.hypot(x - 20.0, y) < 15.0 - cell].any()  # the island is land
    west, east, south, north = water_extent(m)
    for got, edge in [
        (west, -60 + cell / 2),
        (east, 60 - cell / 2),
        (south, -60 + cell / 2),
        (north, 60 - cell / 2),
    ]:
        assert abs(got - edge) <= cell / 2 + 0.1


def test_geojson_multipolygon_and_outside_lonlat_refused(tmp_path):
    path = tmp_path / "lakes.geojson"
    write_geojson(
        path,
        {"type": "MultiPolygon", "coordinates": [[circle_ring(30.0, cx=-50)], [circle_ring(20.0, cx=50)]]},
    )
    m = discretize(open_source(path), DiscretizeOptions(cell_size_m=4.0)).map
    assert abs(m.summary()["area_m2"] - polygon_area(30.0) - polygon_area(20.0)) < 0.25 * 4 * 2 * math.pi * 50
    lat, lon = latlon(0.0, 0.0)
    assert m.rowcol_of(float(lat), float(lon)) is not None and not m.mask[m.rowcol_of(float(lat), float(lon))]
    write_geojson(
        path,
        {
            "type": "Polygon",
            "coordinates": [[[500000, 4100000], [500100, 4100000], [500100, 4100100], [500000, 4100000]]],
        },
    )
    with pytest.raises(GuadalError, match=r"positions must be \[lon, lat\] in degrees"):
        open_source(path)
    write_geojson(path, {"type": "LineString", "coordinates": [[-5.98, 37.4], [-5.97, 37.41]]})
    with pytest.raises(GuadalError, match="holds a LineString; guadal reads Polygon and MultiPolygon"):
        open_source(path)


@pytest.mark.parametrize("decimals", [9, 6])
def test_regular_coordinate_grid_without_cell_size_keeps_its_own_cells(tmp_path, decimals):
    """The paper-scale lake as a mask plus cell centres (rounded as files often are) stays 351 nodes."""
    from support import LAKE

    from guadal_cli.maps.format import load_map

    lake = load_map(LAKE)
    mask_path, grid_path = tmp_path / "lake.csv", tmp_path / "lake_latlon.txt"
    np.savetxt(mask_path, lake.mask.astype(int), fmt="%d", delimiter=",")
    grid_path.write_text(
        "\n".join(
            ";".join(f'"{a:.{decimals}f},{b:.{decimals}f}"' for a, b in zip(r1, r2))
            for r1, r2 in zip(lake.lat, lake.lon)
        )
        + "\n"
    )
    source = open_source(mask_path, latlon_grid=grid_path)
    assert source.regular
    m = discretize(source, DiscretizeOptions()).map
    assert m.water_nodes == lake.water_nodes == 351
    assert m.cell_size_m == pytest.approx(lake.cell_size_m, rel=1e-3)
    # cell for cell: every output water cell sits on a source water cell centre
    x, y = lake.projection.to_xy(m.lat[m.mask], m.lon[m.mask])
    cx, cy = lake.projection.to_xy(lake.lat[lake.mask], lake.lon[lake.mask])
    gap = np.hypot(x[:, None] - cx[None, :], y[:, None] - cy[None, :]).min(axis=1)
    assert gap.max() < 0.5  # metres, on 5 m cells


def test_irregular_coordinate_grid_is_resampled(tmp_path):
    mask_path, grid_path = tmp_path / "lake.csv", tmp_path / "lake_latlon.txt"
    clat, clon, *_ = draw_grid(mask_path, L_SHAPE, dx=5.0, dy=5.0, half_w=60, half_h=60)
    clon = clon + 0.00002 * np.arange(clon.shape[0])[:, None]  # a sheared grid: columns lean east
    write_latlon_grid(grid_path, clat, clon)
    assert not open_source(mask_path, latlon_grid=grid_path).regular

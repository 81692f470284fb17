"""Discretization against lakes of known geometry: areas, node counts, coordinates, options."""

import math

import numpy as np
import pytest
from support.maps import (
    L_AREA,
    L_ARM,
    L_EAST,
    L_NORTH,
    L_SHAPE,
    L_SOUTH,
    L_WEST,
    bounds_text,
    box,
    disc,
    draw_image,
    metres,
    minus,
    union,
)

from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.discretize import DiscretizeOptions, discretize
from guadal_cli.maps.sources import open_source


def make(tmp_path, shape, cell, name="lake.png", half=100.0, **options):
    path = tmp_path / name
    bounds = draw_image(path, shape, half=half)
    source = open_source(path, bounds=bounds_text(bounds))
    return discretize(source, DiscretizeOptions(cell_size_m=cell, **options)).map


@pytest.mark.parametrize("cell", [3.0, 7.0, 12.0])
def test_disc_area_and_node_count_at_several_resolutions(tmp_path, cell):
    radius = 60.0
    m = make(tmp_path, disc(radius), cell)
    true_area = math.pi * radius**2
    # a cell is water when half of it is: errors along the shore cancel to well under a
    # quarter of a cell per metre of shore
    tolerance = 0.25 * cell * 2 * math.pi * radius
    assert abs(m.summary()["area_m2"] - true_area) < tolerance
    assert abs(m.water_nodes - true_area / cell**2) < tolerance / cell**2
    assert m.summary()["cell_size_m"] == cell


@pytest.mark.parametrize("cell", [4.0, 9.0])
def test_l_shaped_lake_edges_and_notch_are_where_they_were_drawn(tmp_path, cell):
    m = make(tmp_path, L_SHAPE, cell)
    # straight edges aligned with the grid move by at most half a cell each (perimeter 400 m)
    assert abs(m.summary()["area_m2"] - L_AREA) <= 0.5 * cell * 400
    x, y = metres(m, m.lat, m.lon)
    wx, wy = x[m.mask], y[m.mask]
    # cells are water when their centre is inside a straight edge: the outermost water centres
    # lie within half a cell of half a cell inside each drawn edge
    assert abs(wx.min() - (L_WEST + cell / 2)) <= cell / 2 + 1e-6
    assert abs(wx.max() - (L_EAST - cell / 2)) <= cell / 2 + 1e-6
    assert abs(wy.min() - (L_SOUTH + cell / 2)) <= cell / 2 + 1e-6
    assert abs(wy.max() - (L_NORTH - cell / 2)) <= cell / 2 + 1e-6
    # the notch (north-east of the inner corner) is land, well inside it
    notch = (x > L_WEST + L_ARM + cell) & (y > L_SOUTH + L_ARM + cell)
    assert notch.any() and not m.mask[notch].any()
    # and the graph goes around it: the path between the arms' tips bends at the corner
    g = NavGraph(m)
    top = g.nearest_node(*_latlon(L_WEST + L_ARM / 2, L_NORTH - cell))
    right = g.nearest_node(*_latlon(L_EAST - cell, L_SOUTH + L_ARM / 2))
    assert g.distance(top, right) > 0.9 * (L_NORTH - L_SOUTH - L_ARM + L_EAST - L_WEST - L_ARM)


def _latlon(x, y):
    from support.maps import latlon

    lat, lon = latlon(x, y)
    return float(lat), float(lon)


def test_known_points_land_on_the_cell_that_holds_them(tmp_path):
    cell = 5.0
    m = make(tmp_path, L_SHAPE, cell)
    for x, y in [
        (L_WEST + 3, L_NORTH - 3),
        (L_EAST - 2, L_SOUTH + 2),
        (L_WEST + 15, L_SOUTH + 15),
        (0.0, -40.0),
    ]:
        lat, lon = _latlon(x, y)
        row, col = m.rowcol_of(lat, lon)
        cx, cy = metres(m, m.lat[row, col], m.lon[row, col])
        assert abs(float(cx) - x) <= cell / 2 + 1e-6 and abs(float(cy) - y) <= cell / 2 + 1e-6
        assert m.mask[row, col]


def two_lakes(channel_width):
    """A big disc (r 40) and a small one (r 25), 110 m apart, joined along y=0 by a channel."""
    big, small = disc(40.0, cx=-50.0), disc(25.0, cx=60.0)
    channel = box(-50.0, 60.0, -channel_width / 2, channel_width / 2)
    return union(big, small, channel)


def test_channel_one_cell_wide_joins_the_lakes_until_a_margin_closes_it(tmp_path):
    cell = 5.0
    joined = make(tmp_path, two_lakes(cell), cell)
    assert NavGraph(joined).n_components == 1
    largest = make(tmp_path, two_lakes(cell), cell, largest_body=True)
    assert largest.water_nodes == joined.water_nodes  # the channel keeps both lakes in the largest body

    margin = 6.0
    split = make(tmp_path, two_lakes(cell), cell, margin_m=margin)
    assert NavGraph(split).n_components == 2
    big_only = make(tmp_path, two_lakes(cell), cell, margin_m=margin, largest_body=True)
    x, y = metres(big_only, big_only.lat, big_only.lon)
    assert big_only.water_nodes > 0
    assert np.all(x[big_only.mask] < 0)  # only the big lake (west) is left
    assert NavGraph(big_only).n_components == 1


def test_largest_body_drops_a_separate_pond(tmp_path):
    cell = 5.0
    both = make(tmp_path, union(disc(40.0, cx=-40.0), disc(15.0, cx=60.0)), cell)
    one = make(tmp_path, union(disc(40.0, cx=-40.0), disc(15.0, cx=60.0)), cell, largest_body=True)
    x, _ = metres(one, one.lat, one.lon)
    assert NavGraph(both).n_components == 2
    assert np.all(x[one.mask] < 0)
    assert both.water_nodes - one.water_nodes == pytest.approx(math.pi * 15**2 / cell**2, rel=0.35)


@pytest.mark.parametrize("margin", [8.0, 20.0])
def test_margin_keeps_exactly_the_cells_far_enough_from_the_shore(tmp_path, margin):
    radius, cell = 60.0, 4.0
    m = make(tmp_path, disc(radius), cell, margin_m=margin)
    x, y = metres(m, m.lat, m.lon)
    from_shore = radius - np.hypot(x, y)  # distance of every cell centre from the drawn shore
    sample = cell / 8
    assert np.all(from_shore[m.mask] >= margin - 2 * sample)
    assert np.all(m.mask[from_shore >= margin + 2 * sample])


def test_fill_holes_fills_small_islands_only(tmp_path):
    radius, cell = 60.0, 4.0
    with_island = minus(disc(radius), disc(6.0, cx=20.0))  # island of 113 m2
    plain = make(tmp_path, disc(radius), cell)
    kept = make(tmp_path, with_island, cell, fill_holes_m2=50.0)
    filled = make(tmp_path, with_island, cell, fill_holes_m2=200.0)
    assert kept.water_nodes < plain.water_nodes - 3
    assert np.array_equal(filled.mask, plain.mask)


def test_cell_larger_than_the_lake_is_refused(tmp_path):
    with pytest.raises(GuadalError, match="larger than the lake"):
        make(tmp_path, disc(10.0), 25.0)


def test_margin_wider_than_the_lake_is_refused(tmp_path):
    with pytest.raises(GuadalError, match="margin of 30 m leaves no water"):
        make(tmp_path, disc(20.0), 2.0, margin_m=30.0)


def test_min_fraction_trades_shore_cells(tmp_path):
    loose = make(tmp_path, disc(50.0), 6.0, min_fraction=0.05)
    strict = make(tmp_path, disc(50.0), 6.0, min_fraction=1.0)
    half = make(tmp_path, disc(50.0), 6.0)
    assert strict.water_nodes < half.water_nodes < loose.water_nodes
    x, y = metres(strict, strict.lat, strict.lon)
    # a fully-water cell lies entirely inside the disc: its far corner too
    assert np.all(np.hypot(np.abs(x[strict.mask]) + 3, np.abs(y[strict.mask]) + 3) <= 50.0 + 0.75)


def test_specks_in_the_water_do_not_count_as_shore_unless_asked(tmp_path):
    radius, cell, margin = 60.0, 5.0, 8.0
    rng = np.random.default_rng(1)
    specks_xy = rng.uniform(-40, 40, size=(40, 2))

    def speckled(x, y):  # sun glints: land specks of about one square metre
        speck = np.zeros(np.shape(x), dtype=bool)
        for sx, sy in specks_xy:
            speck |= (np.abs(x - sx) < 0.5) & (np.abs(y - sy) < 0.5)
        return disc(radius)(x, y) & ~speck

    clean = make(tmp_path, disc(radius), cell, margin_m=margin)
    default = make(tmp_path, speckled, cell, margin_m=margin)
    kept = make(tmp_path, speckled, cell, margin_m=margin, fill_holes_m2=0.0)
    assert np.array_equal(default.mask, clean.mask)
    assert kept.water_nodes < clean.water_nodes - 20

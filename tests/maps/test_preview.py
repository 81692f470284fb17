"""Previews of maps larger than the image: drawn in blocks, with no water lost."""

import numpy as np

from guadal_cli.maps.format import Map
from guadal_cli.maps.preview import _cell_edges, _coarsen, preview_map


def test_a_large_map_is_drawn_in_blocks_that_keep_every_water_cell(tmp_path):
    mask = np.zeros((1001, 900), dtype=bool)
    mask[1000, 3] = True  # one lone water cell in the last row
    mask[10:20, 500:510] = True
    m = Map(mask=mask, cell_size_m=5.0, reference={"row": 0, "col": 0, "lat": 37.0, "lon": -6.0})
    lon_e, lat_e = _cell_edges(m)
    lon_c, lat_c, coarse = _coarsen(lon_e, lat_e, mask, 3)
    assert coarse.shape == (334, 300) and lon_c.shape == lat_c.shape == (335, 301)
    assert coarse[333, 1] and coarse[3:7, 166:170].all() and coarse.sum() == 1 + 16
    # the blocks span the same extent as the cells
    assert lon_c.min() == lon_e.min() and lat_c.min() == lat_e.min() and lon_c.max() == lon_e.max()
    preview_map(m, tmp_path / "big.png")
    assert (tmp_path / "big.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

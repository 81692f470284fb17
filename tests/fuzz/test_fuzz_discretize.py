"""Grid masks as spreadsheets and careless hands write them, read by ``discretize``.

Whatever the separator (comma, semicolon, tab, spaces), header row, byte-order mark or encoding
(UTF-8, UTF-16), a clean mask reads back cell for cell; a mangled one is refused with one
sentence or read as a grid of the same cells.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.fuzz import assert_one_sentence, examples, time_limit

from guadal_cli.errors import GuadalError
from guadal_cli.maps.discretize import DiscretizeOptions, discretize
from guadal_cli.maps.sources import open_source, parse_delimiter, read_grid_mask

BOUNDS = "37.4200,37.4190,-5.9800,-5.9815"  # about 130 x 110 m
SEPARATORS = {",": ",", ";": ";", "\t": "tab", " ": "space", "  ": "space"}

masks = st.integers(2, 9).flatmap(
    lambda rows: st.integers(2, 9).flatmap(
        lambda cols: st.lists(
            st.lists(st.sampled_from([0, 1]), min_size=cols, max_size=cols), min_size=rows, max_size=rows
        )
    )
)


def render(grid, sep: str, header: bool, bom: bool, encoding: str, crlf: bool) -> bytes:
    lines = [sep.join(f"c{i}" for i in range(len(grid[0])))] if header else []
    lines += [sep.join(str(v) for v in row) for row in grid]
    text = ("\r\n" if crlf else "\n").join(lines) + "\n"
    if encoding == "utf-16":
        return text.encode("utf-16")  # with its byte-order mark, as spreadsheets save "Unicode text"
    return ("\ufeff" if bom else "").encode() + text.encode("utf-8")


SETTINGS = settings(
    max_examples=examples(40),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@SETTINGS
@given(
    grid=masks.filter(lambda g: any(map(any, g))),
    sep=st.sampled_from(sorted(SEPARATORS)),
    header=st.booleans(),
    bom=st.booleans(),
    encoding=st.sampled_from(["utf-8", "utf-16"]),
    crlf=st.booleans(),
    named=st.booleans(),
)
def test_a_spreadsheet_grid_mask_reads_back_cell_for_cell(
    grid, sep, header, bom, encoding, crlf, named, tmp_path_factory
):
    path = tmp_path_factory.mktemp("mask") / "lake.csv"
    path.write_bytes(render(grid, sep, header, bom, encoding, crlf))
    delimiter = SEPARATORS[sep] if named else None

    water = read_grid_mask(path, 1.0, parse_delimiter(delimiter))
    assert water.tolist() == (np.array(grid) == 1).tolist()


@SETTINGS
@given(
    grid=masks,
    sep=st.sampled_from(sorted(SEPARATORS)),
    damage=st.lists(st.tuples(st.integers(0, 400), st.binary(min_size=1, max_size=4)), max_size=4),
    encoding=st.sampled_from(["utf-8", "utf-16"]),
    cell=st.one_of(st.sampled_from([0.05, 5.0, 40.0, 1000.0, 1e300, float("nan")]), st.floats(2, 100)),
)
def test_a_mangled_grid_mask_is_refused_in_one_sentence_or_discretized(
    grid, sep, damage, encoding, cell, tmp_path_factory
):
    raw = bytearray(render(grid, sep, False, False, encoding, False))
    for at, junk in damage:
        raw[at % (len(raw) + 1) : at % (len(raw) + 1)] = junk
    path = tmp_path_factory.mktemp("mask") / "lake.csv"
    path.write_bytes(bytes(raw))
    with time_limit(60):
        try:
            source = open_source(path, bounds=BOUNDS)
            discretize(source, DiscretizeOptions(cell_size_m=cell, supersample=4))
        except GuadalError as exc:
            assert_one_sentence(exc)

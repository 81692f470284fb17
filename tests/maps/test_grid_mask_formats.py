"""Grid masks as spreadsheets export them, and ``discretize`` outputs it cannot write.

A European-locale spreadsheet separates cells with ';' and writes decimal commas; "Unicode text"
is UTF-16 with tabs; many exports put a header row and a byte-order mark first. All of them are
the same lake. Files that are not text, and outputs that cannot be written, get one sentence.
"""

import json

import numpy as np
import pytest
from support import LAKE, run_cli
from support.maps import bounds_of, bounds_text, disc, draw_grid
from typer.testing import CliRunner

from guadal_cli.app import app
from guadal_cli.errors import GuadalError
from guadal_cli.maps.sources import read_grid_mask

BOUNDS = "37.4200,37.4190,-5.9800,-5.9815"


def cells_of(path, **kwargs):
    return read_grid_mask(path, 1.0, **kwargs).astype(int).tolist()


GRID = [[0, 0, 0, 0], [0, 1, 1, 0], [0, 1, 1, 1], [0, 0, 0, 0]]


@pytest.mark.parametrize(
    "text",
    [
        "0;0;0;0\n0;1;1;0\n0;1;1;1\n0;0;0;0\n",
        "0;0;0;0;\n0;1;1;0;\n0;1;1;1;\n0;0;0;0;\n",  # a trailing separator, as some exports write
        "0,0;0,0;0;0\n0;1,0;1;0\n0;1;1;1,000\n0;0;0;0\n",  # decimal commas
        "0\t0\t0\t0\n0\t1\t1\t0\n0\t1\t1\t1\n0\t0\t0\t0\n",
        "0 0  0 0\n0 1 1 0\n 0 1 1 1\n0 0 0 0\n",
        "a,b,c,d\n0,0,0,0\n0,1,1,0\n0,1,1,1\n0,0,0,0\n",
        "\ufeffcol1;col2;col3;col4\r\n0;0;0;0\r\n0;1;1;0\r\n0;1;1;1\r\n0;0;0;0\r\n",
        '"0";"0";"0";"0"\n"0";"1";"1";"0"\n"0";"1";"1";"1"\n"0";"0";"0";"0"\n',
    ],
    ids=["semicolon", "trailing", "decimal-comma", "tab", "spaces", "header", "bom-header-crlf", "quoted"],
)
def test_every_spreadsheet_dialect_reads_as_the_same_grid(text, tmp_path):
    path = tmp_path / "lake.csv"
    path.write_text(text, encoding="utf-8")
    assert cells_of(path) == GRID


def test_utf16_unicode_text_export_reads_as_the_same_grid(tmp_path):
    path = tmp_path / "lake.txt"
    path.write_bytes("x\ty\tz\tw\n0\t0\t0\t0\n0\t1\t1\t0\n0\t1\t1\t1\n0\t0\t0\t0\n".encode("utf-16"))
    assert cells_of(path) == GRID


def test_delimiter_option_overrides_the_sniffing(tmp_path):
    path = tmp_path / "lake.csv"
    path.write_text("0 ;0 ;0\n0 ;1 ;1\n")
    assert cells_of(path, delimiter=";") == [[0, 0, 0], [0, 1, 1]]
    with pytest.raises(GuadalError, match="cells were split at ','.*--delimiter"):
        read_grid_mask(path, 1.0, ",")


def test_a_real_semicolon_lake_mask_discretizes_from_the_command_line(tmp_path):
    mask = tmp_path / "lake.csv"
    draw_grid(mask, disc(40), 5, 5, 60, 50, delimiter=";")
    semicolons = run_cli(
        "discretize",
        mask,
        "--bounds",
        bounds_text(bounds_of(60, 50)),
        "--cell-size",
        "5",
        "-o",
        tmp_path / "a.json",
        "--no-preview",
        "--json",
    )
    assert semicolons.returncode == 0, semicolons.stderr
    commas = tmp_path / "comma.csv"
    commas.write_text(mask.read_text().replace(";", ","))
    again = CliRunner().invoke(
        app,
        [
            "discretize",
            str(commas),
            "--bounds",
            bounds_text(bounds_of(60, 50)),
            "--cell-size",
            "5",
            "-o",
            str(tmp_path / "b.json"),
            "--no-preview",
            "--delimiter",
            ",",
        ],
    )
    assert again.exit_code == 0, again.output
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    assert a["mask"] == b["mask"] and sum(r.count("1") for r in a["mask"]) > 100


@pytest.mark.parametrize(
    "content, fragment",
    [
        (bytes(range(256)) * 4, "it is not text (guadal reads UTF-8, or UTF-16 with a byte-order mark)"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "it is not text"),
        ("0,1\n1,1\n".encode("utf-16-le"), "it is not text"),  # UTF-16 without its mark
        (b"0,nan\n1,1\n", "cells must be finite numbers"),
    ],
    ids=["binary", "png-named-csv", "utf16-no-bom", "nan"],
)
def test_a_file_that_is_not_a_grid_of_numbers_gets_one_sentence(content, fragment, tmp_path):
    path = tmp_path / "lake.csv"
    path.write_bytes(content)
    result = CliRunner().invoke(
        app, ["discretize", str(path), "--bounds", BOUNDS, "--cell-size", "5", "-o", str(tmp_path / "m.json")]
    )
    assert result.exit_code == 2, result.output
    assert fragment in " ".join(result.output.split()) and "Traceback" not in result.output
    assert not (tmp_path / "m.json").exists()


def test_an_unknown_delimiter_is_refused(tmp_path):
    path = tmp_path / "lake.csv"
    path.write_text("0,1\n1,1\n")
    result = CliRunner().invoke(
        app,
        [
            "discretize",
            str(path),
            "--bounds",
            BOUNDS,
            "--cell-size",
            "5",
            "-o",
            str(tmp_path / "m.json"),
            "--delimiter",
            "|",
        ],
    )
    assert result.exit_code == 2 and "allowed: ',', ';', 'tab', 'space'" in result.output


@pytest.mark.parametrize("preview", [True, False], ids=["with-preview", "no-preview"])
def test_discretize_into_a_place_that_cannot_be_written_gets_one_sentence(preview, tmp_path):
    mask = tmp_path / "lake.csv"
    mask.write_text("\n".join(",".join(map(str, row)) for row in np.ones((6, 6), int)) + "\n")
    args = ["discretize", str(mask), "--bounds", BOUNDS, "--cell-size", "20", "-o", "/proc/lake.json"]
    result = CliRunner().invoke(app, args + ([] if preview else ["--no-preview"]))
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert ("cannot write preview" if preview else "cannot write map") in message
    assert "Traceback" not in result.output


def test_map_show_into_a_place_that_cannot_be_written_gets_one_sentence():
    result = CliRunner().invoke(app, ["map", "show", str(LAKE), "--output", "/proc/lake.png"])
    assert result.exit_code == 2 and "cannot write preview '/proc/lake.png'" in result.output

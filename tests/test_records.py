"""Run-directory CSVs: the text the mission writes is what the csv module would write."""

import csv
import io

import numpy as np

from guadal_cli.records import _CsvStream, fmt


def test_rows_are_written_as_the_csv_module_writes_them_and_flushed(tmp_path):
    rows = [
        [0, np.int64(12), 3.5, np.float64(1 / 3), None, True, False, "plan", "", "gps"],
        [1, 2, float("nan"), float("inf"), -0.0, 1e20, 12345678901, np.float32(0.1), "  a b ", 7],
        ["a,b", 'say "hi"', "two\nlines", "x", "y", "z", 1, 2, 3, 4],  # exported text cells
    ]
    path = tmp_path / "t.csv"
    stream = _CsvStream(path, ["step", "a,b", 'q"', "d", "e", "f", "g", "h", "i", "j"])
    stream.write(rows[:1])
    assert path.read_text().count("\n") == 2  # flushed: readable while the run goes on
    stream.write(iter(rows[1:]))
    stream.write([])
    assert stream.rows_written == 3
    stream.close()
    expected = io.StringIO()
    writer = csv.writer(expected, lineterminator="\n")
    writer.writerow(["step", "a,b", 'q"', "d", "e", "f", "g", "h", "i", "j"])
    for row in rows:
        writer.writerow([fmt(v) for v in row])
    assert path.read_text(encoding="utf-8") == expected.getvalue()
    assert list(csv.reader(io.StringIO(path.read_text())))[3][:3] == ["a,b", 'say "hi"', "two\nlines"]

"""docs/python-api.md runs as written: its python blocks, in order, in one namespace."""

from __future__ import annotations

import re

from support import ROOT

DOC = ROOT / "docs" / "python-api.md"


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(first line number, code)`` of every fenced python block."""
    return [
        (text[: m.start(1)].count("\n") + 1, m.group(1))
        for m in re.finditer(r"^```python\n(.*?)^```$", text, flags=re.S | re.M)
    ]


def test_every_python_block_of_the_python_api_page_runs(tmp_path, monkeypatch):
    blocks = python_blocks(DOC.read_text())
    assert len(blocks) >= 6  # the paper's three listings, the model, Episode and its invalid targets
    monkeypatch.chdir(tmp_path)  # the page writes its map and ground truth beside itself
    namespace: dict = {"__name__": "python_api_doc"}
    try:
        for line, code in blocks:
            # a failure's traceback names the page and the line of the block
            exec(compile("\n" * (line - 1) + code, str(DOC), "exec"), namespace)
    finally:  # a block that failed midway must not leave boats, bridges or a broker behind
        if "remote" in namespace:
            namespace["remote"].close()
        if "stack" in namespace:
            namespace["stack"].down()

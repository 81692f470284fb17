"""The measured tables in the docs are what the code gives today (docs/generate_tables.py)."""

import importlib.util
import sys

from support import ROOT


def load_generator():
    spec = importlib.util.spec_from_file_location("generate_tables", ROOT / "docs" / "generate_tables.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_documented_tables_match_fresh_runs(capsys):
    generator = load_generator()
    assert generator.main(["--check"]) == 0, capsys.readouterr().out


def test_a_changed_figure_is_caught_and_regenerated(tmp_path, monkeypatch):
    generator = load_generator()
    (tmp_path / "missions").symlink_to(ROOT / "missions")
    (tmp_path / "maps").symlink_to(ROOT / "maps")
    page = tmp_path / "page.md"
    page.write_text(
        "before\n<!-- generated: small (test) -->\n| oil | IoU |\n|---|---|\n| `frontier` | 0.850 |\n"
        "<!-- end generated: small -->\nafter\n"
    )
    table = generator.Table(
        key="small",
        page="page.md",
        mission="missions/oil_spill_frontier.yaml",
        title="oil",
        seeds=(1,),
        rows=(("`frontier`", {"type": "frontier"}),),
        columns=(generator.Column("IoU", "iou", 3),),
    )
    monkeypatch.setattr(generator, "ROOT", tmp_path)
    monkeypatch.setattr(generator, "TABLES", (table,))
    assert generator.main(["--check"]) == 1  # 0.850 is not what frontier gives
    assert generator.main([]) == 0
    text = page.read_text()
    assert text.startswith("before\n") and text.endswith("<!-- end generated: small -->\nafter\n")
    assert "| `frontier` | 0.885 |" in text and "0.850" not in text
    assert generator.main(["--check"]) == 0

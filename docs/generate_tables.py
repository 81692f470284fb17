"""Regenerate the measured tables of the docs from real runs of the example missions.

    python docs/generate_tables.py            # run the missions, rewrite the tables in place
    python docs/generate_tables.py --check    # run them, exit 1 if a documented figure differs

Each table lives between ``<!-- generated: KEY ... -->`` and ``<!-- end generated: KEY -->`` in
its page; nothing outside those markers is touched. A table row is one algorithm on one example
mission, each cell the mean over the listed seeds of a run's final metric. The test suite runs
``--check`` (tests/test_doc_tables.py), so a change that moves a documented figure fails until
the page is regenerated.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Column:
    title: str
    metric: str
    digits: int  # decimals shown


@dataclass(frozen=True)
class Table:
    key: str
    page: str  # relative to the repository
    mission: str  # relative to the repository
    title: str  # the first header cell
    seeds: tuple[int, ...]
    rows: tuple[tuple[str, dict], ...]  # (label, the mission's algorithm section)
    columns: tuple[Column, ...]


TABLES = (
    Table(
        key="trash",
        page="docs/environments.md",
        mission="missions/trash_detection_greedy.yaml",
        title="trash (`trash_detection_greedy.yaml`)",
        seeds=(1, 2, 3),
        rows=(
            ("`detection_greedy`, nearest", {"type": "detection_greedy", "strategy": "nearest"}),
            ("`detection_greedy`, densest", {"type": "detection_greedy", "strategy": "densest"}),
            ("`lawnmower`", {"type": "lawnmower"}),
            ("`frontier`", {"type": "frontier"}),
            ("`random`", {"type": "random"}),
        ),
        columns=(
            Column("fraction collected", "fraction_collected", 2),
            Column("m per item", "distance_per_item", 0),
            Column("time to 50% (s)", "time_to_50pct", 0),
            Column("time to 90% (s)", "time_to_90pct", 0),
        ),
    ),
    Table(
        key="oil_spill",
        page="docs/environments.md",
        mission="missions/oil_spill_frontier.yaml",
        title="oil (`oil_spill_frontier.yaml`)",
        seeds=(1, 2, 3),
        rows=(
            ("`detection_greedy`", {"type": "detection_greedy"}),
            ("`frontier`", {"type": "frontier"}),
            ("`lawnmower`", {"type": "lawnmower"}),
            ("`random`", {"type": "random"}),
        ),
        columns=(
            Column("IoU", "iou", 3),
            Column("detection coverage", "detection_coverage", 3),
            Column("concentration RMSE", "concentration_rmse", 4),
            Column("observed", "observed_fraction", 2),
        ),
    ),
    Table(
        key="rl",
        page="docs/rl.md",
        mission="missions/lake_policy.yaml",
        title="paper lake, 3 boats (`lake_policy.yaml`)",
        seeds=(1, 2, 3),
        rows=(
            (
                "`policy` (`examples/rl/lake_policy.onnx`)",
                {"type": "policy", "model": str(ROOT / "examples" / "rl" / "lake_policy.onnx")},
            ),
            ("`greedy`", {"type": "greedy"}),
            ("`random`", {"type": "random", "mode": "sequential"}),
        ),
        columns=(
            Column("final mean std", "mean_std", 4),
            Column("final max std", "max_std", 3),
            Column("final RMSE", "rmse", 4),
            Column("coverage", "coverage", 2),
        ),
    ),
)


def final_metrics(mission_path: Path, algorithm: dict, seed: int, workdir: Path) -> dict[str, float]:
    """Run the mission with another algorithm section and seed; its final metrics row."""
    from guadal_cli.mission import prepare
    from guadal_cli.runner import MissionRunner

    mission = yaml.safe_load(mission_path.read_text())
    mission["algorithm"] = dict(algorithm)
    mission["seed"] = seed
    mission["map"] = str((mission_path.parent / mission["map"]).resolve())
    name = f"{mission['name']}-{'-'.join(Path(str(v)).name for v in algorithm.values())}-{seed}"
    path = workdir / f"{name}.yaml"
    path.write_text(yaml.safe_dump(mission, sort_keys=False))
    return MissionRunner(prepare(path), output=workdir / name).run().final_metrics


def cell(values: list[float], digits: int) -> str:
    """The mean, or a dash where a seed never reached the metric (NaN)."""
    if any(math.isnan(v) for v in values):
        return "—"
    return f"{sum(values) / len(values):.{digits}f}"


def render(table: Table, workdir: Path) -> str:
    lines = [
        "| " + " | ".join([table.title, *(c.title for c in table.columns)]) + " |",
        "|" + "---|" * (len(table.columns) + 1),
    ]
    for label, algorithm in table.rows:
        runs = [final_metrics(ROOT / table.mission, algorithm, s, workdir) for s in table.seeds]
        cells = [cell([float(r[c.metric]) for r in runs], c.digits) for c in table.columns]
        lines.append("| " + " | ".join([label, *cells]) + " |")
    return "\n".join(lines) + "\n"


def find_block(text: str, table: Table) -> re.Match:
    key = re.escape(table.key)
    found = re.search(rf"<!-- generated: {key}\b[^\n]*-->\n(.*?)<!-- end generated: {key} -->", text, re.S)
    if found is None:
        raise SystemExit(f"{table.page} has no '<!-- generated: {table.key} ... -->' block.")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 where the docs differ")
    parser.add_argument("--only", help="comma-separated table keys (default: all)")
    args = parser.parse_args(argv)
    chosen = [t for t in TABLES if not args.only or t.key in args.only.split(",")]
    stale = []
    with tempfile.TemporaryDirectory() as tmp:
        for table in chosen:
            page = ROOT / table.page
            fresh = render(table, Path(tmp))
            text = page.read_text()
            found = find_block(text, table)
            if fresh == found.group(1):
                continue
            stale.append(table.key)
            if args.check:
                sys.stdout.write(f"{table.page}: table '{table.key}' differs from a fresh run; now:\n{fresh}")
            else:
                page.write_text(text[: found.start(1)] + fresh + text[found.end(1) :])
                sys.stdout.write(f"{table.page}: table '{table.key}' regenerated\n")
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())

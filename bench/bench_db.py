"""The mission database's cost: a paper-scale sim mission with the database off, SQLite and PostgreSQL,
and the import of 100 run directories in rows per second.

1. Whole mission: `missions/lake_greedy.yaml` (3 boats, 925 m each, 351-node lake) run in this
   process with `database=none`, SQLite (one file) and PostgreSQL (one database), interleaved,
   `--repeats` times each after an untimed warm-up of each (imports, caches, the schema). Timed
   from `MissionRunner.run()` until it returns, the writer's final drain included. The same
   mission is also timed as a user runs it: `guadal run` as a new process, imports included.
2. Import: 100 run directories (copies of 4 example runs, each with its own run_id) imported
   into a fresh SQLite file and a fresh PostgreSQL database; rows per second.

    OMP_NUM_THREADS=1 python bench/bench_db.py [--repeats 5] [--pg postgresql://postgres@127.0.0.1/test]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from guadal_cli.db.engine import make_engine, upgrade  # noqa: E402
from guadal_cli.db.ingest import import_run  # noqa: E402
from guadal_cli.mission import prepare  # noqa: E402
from guadal_cli.runner import MissionRunner  # noqa: E402

MISSION = ROOT / "missions" / "lake_greedy.yaml"


class PgServer:
    def __init__(self, admin_url: str):
        import psycopg

        self.admin_url = admin_url
        self.psycopg = psycopg
        self.names = []

    def fresh(self) -> str:
        name = f"guadal_bench_{os.getpid()}_{uuid.uuid4().hex[:8]}"
        with self.psycopg.connect(self.admin_url, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        self.names.append(name)
        return self.admin_url.rsplit("/", 1)[0] + "/" + name

    def drop_all(self) -> None:
        with self.psycopg.connect(self.admin_url, autocommit=True) as conn:
            for name in self.names:
                conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def run_once(folder: Path, url: str) -> float:
    prep = prepare(MISSION)
    out = folder / f"run-{uuid.uuid4().hex[:8]}"
    runner = MissionRunner(prep, output=out, database=url)
    t0 = time.perf_counter()
    result = runner.run()
    for sink in runner.recorder.sinks:
        sink.close()  # until the rows are in the database
    elapsed = time.perf_counter() - t0
    assert result.status == "complete"
    return elapsed


def cli_once(folder: Path, url: str) -> float:
    out = folder / f"cli-{uuid.uuid4().hex[:8]}"
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "guadal_cli", "run", str(MISSION), "-o", str(out), "--db", url, "--quiet"],
        check=True,
    )
    return time.perf_counter() - t0


def whole_mission(folder: Path, pg: PgServer | None, repeats: int) -> list[dict]:
    engines = {"off": "none", "sqlite": f"sqlite:///{folder / 'missions.db'}"}
    if pg is not None:
        engines["postgresql"] = pg.fresh()
    times = {name: [] for name in engines}
    cli_times = {name: [] for name in engines}
    for url in engines.values():
        run_once(
            folder, url
        )  # warm-up; it also creates the schema, as the first mission beside the runs does
    for _ in range(repeats):
        for name, url in engines.items():
            times[name].append(run_once(folder, url))
            cli_times[name].append(cli_once(folder, url))
    base, cli_base = statistics.median(times["off"]), statistics.median(cli_times["off"])
    return [
        {
            "database": name,
            "mission_s": statistics.median(times[name]),
            "ratio": statistics.median(times[name]) / base,
            "cli_s": statistics.median(cli_times[name]),
            "cli_ratio": statistics.median(cli_times[name]) / cli_base,
        }
        for name in engines
    ]


def make_runs(folder: Path, count: int) -> list[Path]:
    sources = []
    for name in ("lake_greedy", "lake_lawnmower", "oil_spill_frontier", "trash_detection_greedy"):
        mission = yaml.safe_load((ROOT / "missions" / f"{name}.yaml").read_text())
        mission["map"] = str(ROOT / "maps" / mission["map"].split("/")[-1])
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(mission))
        out = folder / "sources" / name
        MissionRunner(prepare(path), output=out, database="none").run()
        sources.append(out)
    runs = []
    for i in range(count):
        target = folder / "hundred" / f"run-{i:03d}"
        shutil.copytree(sources[i % len(sources)], target)
        manifest = json.loads((target / "manifest.json").read_text())
        manifest["run_id"] = uuid.uuid4().hex
        (target / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
        runs.append(target)
    return runs


def import_speed(runs: list[Path], url: str) -> dict:
    engine = make_engine(url, writer=True)
    upgrade(engine)
    t0 = time.perf_counter()
    rows = sum(import_run(engine, run).new_rows for run in runs)
    elapsed = time.perf_counter() - t0
    engine.dispose()
    return {"rows": rows, "seconds": elapsed, "rows_per_s": rows / elapsed}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--pg", default="postgresql://postgres@127.0.0.1:5432/test")
    parser.add_argument("--no-pg", action="store_true")
    args = parser.parse_args()
    pg = None if args.no_pg else PgServer(args.pg)
    print(
        f"{platform.python_version()}, {os.cpu_count()} cores, OMP/OpenBLAS/MKL threads = "
        f"{os.environ['OMP_NUM_THREADS']}, load average {os.getloadavg()[0]:.1f}"
    )
    with tempfile.TemporaryDirectory(prefix="guadal-bench-db-") as tmp:
        folder = Path(tmp)
        try:
            print("\n| database | mission (in process), s | ratio | `guadal run` process, s | ratio |")
            print("|---|---|---|---|---|")
            for r in whole_mission(folder, pg, args.repeats):
                print(
                    f"| {r['database']} | {r['mission_s']:.3f} | {r['ratio']:.2f}× | "
                    f"{r['cli_s']:.2f} | {r['cli_ratio']:.2f}× |"
                )
            runs = make_runs(folder, 100)
            print("\n| import of 100 runs into | rows | seconds | rows/s |")
            print("|---|---|---|---|")
            targets = {"sqlite": f"sqlite:///{folder / 'import.db'}"}
            if pg is not None:
                targets["postgresql"] = pg.fresh()
            for name, url in targets.items():
                r = import_speed(runs, url)
                print(f"| {name} | {r['rows']} | {r['seconds']:.2f} | {r['rows_per_s']:,.0f} |")
        finally:
            if pg is not None:
                pg.drop_all()


if __name__ == "__main__":
    main()

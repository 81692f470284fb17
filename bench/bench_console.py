"""The web console under a busy fleet: its CPU, and how long a GPS fix takes to reach the browser.

A real recorder with the real database sink writes a 10-boat run into SQLite as a remote level
would: every boat's GPS fix 5 times a second (50 rows/s), one step (plan rows, samples, metrics)
a second. ``guadal serve`` runs as its own process on that database.

- Baseline, same run: no page open. The console's CPU; and the record -> database latency, seen
  by a Python reader polling the database every 50 ms (what any reader can do at best).
- Measured: one headless Chromium on the run's page. The console's CPU; and the record ->
  browser latency: the page's own event stream is wrapped to note when each fix arrives.

The recorder stamps each fix with its wall-clock time as ``time_s``; browser and recorder share
the machine's clock.

    python bench/bench_console.py [--seconds 20]      # prints a markdown table
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "web"))

from console_support import browser  # noqa: E402
from support import base_mission  # noqa: E402

from guadal_cli.db import queries  # noqa: E402
from guadal_cli.db.writer import DatabaseWriter  # noqa: E402
from guadal_cli.mission import prepare  # noqa: E402
from guadal_cli.records import RunRecorder  # noqa: E402
from guadal_cli.runner import MissionRunner, metric_columns  # noqa: E402

BOATS = 10
GPS_HZ = 5.0
TICKS = os.sysconf("SC_CLK_TCK")

WRAP_EVENTSOURCE = """
window.__latencies = [];
const Original = window.EventSource;
window.EventSource = function (url, options) {
  const source = new Original(url, options);
  source.addEventListener("update", (e) => {
    const now = Date.now() / 1000;
    for (const r of JSON.parse(e.data).track || []) {
      if (r.source === "gps" && r.time_s >= window.__from) window.__latencies.push(now - %f - r.time_s);
    }
  });
  return source;
};
window.__from = Infinity;
"""


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


class FleetWriter(threading.Thread):
    """10 boats wandering on the lake's nodes: GPS at 5 Hz, a step every second."""

    def __init__(self, recorder: RunRecorder, graph, t0: float, seconds: float):
        super().__init__(daemon=True)
        self.recorder, self.graph, self.t0, self.seconds = recorder, graph, t0, seconds
        self.rng = np.random.default_rng(1)
        self.nodes = list(self.rng.choice(graph.n_nodes, BOATS, replace=False))
        self.columns = recorder.metrics.columns

    def run(self) -> None:
        g, step, tick = self.graph, 0, 0
        start = time.monotonic()
        while time.monotonic() - start < self.seconds:
            now = time.time() - self.t0
            if tick % int(GPS_HZ) == 0:
                step += 1
                self.nodes = [int(self.rng.choice(g.neighbors(n))) for n in self.nodes]
                plan = [
                    (step, v, n, g.rows[n], g.cols[n], g.lat[n], g.lon[n], 0.0, "plan", now)
                    for v, n in enumerate(self.nodes)
                ]
                samples = [
                    (step, v, n, g.lat[n], g.lon[n], float(self.rng.random()), now)
                    for v, n in enumerate(self.nodes)
                ]
                metrics = {c: 0.0 for c in self.columns} | {"step": step, "time_s": now}
                self.recorder.write_step(step, metrics, plan, samples)
            fixes = [
                (
                    step,
                    v,
                    "",
                    "",
                    "",
                    g.lat[n] + self.rng.normal(0, 2e-6),
                    g.lon[n] + self.rng.normal(0, 2e-6),
                    "",
                    "gps",
                    time.time() - self.t0,
                )
                for v, n in enumerate(self.nodes)
            ]
            self.recorder.write_track(fixes)
            tick += 1
            time.sleep(max(0.0, start + tick / GPS_HZ - time.monotonic()))


def database_latencies(engine, run_id: int, t0: float, seconds: float) -> list[float]:
    """A Python reader polling for new GPS rows every 50 ms: record -> visible in the database."""
    after = queries.latest_ids(engine, run_id)["trajectory"]
    out, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        for r in queries.trajectory(engine, run_id, after):
            after = max(after, r["id"])
            if r["source"] == "gps":
                out.append(time.time() - t0 - r["time_s"])
        time.sleep(0.05)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each phase")
    args = parser.parse_args()
    phase = args.seconds
    tmp = Path(tempfile.mkdtemp(prefix="guadal-bench-console-"))
    url = f"sqlite:///{tmp / 'guadal.db'}"
    mission = base_mission(
        fleet={"vehicles": BOATS, "initial_positions": "auto", "max_distance": 1e6, "speed": 0.5}
    )
    mission_path = tmp / "mission.yaml"
    import yaml

    mission_path.write_text(yaml.safe_dump(mission))
    prep = prepare(mission_path)
    runner = MissionRunner(prep, output=tmp / "run", database=url)
    t0 = time.time()
    recorder = RunRecorder(
        runner.output,
        prep.resolved_dict(),
        runner._manifest(),
        metric_columns(BOATS, runner.environment.metric_names),
        sinks=[DatabaseWriter(url)],
    )
    writer = FleetWriter(recorder, prep.graph, t0, 3 * phase + 30)
    writer.start()
    serve = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "serve", "--db", url, "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    console = re.search(r"http://\S+/", serve.stdout.readline()).group(0)
    engine = queries.open_database(url)
    run_id = None
    while run_id is None:
        found = queries.list_runs(engine)
        run_id = found[0]["id"] if found else None
        time.sleep(0.1)
    time.sleep(2.0)

    cpu0, wall0 = cpu_seconds(serve.pid), time.monotonic()
    db_lat = database_latencies(engine, run_id, t0, phase)
    idle_cpu = (cpu_seconds(serve.pid) - cpu0) / (time.monotonic() - wall0)

    driver = browser()
    driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": WRAP_EVENTSOURCE % t0})
    driver.get(f"{console}runs/{run_id}")
    time.sleep(3.0)  # the page loads, draws the history, then follows
    driver.execute_script(f"window.__from = {time.time() - t0};")
    cpu0, wall0 = cpu_seconds(serve.pid), time.monotonic()
    time.sleep(phase)
    page_cpu = (cpu_seconds(serve.pid) - cpu0) / (time.monotonic() - wall0)
    browser_lat = driver.execute_script("return window.__latencies;")
    driver.quit()
    serve.terminate()
    serve.wait()
    writer.join()
    recorder.finish("complete")

    db_ms, page_ms = np.array(db_lat) * 1000, np.array(browser_lat) * 1000
    print(
        f"{dt.date.today()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"{BOATS} boats x {GPS_HZ:g} Hz GPS, {phase:g} s per phase, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}\n"
    )
    print("| | fixes seen | p50 ms | p95 ms | console CPU (one core) |")
    print("|---|---|---|---|---|")
    print(
        f"| baseline: no page; record -> database (Python reader, 50 ms poll) | {len(db_ms)} | "
        f"{np.percentile(db_ms, 50):.0f} | {np.percentile(db_ms, 95):.0f} | {idle_cpu:.1%} |"
    )
    print(
        f"| one page open; record -> browser | {len(page_ms)} | {np.percentile(page_ms, 50):.0f} | "
        f"{np.percentile(page_ms, 95):.0f} | {page_cpu:.1%} |"
    )
    print(
        f"\nratio page / baseline: p50 {np.percentile(page_ms, 50) / np.percentile(db_ms, 50):.2f}x, "
        f"p95 {np.percentile(page_ms, 95) / np.percentile(db_ms, 95):.2f}x"
    )


if __name__ == "__main__":
    main()

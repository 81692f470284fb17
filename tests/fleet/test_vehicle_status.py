"""At sitl, vehicles.csv holds what each boat's bridge reports, also while a hop is under way."""

from __future__ import annotations

import csv
from collections import Counter

import yaml
from support import base_mission

from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def test_boats_report_their_state_after_every_hop_and_while_sailing(tmp_path):
    # slow boats (2 s of wall time per 5 m hop): a hop outlasts the one-second status tick
    mission = base_mission(backend={"level": "sitl", "launch": True, "speedup": 5})
    mission["fleet"].update(vehicles=2, max_distance=10.0)
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(mission))
    result = MissionRunner(prepare(tmp_path / "m.yaml"), output=tmp_path / "run", database="none").run()
    assert result.status == "complete"
    with open(tmp_path / "run" / "vehicles.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["vehicle"] for r in rows} == {"0", "1"}
    for r in rows:  # the emulated autopilot, as its bridge reports it
        assert r["mode"] == "GUIDED" and r["armed"] == "1" and r["fault"] == ""
        assert 0 <= float(r["battery"]) <= 100 and 0 <= float(r["link_age_s"]) < 2
    # a row per boat at every step (hops take seconds of mission time), and more while sailing
    per_step = Counter((r["step"], r["vehicle"]) for r in rows)
    assert set(per_step) == {(str(s), str(v)) for s in range(result.steps + 1) for v in (0, 1)}
    assert max(per_step.values()) > 1
    # never faster than once a second of mission time per boat
    for v in ("0", "1"):
        times = [float(r["time_s"]) for r in rows if r["vehicle"] == v]
        assert all(b - a >= 1.0 - 1e-6 for a, b in zip(times, times[1:]))

"""Helpers for the report tests: real missions run in-process, and a fleet that reports GPS fixes.

``GpsTrackBackend`` is a backend plugin (named ``support.report:GpsTrackBackend`` in a mission)
that moves exactly like the ``sim`` level and also reports a GPS fix halfway along every hop and
one at every node, as a remote fleet does. It lets the report's planned-versus-GPS figure and
off-track columns be tested on a run the real runner wrote.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from guadal_cli.fleet.local import LocalFleet, SimBackend
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner
from support import base_mission


class GpsLocalFleet(LocalFleet):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._fixes: list[dict] = []

    def move(self, targets):
        before = dict(self.positions)
        result = super().move(targets)
        g = self.graph
        for v, node in self.positions.items():
            if node != before[v]:
                a, b = before[v], node
                self._fixes.append(
                    {
                        "vehicle": v,
                        "lat": (g.lat[a] + g.lat[b]) / 2,
                        "lon": (g.lon[a] + g.lon[b]) / 2,
                        "time_s": self.mission_time,
                    }
                )
                self._fixes.append(
                    {"vehicle": v, "lat": g.lat[b], "lon": g.lon[b], "time_s": self.mission_time}
                )
        return result

    def track_rows(self):
        rows, self._fixes = self._fixes, []
        return rows


class GpsTrackBackend(SimBackend):
    def make_fleet(self, *, graph, fleet_config, sensor, mission=None):
        return GpsLocalFleet(
            graph, fleet_config.vehicles, fleet_config.max_distance, fleet_config.speed, sensor
        )


def run_mission(folder: Path, name: str, seed: int, **overrides) -> Path:
    """Run a small real mission into ``folder/name`` and return the run directory."""
    mission = base_mission(name=name, seed=seed, **overrides)
    mission["fleet"] = {**mission["fleet"], "vehicles": 2, "max_distance": 100.0}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}-{seed}.yaml"
    path.write_text(yaml.safe_dump(mission, sort_keys=False))
    out = folder / f"{name}-{seed}"
    MissionRunner(prepare(path), output=out).run()
    return out


def invoke(*args):
    """``guadal ...`` in this process (the real app, without paying a start-up per call)."""
    from typer.testing import CliRunner

    from guadal_cli.app import app

    return CliRunner().invoke(app, [str(a) for a in args])

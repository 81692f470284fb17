"""The console's JSON API and downloads over both database engines, on a finished mission."""

from __future__ import annotations

import csv
import io
import json
import urllib.request
import zipfile

from console_support import Console
from support import base_mission, run_cli


def test_a_finished_run_is_listed_streamed_and_downloadable(db_url, tmp_path, write_mission):
    mission = write_mission(base_mission(output={"database": db_url}))
    proc = run_cli("run", mission, "-o", tmp_path / "run", "-q")
    assert proc.returncode == 0, proc.stderr
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    console = Console(db_url)
    try:
        status, body = console.call("/api/runs?status=complete")
        assert status == 200 and [r["name"] for r in body["runs"]] == ["t"]
        run_id = body["runs"][0]["id"]
        assert console.call("/api/runs?status=failed")[1] == {"runs": []}

        status, info = console.call(f"/api/runs/{run_id}")
        assert status == 200 and info["run"]["steps"] == manifest["steps"]
        assert len(info["grid"]["nodes"]) == manifest["map"]["water_nodes"]

        # the stream's first event holds the whole run so far; its id resumes it
        with urllib.request.urlopen(f"{console.url}/api/runs/{run_id}/stream", timeout=10) as stream:
            lines = []
            while not (lines and lines[-1] == ""):
                lines.append(stream.readline().decode().rstrip("\n"))
        event = dict(line.split(": ", 1) for line in lines if ": " in line)
        data = json.loads(event["data"])
        assert event["event"] == "update" and event["id"].count(".") == 6
        assert [s["step"] for s in data["steps"]] == list(range(manifest["steps"] + 1))
        assert len(data["measurements"]) == manifest["final_metrics"]["samples"]
        assert set(data["fields"][-1]["values"]) >= {"mean", "std"}
        # each boat's state and each decision's targets, as the run directory has them
        with open(tmp_path / "run" / "targets.csv", newline="") as fh:
            targets = [(int(r["step"]), int(r["vehicle"]), int(r["node"])) for r in csv.DictReader(fh)]
        assert [(t["step"], t["vehicle"], t["node"]) for t in data["targets"]] == targets
        assert {t["vehicle"] for t in data["targets"]} == {0, 1, 2}
        with open(tmp_path / "run" / "vehicles.csv", newline="") as fh:
            assert len(data["vehicles"]) == sum(1 for _ in csv.DictReader(fh))
        last = {v["vehicle"]: v for v in data["vehicles"]}
        assert sorted(last) == [0, 1, 2]
        for v, row in last.items():  # simulated boats: GUIDED and armed; no battery, no link to age
            reported = (row["mode"], row["armed"], row["battery"], row["link_age_s"])
            assert reported == ("GUIDED", True, None, None)
            assert abs(row["remaining"] - (120.0 - manifest["final_metrics"][f"distance_v{v}"])) < 1e-6

        status, raw = console.call(f"/api/runs/{run_id}/download/csv")
        names = zipfile.ZipFile(io.BytesIO(raw)).namelist()
        assert status == 200 and {n.split("/")[-1] for n in names} >= {"metrics.csv", "trajectory.csv"}
        for name in ("metrics.csv", "vehicles.csv", "targets.csv"):
            inside = [n for n in names if n.endswith(name)][0]
            exported = zipfile.ZipFile(io.BytesIO(raw)).read(inside)
            assert exported == (tmp_path / "run" / name).read_bytes()
        status, raw = console.call(f"/api/runs/{run_id}/download/geojson")
        assert status == 200 and json.loads(raw)["type"] == "FeatureCollection"
        status, raw = console.call(f"/api/runs/{run_id}/download/plan")
        assert status == 200 and any(n.endswith(".plan") for n in zipfile.ZipFile(io.BytesIO(raw)).namelist())
        status, body = console.call(f"/api/runs/{run_id}/download/shapefile")
        assert (
            status == 404
            and body["error"] == "no download 'shapefile'; downloads are csv, geojson, kml, plan."
        )
        assert console.call("/api/runs/999")[0] == 404
    finally:
        console.stop()

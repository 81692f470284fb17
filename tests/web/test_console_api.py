"""The console's JSON API and downloads over both database engines, on a finished mission."""

from __future__ import annotations

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
        assert event["event"] == "update" and event["id"].count(".") == 4
        assert [s["step"] for s in data["steps"]] == list(range(manifest["steps"] + 1))
        assert len(data["measurements"]) == manifest["final_metrics"]["samples"]
        assert set(data["fields"][-1]["values"]) >= {"mean", "std"}

        status, raw = console.call(f"/api/runs/{run_id}/download/csv")
        names = zipfile.ZipFile(io.BytesIO(raw)).namelist()
        assert status == 200 and {n.split("/")[-1] for n in names} >= {"metrics.csv", "trajectory.csv"}
        metrics = [n for n in names if n.endswith("metrics.csv")][0]
        exported = zipfile.ZipFile(io.BytesIO(raw)).read(metrics)
        assert exported == (tmp_path / "run" / "metrics.csv").read_bytes()
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

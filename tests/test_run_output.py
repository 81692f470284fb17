"""What `guadal run` tells people and scripts: the summary, --quiet, --run-dir, live progress."""

import csv
import json
import re
import signal
import subprocess
import sys
import time

from support import ROOT, base_mission, run_cli


def test_quiet_prints_only_the_run_directory(tmp_path, write_mission):
    mission = write_mission(base_mission())
    out = tmp_path / "r"
    proc = run_cli("run", mission, "--run-dir", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == f"{out}\n" and proc.stderr == ""
    assert (out / "manifest.json").is_file()
    # without --run-dir, the printed path is the new directory inside output.directory
    proc = run_cli("run", mission, "-q")
    printed = proc.stdout.strip()
    assert proc.returncode == 0 and printed.startswith(str(tmp_path / "runs"))
    assert json.loads((tmp_path / printed / "manifest.json").read_text())["status"] == "complete"


def test_output_still_names_the_run_directory_with_a_deprecation_note(tmp_path, write_mission):
    mission = write_mission(base_mission())
    proc = run_cli("run", mission, "--output", tmp_path / "old", "-q")
    assert proc.returncode == 0 and (tmp_path / "old" / "metrics.csv").is_file()
    assert "--output is deprecated" in proc.stderr and "--run-dir" in proc.stderr
    proc = run_cli("run", mission, "--output", tmp_path / "a", "--run-dir", tmp_path / "b")
    assert proc.returncode == 2 and "give the run directory once" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_summary_numbers_are_rounded_for_people(tmp_path, write_mission):
    mission = write_mission(base_mission(fleet={"vehicles": 2, "max_distance": 233.3, "speed": 0.7}))
    proc = run_cli("run", mission, "--run-dir", tmp_path / "r")
    assert proc.returncode == 0, proc.stderr
    with open(tmp_path / "r" / "metrics.csv", newline="") as fh:
        last = list(csv.DictReader(fh))[-1]
    assert len(last["total_distance"].replace(".", "")) > 4  # the file keeps full precision...
    assert not re.search(r"\d\.\d{5,}|\d{5,}\.\d", proc.stdout)  # ...the summary does not
    assert f"{float(last['rmse']):.4g}" in proc.stdout
    assert f"run directory: {tmp_path / 'r'}" in proc.stdout


def test_manifest_reports_progress_while_running(tmp_path, write_mission):
    mission = write_mission(
        base_mission(map=str(ROOT / "maps" / "reservoir.json"), fleet={"vehicles": 2, "max_distance": 100000})
    )
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(mission), "--run-dir", str(out), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        seen = None
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "manifest.json").exists():
                manifest = json.loads((out / "manifest.json").read_text())  # always whole: atomic rewrites
                if manifest["status"] == "running" and (manifest.get("progress") or {}).get("steps", 0) > 0:
                    seen = manifest
                    break
            time.sleep(0.05)  # polling for the condition, not waiting a fixed time
        assert seen is not None, "the running manifest never reported progress"
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    progress = seen["progress"]
    with open(out / "metrics.csv", newline="") as fh:
        rows = {int(r["step"]): r for r in csv.DictReader(fh)}
    row = rows[progress["steps"]]  # the progress describes a step the CSV holds
    assert seen["steps"] == progress["steps"] and progress["updated_at"]
    assert progress["mission_time_s"] == round(float(row["time_s"]), 3)
    assert progress["total_distance_m"] == round(float(row["total_distance"]), 3)
    assert progress["distance_m"] == {
        "0": round(float(row["distance_v0"]), 3),
        "1": round(float(row["distance_v1"]), 3),
    }
    final = json.loads((out / "manifest.json").read_text())
    assert final["status"] == "interrupted" and final["progress"]["steps"] == max(rows)

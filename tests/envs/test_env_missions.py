"""trash and oil_spill as users run them: the example missions, validation, determinism, sitl."""

import csv

import pytest
import yaml
from support import LAKE, ROOT, run_cli
from typer.testing import CliRunner

from guadal_cli.app import app
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner

CSVS = ("metrics.csv", "trajectory.csv", "measurements.csv", "fields.csv")


def read_csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def example(name, **changes) -> dict:
    mission = yaml.safe_load((ROOT / "missions" / f"{name}.yaml").read_text())
    mission["map"] = str(LAKE)
    mission.pop("output", None)
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            mission[section][field] = value
        else:
            mission[section] = value
    return mission


def test_the_same_mission_twice_gives_byte_identical_csvs(tmp_path):
    """Drift with a random walk, detections and pick-ups: all of it follows the seed."""
    mission = ROOT / "missions" / "trash_detection_greedy.yaml"
    for run in ("a", "b"):
        proc = run_cli("run", mission, "--output", tmp_path / run, "--quiet")
        assert proc.returncode == 0, proc.stderr
    for name in CSVS:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    rows = read_csv(tmp_path / "a" / "metrics.csv")
    collected = [float(r["fraction_collected"]) for r in rows]
    assert collected == sorted(collected) and collected[0] < 0.2 and collected[-1] > 0.9
    assert float(rows[-1]["time_to_50pct"]) <= float(rows[-1]["time_to_90pct"]) <= float(rows[-1]["time_s"])
    total = float(rows[-1]["total_distance"])
    assert float(rows[-1]["distance_per_item"]) == pytest.approx(
        total / float(rows[-1]["items_collected"]), rel=1e-6
    )


def test_oil_spill_is_deterministic_too(tmp_path, write_mission):
    path = write_mission(example("oil_spill_detection_greedy", fleet__max_distance=200))
    for run in ("a", "b"):
        assert MissionRunner(prepare(path), output=tmp_path / run).run().status == "complete"
    for name in CSVS:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_iou_rises_as_frontier_exploration_uncovers_the_spill(tmp_path):
    proc = run_cli(
        "run", ROOT / "missions" / "oil_spill_frontier.yaml", "--output", tmp_path / "run", "--quiet"
    )
    assert proc.returncode == 0, proc.stderr
    rows = read_csv(tmp_path / "run" / "metrics.csv")
    observed = [float(r["observed_fraction"]) for r in rows]
    assert observed == sorted(observed) and observed[-1] == 1.0
    iou = [float(r["iou"]) for r in rows]
    early = iou[len(iou) // 10]
    assert iou[-1] > early + 0.3 and iou[-1] > 0.7
    fields = read_csv(tmp_path / "run" / "fields.csv")
    assert {"ground_truth", "concentration", "observed", "age", "evidence"} <= set(fields[0])


@pytest.mark.parametrize("env", ["trash", "oil_spill"])
@pytest.mark.parametrize("algorithm", ["greedy", "expected_improvement"])
def test_an_algorithm_needing_a_gp_is_refused_at_validation_in_one_sentence(env, algorithm, write_mission):
    base = "trash_lawnmower" if env == "trash" else "oil_spill_frontier"
    path = write_mission(example(base, algorithm={"type": algorithm}))
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 2
    message = " ".join(result.output.split())
    assert "Traceback" not in message and message.count(". ") == 0 and message.endswith(".")
    assert f"'{algorithm}' needs" in message and "std" in message and f"'{env}' does not provide" in message


@pytest.mark.parametrize("env", ["trash", "oil_spill"])
@pytest.mark.parametrize("algorithm", ["lawnmower", "random", "frontier", "detection_greedy"])
def test_baselines_and_new_algorithms_run_on_both(env, algorithm, tmp_path, write_mission):
    base = "trash_lawnmower" if env == "trash" else "oil_spill_frontier"
    path = write_mission(example(base, algorithm={"type": algorithm}, fleet__max_distance=120))
    result = MissionRunner(prepare(path), output=tmp_path / "run").run()
    assert result.status == "complete" and result.steps > 5
    last = result.final_metrics
    assert all(last[f"distance_v{v}"] <= 120 + 1e-6 for v in range(3))
    assert last["samples"] > 3 * 5


def test_new_algorithms_refused_on_gp_in_one_sentence(write_mission):
    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy.yaml").read_text())
    mission["map"] = str(LAKE)
    mission["algorithm"] = {"type": "frontier"}
    result = CliRunner().invoke(app, ["validate", str(write_mission(mission))])
    assert result.exit_code == 2
    message = " ".join(result.output.split())
    assert "'frontier' needs observed" in message and "'gp' does not provide" in message


def test_the_spill_advances_with_the_vehicles_clock_at_sitl_and_frontier_sends_the_same_targets(
    tmp_path, write_mission
):
    """Frontier reads only what has been observed, so its targets match sim's even though the
    spill, driven by the vehicles' own clock, evolves differently at sitl."""
    plans, times = {}, {}
    for level in ("sim", "sitl"):
        backend = {"level": "sim"} if level == "sim" else {"level": "sitl", "launch": True, "speedup": 200}
        path = write_mission(
            example("oil_spill_frontier", backend=backend, fleet__max_distance=40), name=f"{level}.yaml"
        )
        result = MissionRunner(prepare(path), output=tmp_path / level).run()
        assert result.status == "complete"
        plans[level] = [
            (r["step"], r["vehicle"], r["node"])
            for r in read_csv(tmp_path / level / "trajectory.csv")
            if r["source"] == "plan"
        ]
        times[level] = [float(r["time_s"]) for r in read_csv(tmp_path / level / "metrics.csv")]
        masses = [float(r["total_mass"]) for r in read_csv(tmp_path / level / "metrics.csv")]
        assert masses[-1] > masses[0]  # the continuous source released with mission time
    assert len(plans["sim"]) > 3 * 4 and plans["sitl"] == plans["sim"]
    assert times["sitl"] != times["sim"]

"""The gp environment's ground truths and its periodic hyperparameter fitting, through missions."""

import numpy as np
from support import LAKE, base_mission, run_cli

from guadal_cli.maps.format import Map, load_map
from guadal_cli.mission import prepare
from guadal_cli.runner import MissionRunner


def test_gp_prior_truth_is_smooth_and_normalised(write_mission):
    prep = prepare(
        write_mission(
            base_mission(
                environment={"type": "gp", "ground_truth": {"type": "gp_prior", "length_scale": 30.0}}
            )
        )
    )
    truth, g = prep.environment.ground_truth, prep.graph
    assert truth.min() == 0.0 and truth.max() == 1.0
    # smooth: neighbours 5 m apart differ far less than random nodes do
    pairs = [(a, b) for a in range(g.n_nodes) for b in g.neighbors(a) if a < b]
    neighbour_gap = np.mean([abs(truth[a] - truth[b]) for a, b in pairs])
    rng = np.random.default_rng(0)
    random_gap = np.mean(
        np.abs(truth[rng.integers(0, g.n_nodes, 2000)] - truth[rng.integers(0, g.n_nodes, 2000)])
    )
    assert neighbour_gap < 0.25 * random_gap


def test_external_truth_file_is_read_on_the_map_grid(write_mission, tmp_path):
    shape = load_map(LAKE).shape
    grid = np.fromfunction(lambda r, c: r * 100 + c, shape)
    np.savetxt(tmp_path / "survey.csv", grid, delimiter=",")
    mission = write_mission(
        base_mission(environment={"type": "gp", "ground_truth": {"type": "file", "path": "survey.csv"}})
    )
    prep = prepare(mission)  # the path resolves against the mission file's folder
    g = prep.graph
    assert np.array_equal(prep.environment.ground_truth, g.rows * 100 + g.cols)
    np.savetxt(tmp_path / "survey.csv", grid[:-1], delimiter=",")
    proc = run_cli("validate", mission)
    assert (
        proc.returncode == 2
        and "environment.ground_truth.path" in proc.stderr
        and "must match" in proc.stderr
    )


def test_hyperparameters_are_refitted_at_the_chosen_interval(write_mission, tmp_path):
    env = {
        "type": "gp",
        "ground_truth": {"type": "gp_prior", "length_scale": 40.0},
        "kernel": {"type": "rbf", "length_scale": 5.0, "noise": 1e-3},
        "fit_every": 10,
    }
    prep = prepare(write_mission(base_mission(environment=env, fleet={"vehicles": 2, "max_distance": 150})))
    MissionRunner(prep, output=tmp_path / "run").run()
    fitted = prep.environment.model.kernel
    assert fitted.length_scale > 10.0  # pulled from 5 m towards the truth's 40 m
    assert prep.environment.config.kernel.length_scale == 5.0  # the mission's setting is kept as written


def test_vehicles_in_separate_water_bodies_are_refused(write_mission, tmp_path):
    mask = np.zeros((6, 12), bool)
    mask[1:5, 1:5] = True
    mask[1:5, 7:11] = True
    Map(mask=mask, cell_size_m=5, reference={"row": 0, "col": 0, "lat": 37.0, "lon": -6.0}).save(
        tmp_path / "two.json"
    )
    mission = base_mission(
        map=str(tmp_path / "two.json"),
        fleet={
            "vehicles": 2,
            "initial_positions": [{"row": 2, "col": 2}, {"row": 2, "col": 8}],
            "max_distance": 50,
        },
    )
    proc = run_cli("validate", write_mission(mission))
    assert proc.returncode == 2 and "separate water bodies" in proc.stderr
    # auto places every boat in the largest body, so the same fleet with auto is valid
    mission["fleet"]["initial_positions"] = "auto"
    assert run_cli("validate", write_mission(mission)).returncode == 0

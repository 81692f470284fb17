"""The gp environment's ground truths, its hyperparameter fitting and its choice of model, through missions."""

import json

import numpy as np
import pytest
from support import LAKE, base_mission, run_cli

from guadal_cli.envs.ground_truth import GPPriorField
from guadal_cli.errors import GuadalError
from guadal_cli.graph import NavGraph
from guadal_cli.maps.format import Map, load_map
from guadal_cli.mission import prepare
from guadal_cli.models.local_gp import LocalGP
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
    (tmp_path / "survey.csv").write_bytes(bytes(range(128, 256)) * 3)  # a binary file: no grid at all
    with pytest.raises(GuadalError, match="'.*survey.csv' is not a grid of numbers"):
        prepare(mission)


@pytest.mark.parametrize("model", ["exact", "local"])
def test_hyperparameters_are_refitted_at_the_chosen_interval(model, write_mission, tmp_path):
    env = {
        "type": "gp",
        "ground_truth": {"type": "gp_prior", "length_scale": 40.0},
        "kernel": {"type": "rbf", "length_scale": 5.0, "noise": 1e-3},
        "fit_every": 10,
        "model": {"type": model},
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


def test_the_local_gp_takes_over_past_the_exact_gps_memory_and_the_manifest_says_so(write_mission, tmp_path):
    fleet = {"vehicles": 3, "initial_positions": "auto", "max_distance": 300.0, "speed": 0.5}
    env = {"type": "gp", "kernel": {"type": "matern", "nu": 1.5, "length_scale": 20.0, "noise": 1e-3}}
    exact = MissionRunner(
        prepare(write_mission(base_mission(environment=env, fleet=fleet))), tmp_path / "a"
    ).run()
    # 351 nodes: the exact GP needs 1.5 MB up to 128 samples and 2.2 MB for 256
    env["model"] = {"exact_max_mb": 2.0}
    prep = prepare(write_mission(base_mission(environment=env, fleet=fleet), name="capped.yaml"))
    capped = MissionRunner(prep, tmp_path / "b").run()

    manifests = [json.loads((tmp_path / d / "manifest.json").read_text()) for d in ("a", "b")]
    assert manifests[0]["model"] == {"type": "exact"}
    model = manifests[1]["model"]
    assert model["type"] == "local" and 120 <= model["since_sample"] <= 128 < capped.final_metrics["samples"]
    assert "exact_max_mb" in model["reason"]
    assert isinstance(prep.environment.model, LocalGP)
    # the hand-over keeps the samples: the maps stay close to the exact run's
    fields = [np.genfromtxt(tmp_path / d / "fields.csv", delimiter=",", names=True) for d in ("a", "b")]
    assert abs(fields[0]["std"].mean() - fields[1]["std"].mean()) < 0.05
    assert capped.final_metrics["rmse"] < exact.final_metrics["rmse"] + 0.05


def square_lake(side: int) -> NavGraph:
    return NavGraph(
        Map(
            mask=np.ones((side, side), bool),
            cell_size_m=5.0,
            reference={"row": 0, "col": 0, "lat": 37, "lon": -6},
        )
    )


def test_gp_prior_draws_have_the_kernels_correlation_on_large_grids():
    graph = square_lake(300)  # 90,000 nodes: a dense covariance would take 65 GB
    field = GPPriorField(GPPriorField.Config(length_scale=20.0))
    lags = {1: [], 4: [], 8: []}
    for seed in range(4):
        z = field.generate(graph, np.random.default_rng(seed))
        z = graph.to_grid((z - z.mean()) / z.std())
        for lag, seen in lags.items():
            seen.append(np.mean(z[:, :-lag] * z[:, lag:]))
    for lag, seen in lags.items():
        assert np.mean(seen) == pytest.approx(np.exp(-0.5 * (5.0 * lag / 20.0) ** 2), abs=0.05)
    again = field.generate(graph, np.random.default_rng(0))
    assert np.array_equal(again, field.generate(graph, np.random.default_rng(0)))  # seeded


def test_a_gp_prior_too_big_to_draw_is_refused_in_one_sentence(monkeypatch):
    monkeypatch.setattr(GPPriorField, "MAX_CELLS", 10_000)
    with pytest.raises(GuadalError, match=r"^a gp_prior .* 300 x 300 grid .*; use a") as err:
        GPPriorField(GPPriorField.Config()).generate(square_lake(300), np.random.default_rng(0))
    assert str(err.value).count(". ") == 0


def test_model_updates_run_with_the_configured_blas_threads_and_restore_them():
    from threadpoolctl import threadpool_info, threadpool_limits

    from guadal_cli.envs.gp import BlasThreads

    def counts():
        return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]

    with threadpool_limits(limits=2, user_api="blas"):
        assert counts() and set(counts()) == {2}
        with BlasThreads(1):
            assert set(counts()) == {1}
        assert set(counts()) == {2}

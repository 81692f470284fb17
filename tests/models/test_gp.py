import numpy as np
import pytest
from sklearn.gaussian_process import GaussianProcessRegressor

from guadal_cli.models.gp import IncrementalGP, KernelConfig, sklearn_kernel


@pytest.fixture
def points():
    rr, cc = np.mgrid[0:15, 0:20]
    return np.column_stack([cc.ravel() * 5.0, rr.ravel() * -5.0])


@pytest.mark.parametrize(
    "kernel",
    [
        KernelConfig(type="rbf", length_scale=20, noise=1e-4),
        KernelConfig(type="matern", nu=0.5, length_scale=12, variance=0.5, noise=1e-3),
        KernelConfig(type="matern", nu=1.5, length_scale=15, variance=2.0, noise=1e-2),
        KernelConfig(type="matern", nu=2.5, length_scale=30, noise=1e-5),
    ],
)
def test_incremental_posterior_equals_a_full_refit(points, kernel):
    rng = np.random.default_rng(1)
    idx = rng.integers(0, len(points), 80)  # repeats included: vehicles revisit nodes
    y = np.sin(points[idx, 0] / 20) + rng.normal(0, 0.05, len(idx))
    gp = IncrementalGP(kernel, points, prior_mean=0.0)
    for i, value in zip(idx, y):
        gp.add(points[i], value)
    ref = GaussianProcessRegressor(kernel=sklearn_kernel(kernel), alpha=kernel.noise, optimizer=None).fit(
        points[idx], y
    )
    mean, std = ref.predict(points, return_std=True)
    assert np.abs(gp.mean - mean).max() < 1e-8
    assert np.abs(gp.std - std).max() < 1e-8


def test_sampling_a_node_shrinks_its_uncertainty_and_pulls_the_mean(points):
    gp = IncrementalGP(KernelConfig(length_scale=15, noise=1e-4), points, prior_mean=0.5)
    assert np.allclose(gp.mean, 0.5) and np.allclose(gp.std, 1.0)
    gp.add(points[10], 2.0)
    assert gp.std[10] < 0.02 and gp.mean[10] == pytest.approx(2.0, abs=1e-3)
    far = np.argmax(np.hypot(*(points - points[10]).T))
    assert gp.std[far] == pytest.approx(1.0, abs=1e-3)


def test_hyperparameter_fit_moves_towards_the_true_length_scale(points):
    rng = np.random.default_rng(4)
    truth = KernelConfig(type="rbf", length_scale=25.0, noise=1e-4)
    from guadal_cli.models.gp import kernel_matrix

    k = kernel_matrix(truth, points, points) + 1e-8 * np.eye(len(points))
    field = np.linalg.cholesky(k) @ rng.standard_normal(len(points))
    gp = IncrementalGP(KernelConfig(type="rbf", length_scale=3.0, noise=1e-3), points)
    idx = rng.choice(len(points), 120, replace=False)
    gp.add_many(points[idx], field[idx])
    before = np.sqrt(np.mean((gp.mean - field) ** 2))
    fitted = gp.fit_hyperparameters()
    after = np.sqrt(np.mean((gp.mean - field) ** 2))
    assert 12.0 < fitted.length_scale < 50.0
    assert after < before
    assert gp.n_ == 120


def _refit(points, kernel, idx, y):
    ref = GaussianProcessRegressor(kernel=sklearn_kernel(kernel), alpha=kernel.noise, optimizer=None)
    return ref.fit(points[idx], y).predict(points, return_std=True)


def test_samples_on_prediction_points_equal_a_full_refit(points):
    """The runner's path: samples at graph nodes (repeats included), a hop's samples at a time."""
    kernel = KernelConfig(type="matern", nu=1.5, length_scale=15, variance=2.0, noise=1e-3)
    rng = np.random.default_rng(2)
    idx = rng.integers(0, len(points), 84)
    idx[1] = idx[0]
    y = np.cos(points[idx, 1] / 15) + rng.normal(0, 0.05, len(idx))
    gp = IncrementalGP(kernel, points)
    for start in range(0, len(idx), 3):
        part = idx[start : start + 3]
        gp.add_many(points[part], y[start : start + 3], points=part.tolist())
    mean, std = _refit(points, kernel, idx, y)
    assert gp.n_ == len(idx)
    assert np.abs(gp.mean - mean).max() < 1e-10
    assert np.abs(gp.std - std).max() < 1e-10
    assert np.array_equal(gp.X_, points[idx]) and np.array_equal(gp.y_, y)


def test_posterior_arrays_are_read_only_snapshots(points):
    gp = IncrementalGP(KernelConfig(length_scale=15), points)
    gp.add(points[3], 1.0, 3)
    before_mean, before_std = gp.mean, gp.std
    assert gp.mean is before_mean  # not recomputed between samples
    with pytest.raises(ValueError):
        before_std[0] = 0.0
    gp.add(points[40], 2.0)  # off the points' index: the other path
    assert gp.mean is not before_mean and gp.std[40] < before_std[40]
    assert before_mean[3] == pytest.approx(gp.mean[3], abs=0.5)  # the old snapshot kept its values

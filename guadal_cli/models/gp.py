"""Gaussian-process regression over the graph's nodes, updated one sample at a time.

Refitting a GP on ``n`` samples costs O(n^3) and, to predict at ``N`` nodes, O(n^2 N). Here the
Cholesky factor ``L`` of the training covariance grows by one row per sample, and so do
``V = L^-1 K(X, nodes)`` and ``z = L^-1 (y - m)``. The posterior at every node is then

    mean = m + V^T z        var = k(x, x) - sum(V^2, axis=0)

and a new sample changes both by one rank-one term: O(n N) per sample, no refit. When the
sample lies on a prediction point (vehicles sample at graph nodes) the new row of ``L`` is
already a column of ``V``, so not even a triangular solve is needed. The
result equals scikit-learn's ``GaussianProcessRegressor`` with the same kernel, ``alpha`` equal
to the noise variance and the optimizer off (``bench/`` checks this to 1e-6).

Hyperparameters can be re-estimated at chosen intervals by maximising the marginal likelihood
(with scikit-learn's optimiser); the factor is then rebuilt once from the stored samples.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.linalg import solve_triangular
from scipy.spatial.distance import cdist


class KernelConfig(BaseModel):
    """Covariance of the field: RBF or Matérn, stationary, in metres.

    The default, Matérn 3/2 with a little noise, suits sampling along 5 m grids: a near-noiseless
    RBF over such dense, clustered samples overshoots between them (measured on the example
    missions: RMSE rising from 0.15 to 0.6 before falling, and ending 25 times higher).
    """

    model_config = ConfigDict(extra="forbid")
    type: Literal["rbf", "matern"] = "matern"
    # The upper bounds are far beyond any field a boat samples; past them the posterior's
    # arithmetic (variance squared, distance over length) overflows to NaN instead of refusing.
    length_scale: float = Field(
        default=20.0, ge=1e-3, le=1e7, description="Correlation length, metres (1 mm to 10,000 km)."
    )
    variance: float = Field(default=1.0, gt=0, le=1e12, description="Signal variance (at most 1e12).")
    noise: float = Field(
        default=1e-3, ge=1e-8, le=1e12, description="Observation noise variance (1e-8 to 1e12)."
    )
    nu: Literal[0.5, 1.5, 2.5] = Field(default=1.5, description="Matérn smoothness (matern only).")


def correlation(cfg: KernelConfig, d: np.ndarray) -> np.ndarray:
    """The kernel's correlation at distances ``d`` measured in length scales."""
    if cfg.type == "rbf":
        return np.exp(-0.5 * d**2)
    if cfg.nu == 0.5:
        return np.exp(-d)
    if cfg.nu == 1.5:
        s = math.sqrt(3.0) * d
        return (1.0 + s) * np.exp(-s)
    s = math.sqrt(5.0) * d
    return (1.0 + s + s**2 / 3.0) * np.exp(-s)


def kernel_matrix(cfg: KernelConfig, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Covariance between point sets ``a`` (n,2) and ``b`` (m,2), without the noise term."""
    return cfg.variance * correlation(cfg, cdist(a / cfg.length_scale, b / cfg.length_scale))


def sklearn_kernel(cfg: KernelConfig, fit_bounds=None):
    """The same kernel in scikit-learn terms (for fitting and for the benchmark baseline)."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, Matern

    bounds = fit_bounds or "fixed"
    base = (
        RBF(length_scale=cfg.length_scale, length_scale_bounds=bounds)
        if cfg.type == "rbf"
        else Matern(length_scale=cfg.length_scale, nu=cfg.nu, length_scale_bounds=bounds)
    )
    return ConstantKernel(cfg.variance, constant_value_bounds=bounds) * base


class IncrementalGP:
    """Posterior mean and std at fixed prediction points, updated sample by sample."""

    def __init__(self, kernel: KernelConfig, points: np.ndarray, prior_mean: float = 0.0):
        self.kernel = kernel
        self.points = np.asarray(points, dtype=float)
        self.prior_mean = float(prior_mean)
        self.reset()

    #: up to this many prediction points, the whole point-to-point kernel is kept (32 MB at most)
    CACHE_POINTS = 2048

    def _kernel_row(self, point: int) -> np.ndarray:
        """k(point, every point): from the cached kernel on small maps, computed on large ones."""
        if len(self.points) > self.CACHE_POINTS:
            return kernel_matrix(self.kernel, self.points[point : point + 1], self.points)[0]
        if self._K is None:
            self._K = kernel_matrix(self.kernel, self.points, self.points)
        return self._K[point]

    def reset(self) -> None:
        self._K = None  # the kernel may have changed (hyperparameter fit)
        n_points = len(self.points)
        self._cap = 64
        self._L = np.zeros((self._cap, self._cap))
        self._V = np.zeros((self._cap, n_points))
        self._z = np.zeros(self._cap)
        self._X = np.zeros((self._cap, 2))
        self._y = np.zeros(self._cap)
        self.n_ = 0
        self._mean_delta = np.zeros(n_points)
        self._var = np.full(n_points, self.kernel.variance)
        self._mean = self._std = None  # the posterior as last read, until the next sample

    def memory_bytes(self, n_samples: int | None = None) -> int:
        """Bytes held with ``n_samples`` samples (default: now): the samples x nodes matrix
        ``V`` dominates, allocated in doublings of 64 rows."""
        n = self.n_ if n_samples is None else n_samples
        cap = 64
        while cap < n:
            cap *= 2
        n_points = len(self.points)
        cached = n_points**2 if n_points <= self.CACHE_POINTS else 0
        return 8 * (cap * (cap + n_points + 4) + 2 * n_points + cached)

    def _grow(self) -> None:
        cap = self._cap * 2
        L = np.zeros((cap, cap))
        L[: self._cap, : self._cap] = self._L
        V = np.zeros((cap, self._V.shape[1]))
        V[: self._cap] = self._V
        z = np.zeros(cap)
        z[: self._cap] = self._z
        X = np.zeros((cap, 2))
        X[: self._cap] = self._X
        y = np.zeros(cap)
        y[: self._cap] = self._y
        self._L, self._V, self._z, self._X, self._y, self._cap = L, V, z, X, y, cap

    @property
    def X_(self) -> np.ndarray:
        """Sample locations so far (metres)."""
        return self._X[: self.n_]

    @property
    def y_(self) -> np.ndarray:
        """Sample values so far."""
        return self._y[: self.n_]

    def add(self, x: np.ndarray, y: float, point: int | None = None) -> None:
        """Condition on one observation ``y`` at location ``x`` (metres).

        ``point``: index of the prediction point the sample lies on, if any (the fast path).
        """
        n = self.n_
        if n == self._cap:
            self._grow()
        V, kernel = self._V, self.kernel
        k_xx = kernel.variance + kernel.noise
        v = V[n]  # the new row, computed in place
        if point is not None:
            x = self.points[point]
            k_star = self._kernel_row(point)
            l = V[:n, point]  # L^-1 k(X, x) is V's column for that point
        else:
            x = np.asarray(x, dtype=float).reshape(2)
            k_star = kernel_matrix(kernel, x[None], self.points)[0]
            l = np.zeros(0)
            if n:
                k_x = kernel_matrix(kernel, x[None], self.X_)[0]
                l = solve_triangular(
                    np.ascontiguousarray(self._L[:n, :n]), k_x, lower=True, check_finite=False
                )
        if n:
            d2 = k_xx - l @ l
            np.subtract(k_star, l @ V[:n], out=v)
            z_prev = l @ self._z[:n]
            self._L[n, :n] = l
        else:
            d2, z_prev = k_xx, 0.0
            v[:] = k_star
        d = math.sqrt(max(d2, 1e-12))
        self._L[n, n] = d
        v /= d
        z_n = (y - self.prior_mean - z_prev) / d
        self._z[n] = z_n
        self._mean_delta += z_n * v
        self._var -= v * v
        self._X[n] = x
        self._y[n] = y
        self.n_ = n + 1
        self._mean = self._std = None

    def add_many(self, xs: np.ndarray, ys, points=None) -> None:
        xs = np.asarray(xs, dtype=float).reshape(-1, 2)
        points = [None] * len(xs) if points is None else points
        for x, y, p in zip(xs, ys, points):
            self.add(x, float(y), p)

    @property
    def mean(self) -> np.ndarray:
        """Posterior mean at every point (read-only; computed once per sample)."""
        if self._mean is None:
            self._mean = self.prior_mean + self._mean_delta
            self._mean.flags.writeable = False
        return self._mean

    @property
    def std(self) -> np.ndarray:
        """Posterior standard deviation at every point (read-only; computed once per sample)."""
        if self._std is None:
            self._std = np.sqrt(np.clip(self._var, 0.0, None))
            self._std.flags.writeable = False
        return self._std

    def fit_hyperparameters(self, seed: int = 0) -> KernelConfig:
        """Maximise the marginal likelihood over length scale, variance and noise; rebuild."""
        if self.n_ < 3:
            return self.kernel
        span = float(np.ptp(self.points, axis=0).max()) or 1.0
        self.kernel = fit_kernel(self.kernel, self.X_, self.y_ - self.prior_mean, span, seed)
        X, y = self.X_.copy(), self.y_.copy()
        self.reset()
        self.add_many(X, y)
        return self.kernel


def fit_kernel(kernel: KernelConfig, X: np.ndarray, y: np.ndarray, span: float, seed: int) -> KernelConfig:
    """The kernel maximising the marginal likelihood of ``y`` (prior mean removed) at ``X``;
    length scales are bounded by ten times ``span``, the extent of the map in metres. One more
    start (seeded) besides the current kernel: from a short length scale alone, the optimiser
    can settle on a degenerate optimum (length scale at its lower bound, samples independent)."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import WhiteKernel

    fit = sklearn_kernel(kernel, fit_bounds=(1e-2, max(span, 1.0) * 10)) + WhiteKernel(
        kernel.noise, noise_level_bounds=(1e-8, 1.0)
    )
    fit.k1.k1.constant_value_bounds = (1e-4, 1e3)
    gpr = GaussianProcessRegressor(kernel=fit, normalize_y=False, n_restarts_optimizer=1, random_state=seed)
    gpr.fit(X, y)
    fitted = gpr.kernel_
    return kernel.model_copy(
        update={
            "variance": float(fitted.k1.k1.constant_value),
            "length_scale": float(fitted.k1.k2.length_scale),
            "noise": float(max(fitted.k2.noise_level, 1e-8)),
        }
    )

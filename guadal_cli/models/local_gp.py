"""A local GP for lakes too big for the exact one: every node conditioned on its nearest samples.

The exact GP (:mod:`.gp`) keeps a samples x nodes matrix: on a million-node lake it no longer
fits in memory after a few dozen samples, and each sample costs O(samples x nodes). Here the
posterior at a node uses only its ``neighbours`` nearest samples within ``radius`` length
scales, a nearest-neighbour GP. A Matérn field is screened by near samples (the far ones add
almost nothing once near ones are known), so on the shipped missions it stays within a few
thousandths of the exact posterior (``bench/RESULTS.md``), and:

* memory is O(nodes + samples): the posterior mean and std per node, and the samples;
* a sample changes only the nodes it joins the nearest samples of (within ``radius``, and
  nearer than their current farthest neighbour): O(those nodes x neighbours^3) per sample,
  whatever the lake's size or the number of samples so far.

``add_many`` folds a batch in (a fleet's step) with one vectorised pass over the nodes it
changes; ``add`` only stores a sample, and the next read of ``mean`` or ``std`` folds it in.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from .gp import KernelConfig, correlation, fit_kernel

#: nodes recomputed per vectorised chunk: a few neighbours^2 arrays each (~10 MB at 32 neighbours)
_CHUNK = 256


class LocalGP:
    """Posterior mean and std at fixed points, each from its nearest samples within a radius.

    Same interface as :class:`~guadal_cli.models.gp.IncrementalGP` (``add``, ``add_many``,
    ``mean``, ``std``, ``X_``, ``y_``, ``n_``, ``reset``, ``fit_hyperparameters``).
    """

    def __init__(
        self,
        kernel: KernelConfig,
        points: np.ndarray,
        prior_mean: float = 0.0,
        neighbours: int = 32,
        radius: float = 4.0,
    ):
        self.kernel = kernel
        self.points = np.asarray(points, dtype=float)
        self.prior_mean = float(prior_mean)
        self.neighbours = int(neighbours)
        self.radius = float(radius)
        self._tree = cKDTree(self.points)
        self.reset()

    @property
    def radius_m(self) -> float:
        """The radius in metres (``radius`` is in length scales, so it follows a fitted kernel)."""
        return self.radius * self.kernel.length_scale

    def reset(self) -> None:
        n_points = len(self.points)
        self._X = np.zeros((64, 2))
        self._y = np.zeros(64)
        self.n_ = 0
        self._fresh = 0  # samples [_fresh, n_) are stored but not yet folded into the posterior
        self._buckets: dict[tuple[int, int], list[int]] = {}
        self._bucket_m = self.radius_m
        self._mean = np.full(n_points, self.prior_mean)
        self._var = np.full(n_points, self.kernel.variance)
        # distance from each node to its farthest neighbour sample (inf: fewer than
        # ``neighbours`` within the radius); a farther new sample leaves the node as it is
        self._reach = np.full(n_points, np.inf)

    def memory_bytes(self, n_samples: int | None = None) -> int:
        """Bytes held with ``n_samples`` samples (default: now): three floats per node and
        about a hundred bytes per sample (position, value, bucket entry), no samples x nodes matrix."""
        n = self.n_ if n_samples is None else n_samples
        return 8 * 3 * len(self.points) + 100 * max(n, len(self._y))

    @property
    def X_(self) -> np.ndarray:
        return self._X[: self.n_]

    @property
    def y_(self) -> np.ndarray:
        return self._y[: self.n_]

    def _bucket(self, x: np.ndarray) -> tuple[int, int]:
        return (math.floor(x[0] / self._bucket_m), math.floor(x[1] / self._bucket_m))

    def add(self, x: np.ndarray, y: float, point: int | None = None) -> None:
        """Store one observation ``y`` at ``x`` (metres); it is folded in at the next read."""
        if self.n_ == len(self._y):
            self._X = np.concatenate([self._X, np.zeros_like(self._X)])
            self._y = np.concatenate([self._y, np.zeros_like(self._y)])
        x = np.asarray(x, dtype=float).reshape(2)
        self._X[self.n_] = x
        self._y[self.n_] = float(y)
        self._buckets.setdefault(self._bucket(x), []).append(self.n_)
        self.n_ += 1

    def add_many(self, xs: np.ndarray, ys, points=None) -> None:
        """Condition on a batch of observations now (one pass over the nodes they change)."""
        for x, y in zip(np.asarray(xs, dtype=float).reshape(-1, 2), ys):
            self.add(x, float(y))
        self._fold_in()

    @property
    def mean(self) -> np.ndarray:
        self._fold_in()
        view = self._mean.view()
        view.flags.writeable = False
        return view

    @property
    def std(self) -> np.ndarray:
        self._fold_in()
        return np.sqrt(np.clip(self._var, 0.0, None))

    # --- the update ------------------------------------------------------------------------
    def _fold_in(self) -> None:
        if self._fresh == self.n_:
            return
        fresh = self._X[self._fresh : self.n_]
        self._fresh = self.n_
        changed = []
        for x, near in zip(fresh, self._tree.query_ball_point(fresh, self.radius_m)):
            near = np.asarray(near, dtype=np.intp)
            d = np.hypot(*(self.points[near] - x).T)
            changed.append(near[d <= self._reach[near]])
        nodes = np.unique(np.concatenate(changed))
        if len(nodes):
            self._recompute(nodes, self._samples_near(fresh))

    def _samples_near(self, fresh: np.ndarray) -> np.ndarray:
        """Every sample that may be among a recomputed node's neighbours (within 2 radii of a
        fresh sample), in sample order so that the result does not depend on dict order."""
        keys = {self._bucket(x) for x in fresh}
        around = {(i + di, j + dj) for i, j in keys for di in (-2, -1, 0, 1, 2) for dj in (-2, -1, 0, 1, 2)}
        found = [self._buckets[k] for k in around if k in self._buckets]
        return np.sort(np.concatenate([np.asarray(f, dtype=np.intp) for f in found]))

    def _recompute(self, nodes: np.ndarray, candidates: np.ndarray) -> None:
        """The posterior at ``nodes`` from their nearest ``candidates`` within the radius."""
        X, r = self._X[candidates], self._y[candidates] - self.prior_mean
        k = min(self.neighbours, len(candidates))
        tree = cKDTree(X)
        ell, variance = self.kernel.length_scale, self.kernel.variance
        diagonal = np.arange(k)
        # a node with fewer than k samples in reach gets padding samples this far apart and
        # away, uncorrelated with everything: they change neither mean nor variance
        far = 1e6 * ell * (1.0 + diagonal)
        for start in range(0, len(nodes), _CHUNK):
            chunk = nodes[start : start + _CHUNK]
            d, idx = tree.query(self.points[chunk], k=k, distance_upper_bound=self.radius_m)
            d, idx = d.reshape(len(chunk), k), idx.reshape(len(chunk), k)
            missing = idx == len(candidates)
            idx[missing] = 0
            xs = X[idx] - self.points[chunk, None, :]  # centred on the node: no cancellation
            xs[missing] = 0.0
            xs[..., 0] += np.where(missing, far, 0.0)
            sq = np.einsum("ijk,ijk->ij", xs, xs)
            d2 = sq[:, :, None] + sq[:, None, :] - 2.0 * (xs @ xs.transpose(0, 2, 1))
            K = variance * correlation(self.kernel, np.sqrt(np.maximum(d2, 0.0)) / ell)
            K[:, diagonal, diagonal] = variance + self.kernel.noise
            ks = variance * correlation(self.kernel, np.where(missing, far, d) / ell)
            rhs = np.stack([ks, np.where(missing, 0.0, r[idx])], axis=-1)
            sol = np.linalg.solve(K, rhs)
            self._var[chunk] = variance - np.einsum("ij,ij->i", ks, sol[:, :, 0])
            self._mean[chunk] = self.prior_mean + np.einsum("ij,ij->i", ks, sol[:, :, 1])
            self._reach[chunk] = d[:, -1] if k == self.neighbours else np.inf

    def fit_hyperparameters(self, seed: int = 0, max_samples: int = 1000) -> KernelConfig:
        """Fit the kernel on at most ``max_samples`` samples (evenly spread over the mission:
        a fit is O(samples^3)), then recompute every node near a sample."""
        if self.n_ < 3:
            return self.kernel
        keep = np.unique(np.linspace(0, self.n_ - 1, min(self.n_, max_samples)).astype(int))
        span = float(np.ptp(self.points, axis=0).max()) or 1.0
        self.kernel = fit_kernel(self.kernel, self.X_[keep], self.y_[keep] - self.prior_mean, span, seed)
        X, y = self.X_.copy(), self.y_.copy()
        self.reset()
        self.add_many(X, y)
        return self.kernel

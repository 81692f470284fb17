"""Ground-truth generators for scalar fields (water quality, say): plugins of
``guadal.ground_truths``. Each returns one value per graph node; land is never part of it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ..errors import GuadalError
from ..graph import NavGraph


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _normalise(values: np.ndarray) -> np.ndarray:
    lo, hi = float(values.min()), float(values.max())
    return np.zeros_like(values) if hi - lo < 1e-12 else (values - lo) / (hi - lo)


class ShekelField:
    """Shekel-style multi-peak field, normalised to [0, 1] over the water nodes.

    ``f(x) = sum_i 1 / (c_i + |x - a_i|^2)`` with the map scaled so its longest side spans 10
    units (as in the Shekel benchmark); peak centres ``a_i`` are random water nodes and the
    widths ``c_i`` are drawn from ``[min_width, max_width]``: smaller means sharper peaks.
    """

    class Config(_Config):
        peaks: int = Field(default=4, ge=1, le=50, description="Number of peaks.")
        min_width: float = Field(default=0.2, gt=0)
        max_width: float = Field(default=1.0, gt=0)

    def __init__(self, config: ShekelField.Config):
        if config.max_width < config.min_width:
            raise GuadalError("environment.ground_truth.max_width must be at least min_width.")
        self.config = config

    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        xy = graph.xy - graph.xy.min(axis=0)
        scale = 10.0 / max(float(xy.max()), 1e-9)
        pts = xy * scale
        centres = pts[
            rng.choice(graph.n_nodes, size=self.config.peaks, replace=graph.n_nodes < self.config.peaks)
        ]
        widths = rng.uniform(self.config.min_width, self.config.max_width, size=self.config.peaks)
        d2 = ((pts[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        return _normalise((1.0 / (widths[None, :] + d2)).sum(axis=1))


class GPPriorField:
    """A smooth field drawn from a zero-mean GP prior (RBF), normalised to [0, 1]."""

    class Config(_Config):
        length_scale: float = Field(default=30.0, gt=0, description="Correlation length, metres.")

    def __init__(self, config: GPPriorField.Config):
        self.config = config

    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        from ..models.gp import KernelConfig, kernel_matrix

        k = kernel_matrix(KernelConfig(type="rbf", length_scale=self.config.length_scale), graph.xy, graph.xy)
        # smooth kernels give near-singular covariances: a small jitter keeps Cholesky stable
        k[np.diag_indices_from(k)] += 1e-6
        sample = np.linalg.cholesky(k) @ rng.standard_normal(graph.n_nodes)
        return _normalise(sample)


class FileField:
    """An externally provided map (a past survey, a satellite estimate) on the map's grid.

    The file is a CSV grid of the map's shape (comma or whitespace separated); land cells may
    hold anything, water cells must be numbers. Values are used as they are unless
    ``normalise`` is set.
    """

    class Config(_Config):
        path: str = Field(description="CSV grid with the map's shape, relative to the mission file.")
        normalise: bool = False

    def __init__(self, config: FileField.Config):
        self.config = config

    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        path = Path(self.config.path)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if not path.is_file():
            raise GuadalError(f"environment.ground_truth.path: file '{path}' does not exist.")
        text = path.read_text()
        delimiter = "," if "," in text else None
        try:
            grid = np.genfromtxt(path, delimiter=delimiter, dtype=float)
        except ValueError as exc:
            raise GuadalError(
                f"environment.ground_truth.path: '{path}' is not a grid of numbers ({exc})."
            ) from exc
        if grid.shape != graph.map.shape:
            raise GuadalError(
                f"environment.ground_truth.path: '{path}' has shape {grid.shape}, the map is {graph.map.shape}; they must match."
            )
        values = grid[graph.rows, graph.cols]
        if not np.all(np.isfinite(values)):
            raise GuadalError(
                f"environment.ground_truth.path: '{path}' has non-numeric values on water cells."
            )
        return _normalise(values) if self.config.normalise else values

"""Ground-truth generators for scalar fields (water quality, say): plugins of
``guadal.ground_truths``. Each returns one value per graph node; land is never part of it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ..errors import GuadalError
from ..graph import NavGraph
from .base import GroundTruth


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _normalise(values: np.ndarray) -> np.ndarray:
    lo, hi = float(values.min()), float(values.max())
    return np.zeros_like(values) if hi - lo < 1e-12 else (values - lo) / (hi - lo)


class ShekelField(GroundTruth):
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
            raise GuadalError("must be at least min_width.", field="max_width")
        super().__init__(config)

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


class GPPriorField(GroundTruth):
    """A smooth field drawn from a zero-mean GP prior (RBF), normalised to [0, 1].

    Drawn on the map's whole grid by circulant embedding: the grid, padded by six length scales
    on each axis (where the kernel has vanished), is a torus on which the covariance is
    diagonalised by the FFT, so a draw costs O(N log N) time and O(N) memory at any size.
    Cells are spaced by the grid's mean spacing along rows and columns.
    """

    #: largest padded grid drawn (cells): 128 M cells take ~3 GB of FFT workspace
    MAX_CELLS = 2**27

    class Config(_Config):
        length_scale: float = Field(default=30.0, gt=0, description="Correlation length, metres.")

    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        from scipy import fft

        m = graph.map
        rows, cols = m.shape
        dy = float(np.abs(np.diff(m.y, axis=0)).mean()) if rows > 1 else m.cell_size_m
        dx = float(np.abs(np.diff(m.x, axis=1)).mean()) if cols > 1 else m.cell_size_m
        ell = self.config.length_scale
        size = [
            fft.next_fast_len(n + min(n, math.ceil(6 * ell / d)), real=True)
            for n, d in ((rows, dy), (cols, dx))
        ]
        if size[0] * size[1] > self.MAX_CELLS:
            raise GuadalError(
                f"a gp_prior with length_scale {ell:g} m on this {rows} x {cols} grid "
                f"needs a {size[0]} x {size[1]} FFT, more than the {self.MAX_CELLS:,} cells allowed; "
                "use a shorter length_scale, a coarser map or a file ground truth."
            )
        # the covariance's first row on the torus: distance to cell (0, 0) the short way round
        i = np.arange(size[0])
        j = np.arange(size[1])
        di = np.minimum(i, size[0] - i)[:, None] * (dy / ell)
        dj = np.minimum(j, size[1] - j)[None, :] * (dx / ell)
        eigenvalues = fft.rfft2(np.exp(-0.5 * (di**2 + dj**2))).real
        del di, dj
        # a kernel too long for the padding leaves tiny negative eigenvalues: dropped
        amplitude = np.sqrt(np.clip(eigenvalues, 0.0, None))
        del eigenvalues
        noise = fft.rfft2(rng.standard_normal(size))
        noise *= amplitude
        del amplitude
        field = fft.irfft2(noise, s=size)
        return _normalise(field[graph.rows, graph.cols])


class FileField(GroundTruth):
    """An externally provided map (a past survey, a satellite estimate) on the map's grid.

    The file is a CSV grid of the map's shape (comma or whitespace separated); land cells may
    hold anything, water cells must be numbers. Values are used as they are unless
    ``normalise`` is set.
    """

    class Config(_Config):
        path: str = Field(description="CSV grid with the map's shape, relative to the mission file.")
        normalise: bool = False

    def generate(self, graph: NavGraph, rng: np.random.Generator, base_dir=None) -> np.ndarray:
        path = Path(self.config.path)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if not path.is_file():
            raise GuadalError(f"file '{path}' does not exist.", field="path")
        try:
            text = path.read_text(encoding="utf-8")
            delimiter = "," if "," in text else None
            grid = np.genfromtxt(path, delimiter=delimiter, dtype=float)
        except ValueError as exc:  # UnicodeDecodeError too: a binary file is no grid
            raise GuadalError(f"'{path}' is not a grid of numbers ({exc}).", field="path") from exc
        if grid.shape != graph.map.shape:
            raise GuadalError(
                f"'{path}' has shape {grid.shape}, the map is {graph.map.shape}; they must match.",
                field="path",
            )
        values = grid[graph.rows, graph.cols]
        if not np.all(np.isfinite(values)):
            raise GuadalError(f"'{path}' has non-numeric values on water cells.", field="path")
        return _normalise(values) if self.config.normalise else values

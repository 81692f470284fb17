"""The local GP: its accuracy contract against the exact GP, and its memory bound."""

import tracemalloc

import numpy as np
import pytest

from guadal_cli.models.gp import IncrementalGP, KernelConfig
from guadal_cli.models.local_gp import LocalGP


def grid(rows: int, cols: int) -> np.ndarray:
    rr, cc = np.mgrid[0:rows, 0:cols]
    return np.column_stack([cc.ravel() * 5.0, rr.ravel() * -5.0])


def boat_walks(rows: int, cols: int, boats: int, hops: int, seed: int = 0) -> list[int]:
    """Nodes visited by boats wandering from the centre one cell at a time, as vehicles sample."""
    rng = np.random.default_rng(seed)
    nodes = []
    for _ in range(boats):
        r, c = rows // 2, cols // 2
        for _ in range(hops):
            r = int(np.clip(r + rng.integers(-1, 2), 0, rows - 1))
            c = int(np.clip(c + rng.integers(-1, 2), 0, cols - 1))
            nodes.append(r * cols + c)
    return nodes


@pytest.mark.parametrize(
    "kernel",
    [
        KernelConfig(),  # the default: Matérn 3/2, 20 m
        KernelConfig(type="matern", nu=0.5, length_scale=25, noise=1e-2),
        KernelConfig(type="matern", nu=2.5, length_scale=20, noise=1e-3),
    ],
)
def test_local_gp_stays_close_to_the_exact_gp(kernel):
    """The contract for Matérn kernels at the default 32 neighbours, with boats sampling in
    overlapping clumps (harder than the shipped missions): on a field spanning 4, mean within 0.2
    everywhere and 0.02 on average; std (prior 1) within 0.06 and 0.003. Four neighbours miss it."""
    points = grid(24, 32)
    field = np.sin(points[:, 0] / 25) + np.cos(points[:, 1] / 30)
    nodes = boat_walks(24, 32, boats=3, hops=70)
    exact, local = IncrementalGP(kernel, points), LocalGP(kernel, points)
    for n in nodes:
        exact.add(points[n], field[n], point=n)
    for i in range(0, len(nodes), 3):  # three boats' samples per update, as a fleet sends them
        batch = nodes[i : i + 3]
        local.add_many(points[batch], field[batch])
    mean_err, std_err = np.abs(local.mean - exact.mean), np.abs(local.std - exact.std)
    assert mean_err.max() < 0.2 and mean_err.mean() < 0.02
    assert std_err.max() < 0.06 and std_err.mean() < 0.003


def test_with_every_sample_in_reach_it_is_the_exact_gp():
    points = grid(12, 15)
    nodes = boat_walks(12, 15, boats=2, hops=40, seed=3)
    values = np.random.default_rng(1).normal(size=len(nodes))
    kernel = KernelConfig(length_scale=15.0, noise=1e-2)
    exact = IncrementalGP(kernel, points, prior_mean=0.3)
    local = LocalGP(kernel, points, prior_mean=0.3, neighbours=len(nodes), radius=100.0)
    for n, v in zip(nodes, values):
        exact.add(points[n], v, point=n)
        local.add(points[n], v)  # one at a time: folded in at the next read
        if n % 3 == 0:
            assert np.abs(local.std - exact.std).max() < 1e-8
    assert np.abs(local.mean - exact.mean).max() < 1e-8
    assert np.abs(local.std - exact.std).max() < 1e-8


def test_memory_grows_with_nodes_plus_samples_not_their_product():
    points = grid(200, 200)  # 40,000 nodes
    nodes = boat_walks(200, 200, boats=4, hops=50, seed=2)
    local = LocalGP(KernelConfig(), points)
    exact_bytes = IncrementalGP(KernelConfig(), points).memory_bytes(len(nodes))
    tracemalloc.start()
    try:
        for i in range(0, len(nodes), 4):
            batch = nodes[i : i + 4]
            local.add_many(points[batch], np.ones(len(batch)))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert exact_bytes > 80e6  # 200 samples x 40,000 nodes: what the exact GP would hold
    assert local.memory_bytes() < 8 * 4 * len(points) + 200 * len(nodes)
    assert peak < 20e6  # its arrays, plus a fixed workspace for one chunk of nodes
    assert local.std.min() < 0.1  # and it did condition on the samples

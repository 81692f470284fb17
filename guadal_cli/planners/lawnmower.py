"""``lawnmower``: the paper's "flooding" baseline, systematic boustrophedon coverage.

The reachable water is cut into one band per vehicle, across the lake's longer side, with equal
node counts. Inside its band a vehicle sweeps line by line, alternating direction (a lawnmower
pattern). Each decision sends a vehicle to the next node of its sweep that no vehicle has
sampled yet; the runner walks it there over water. It ignores the model: it serves as the
uninformed baseline.
"""

from __future__ import annotations

import numpy as np

from ..envs.base import Observation
from .base import TARGET, Planner


def boustrophedon_routes(graph, start_nodes: dict[int, int]) -> dict[int, list[int]]:
    """One sweep per vehicle over the water body the vehicles share."""
    component = graph.component[next(iter(start_nodes.values()))]
    nodes = np.nonzero(graph.component == component)[0]
    rows, cols = graph.rows[nodes], graph.cols[nodes]
    wide = (cols.max() - cols.min()) >= (rows.max() - rows.min())
    band_key, line_key = (cols, rows) if wide else (rows, cols)
    # bands: contiguous in band_key with equal node counts
    order = nodes[np.lexsort((line_key, band_key))]
    chunks = np.array_split(order, len(start_nodes))
    routes = []
    for chunk in chunks:
        r, c = graph.rows[chunk], graph.cols[chunk]
        line = r if wide else c
        along = c if wide else r
        route = []
        for i, value in enumerate(np.unique(line)):
            on_line = chunk[line == value]
            pos = along[line == value]
            step = on_line[np.argsort(pos, kind="stable")]
            route.extend(step[::-1] if i % 2 else step)
        routes.append([int(n) for n in route])
    # give the westernmost (or northernmost) band to the westernmost vehicle, and so on
    by_position = sorted(
        start_nodes, key=lambda v: (graph.x[start_nodes[v]], v) if wide else (-graph.y[start_nodes[v]], v)
    )
    return {v: routes[i] for i, v in enumerate(by_position)}


class Lawnmower(Planner):
    modes = (TARGET,)

    def reset(self, graph, n_vehicles, mode, seed) -> None:
        super().reset(graph, n_vehicles, mode, seed)
        self.routes_: dict[int, list[int]] | None = None
        self.cursor_: dict[int, int] = {}

    def next_targets(self, observation: Observation) -> dict[int, int]:
        if self.routes_ is None:
            self.routes_ = boustrophedon_routes(observation.graph, observation.positions)
            self.cursor_ = {v: 0 for v in self.routes_}
        occupied = set(observation.positions.values())
        targets = {}
        for v, route in self.routes_.items():
            if observation.done.get(v):
                self.cursor_[v] = len(route)
                continue
            i = self.cursor_[v]
            while i < len(route) and (
                observation.visits[route[i]] > 0 or route[i] in occupied or route[i] in targets.values()
            ):
                i += 1
            self.cursor_[v] = i
            if i < len(route):
                targets[v] = route[i]
        return targets

    @property
    def done(self) -> bool:
        return self.routes_ is not None and all(self.cursor_[v] >= len(r) for v, r in self.routes_.items())

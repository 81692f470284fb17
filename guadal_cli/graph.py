"""The navigation graph: water cells as nodes, 8-connected, edges weighted in metres.

Node ids are ``0..N-1`` over the water cells in row-major order, so they are stable for a given
map and can be written to CSVs and compared across runs and levels. Attributes per node:
``row, col, x, y, lat, lon``. Heavy queries (all distances from a node, nearest node) use
numpy/scipy arrays beside the networkx graph so that 5,000-node maps stay fast.
"""

from __future__ import annotations

from functools import lru_cache

import networkx as nx
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from .errors import GuadalError
from .maps.format import Map

_OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


class NavGraph:
    """Graph view of a :class:`Map` with the queries planners and fleets need."""

    def __init__(self, map_: Map):
        self.map = map_
        rows, cols = np.nonzero(map_.mask)
        self.n_nodes = len(rows)
        self.rows = rows.astype(int)
        self.cols = cols.astype(int)
        self.x = map_.x[rows, cols].astype(float)
        self.y = map_.y[rows, cols].astype(float)
        self.lat = map_.lat[rows, cols].astype(float)
        self.lon = map_.lon[rows, cols].astype(float)
        self.xy = np.column_stack([self.x, self.y])
        self._index = np.full(map_.mask.shape, -1, dtype=int)
        self._index[rows, cols] = np.arange(self.n_nodes)

        src, dst, w = [], [], []
        h, wdt = map_.mask.shape
        for dr, dc in _OFFSETS:
            r2, c2 = self.rows + dr, self.cols + dc
            ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < wdt)
            a = np.nonzero(ok)[0]
            b = self._index[r2[ok], c2[ok]]
            keep = b >= 0
            a, b = a[keep], b[keep]
            src.append(a)
            dst.append(b)
            w.append(np.hypot(self.x[a] - self.x[b], self.y[a] - self.y[b]))
        src_a, dst_a, w_a = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
        self.adjacency = csr_matrix((w_a, (src_a, dst_a)), shape=(self.n_nodes, self.n_nodes))
        self._neighbors = [
            tuple(
                int(v)
                for v in self.adjacency.indices[self.adjacency.indptr[i] : self.adjacency.indptr[i + 1]]
            )
            for i in range(self.n_nodes)
        ]
        self._edge_length = {(int(a), int(b)): float(w) for a, b, w in zip(src_a, dst_a, w_a)}
        self.n_components, self.component = connected_components(self.adjacency, directed=False)
        self._tree = cKDTree(self.xy)

        self.graph = nx.Graph()
        for i in range(self.n_nodes):
            self.graph.add_node(
                i,
                row=int(self.rows[i]),
                col=int(self.cols[i]),
                x=float(self.x[i]),
                y=float(self.y[i]),
                lat=float(self.lat[i]),
                lon=float(self.lon[i]),
            )
        upper = src_a < dst_a
        self.graph.add_weighted_edges_from(
            zip(src_a[upper].tolist(), dst_a[upper].tolist(), w_a[upper].tolist())
        )
        self._dist_cache = lru_cache(maxsize=256)(self._dijkstra_from)

    # --- lookups -------------------------------------------------------------------------
    def node_at(self, row: int, col: int) -> int | None:
        """Node id of the cell, or None for land or off-grid cells."""
        if 0 <= row < self._index.shape[0] and 0 <= col < self._index.shape[1]:
            n = int(self._index[row, col])
            return n if n >= 0 else None
        return None

    def nearest_node(self, lat: float, lon: float) -> int:
        x, y = self.map.projection.to_xy(lat, lon)
        return int(self._tree.query([float(x), float(y)])[1])

    def nodes_within(self, node: int, radius_m: float) -> np.ndarray:
        """Nodes whose centres lie within ``radius_m`` (straight line) of ``node``."""
        return np.asarray(self._tree.query_ball_point(self.xy[node], radius_m + 1e-9), dtype=int)

    def neighbors(self, node: int) -> tuple[int, ...]:
        return self._neighbors[node]

    def edge_length(self, a: int, b: int) -> float:
        """Metres between two neighbouring nodes (KeyError if they are not neighbours)."""
        return self._edge_length[(a, b)]

    # --- paths ---------------------------------------------------------------------------
    def _dijkstra_from(self, source: int):
        dist, pred = dijkstra(self.adjacency, directed=False, indices=source, return_predecessors=True)
        dist.setflags(write=False)
        pred.setflags(write=False)
        return dist, pred

    def distances_from(self, source: int) -> np.ndarray:
        """Water-path distance in metres from ``source`` to every node (inf if unreachable)."""
        return self._dist_cache(int(source))[0]

    def distance(self, a: int, b: int) -> float:
        return float(self.distances_from(a)[b])

    def shortest_path(self, a: int, b: int, avoid: frozenset[int] | set[int] = frozenset()) -> list[int]:
        """Nodes from ``a`` to ``b`` inclusive along the shortest water path.

        ``avoid`` removes nodes (other vehicles) from the search; the result is empty when no
        path exists.
        """
        if a == b:
            return [a]
        if not avoid and (a, b) in self._edge_length:
            return [a, b]  # neighbours: one edge is always the shortest way
        if avoid:
            keep = np.ones(self.n_nodes, dtype=bool)
            keep[list(avoid - {a, b})] = False
            adj = self.adjacency.multiply(keep[:, None]).multiply(keep[None, :]).tocsr()
            adj.eliminate_zeros()  # csgraph treats stored zeros as free edges
            dist, pred = dijkstra(adj, directed=False, indices=a, return_predecessors=True)
        else:
            dist, pred = self._dist_cache(int(a))
        if not np.isfinite(dist[b]):
            return []
        path = [int(b)]
        while path[-1] != a:
            path.append(int(pred[path[-1]]))
        return path[::-1]

    def same_component(self, nodes) -> bool:
        return len({int(self.component[n]) for n in nodes}) <= 1

    # --- attributes ----------------------------------------------------------------------
    def fill_graph_attribute(self, name: str, values) -> None:
        """Store one value per node as a node attribute (an array of N, or a full grid)."""
        values = np.asarray(values)
        if values.shape == self.map.mask.shape:
            values = values[self.rows, self.cols]
        if values.shape != (self.n_nodes,):
            raise GuadalError(
                f"attribute '{name}' needs {self.n_nodes} values or a {self.map.mask.shape} grid, got {values.shape}."
            )
        nx.set_node_attributes(self.graph, {i: values[i].item() for i in range(self.n_nodes)}, name)

    def node_attribute(self, name: str) -> np.ndarray:
        return np.array([self.graph.nodes[i][name] for i in range(self.n_nodes)])

    def to_grid(self, values, fill=np.nan) -> np.ndarray:
        """Per-node values back on the map's grid (land = ``fill``), for plots and files."""
        grid = np.full(self.map.mask.shape, fill, dtype=float)
        grid[self.rows, self.cols] = values
        return grid

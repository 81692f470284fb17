"""The navigation graph: water cells as nodes, 8-connected, edges weighted in metres.

Node ids are ``0..N-1`` over the water cells in row-major order, so they are stable for a given
map and can be written to CSVs and compared across runs and levels. Attributes per node:
``row, col, x, y, lat, lon``.

Everything is numpy arrays: the edges are one CSR matrix (neighbours, edge lengths, and
scipy.sparse.csgraph for paths), so a million-node lake costs about 150 MB and no Python object
per node or per edge. ``to_networkx()`` builds a networkx copy on demand, for users who want one.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from functools import lru_cache

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse import triu as sp_triu
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
        del src, dst, w
        self.adjacency = csr_matrix((w_a, (src_a, dst_a)), shape=(self.n_nodes, self.n_nodes))
        del src_a, dst_a, w_a
        self._indptr = self.adjacency.indptr
        self._indices = self.adjacency.indices
        self._lengths = self.adjacency.data
        self.n_components, self.component = connected_components(self.adjacency, directed=False)
        self._tree = cKDTree(self.xy)
        self._attributes: dict[str, np.ndarray] = {}
        # the neighbourhoods vehicles stand in are asked for many times a step: a bounded cache
        self._adjacent = lru_cache(maxsize=4096)(self._adjacent_uncached)
        # shortest-path trees (distances + predecessors, 12 bytes a node each), least recently
        # used first; bounded in bytes so that a million-node lake keeps a few, a small one many
        self._trees: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._max_trees = int(min(256, max(4, self.PATH_CACHE_BYTES // max(12 * self.n_nodes, 1))))

    #: memory the cache of shortest-path trees may use (one tree per recent source node)
    PATH_CACHE_BYTES = 256 * 2**20

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
        return self._adjacent(node)[0]

    def neighbours_within(self, node: int, budget_m: float) -> list[int]:
        """Neighbours one edge of at most ``budget_m`` metres away (1e-9 m of rounding allowed)."""
        nodes, lengths = self._adjacent(node)
        limit = budget_m + 1e-9
        return [n for n, length in zip(nodes, lengths) if length <= limit]

    def shortest_edge(self, node: int) -> float:
        """Metres to the nearest neighbour (inf for a node without one): the least a hop costs."""
        lengths = self._adjacent(node)[1]
        return min(lengths) if lengths else math.inf

    def edge_length(self, a: int, b: int) -> float:
        """Metres between two neighbouring nodes (KeyError if they are not neighbours)."""
        nodes, lengths = self._adjacent(a)
        try:
            return lengths[nodes.index(b)]
        except ValueError:
            raise KeyError((a, b)) from None

    def _adjacent_uncached(self, node: int) -> tuple[tuple[int, ...], tuple[float, ...]]:
        """Neighbours of ``node`` and the lengths of the edges to them, as Python tuples."""
        part = slice(int(self._indptr[node]), int(self._indptr[node + 1]))
        return tuple(self._indices[part].tolist()), tuple(self._lengths[part].tolist())

    # --- paths ---------------------------------------------------------------------------
    def _tree_from(self, source: int, limit: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distances and predecessors from ``source`` (cached, read-only), exact up to ``limit``
        metres and inf beyond it; a cached tree that reaches at least as far serves."""
        tree = self._trees.get(source)
        if tree is not None and tree[2] >= limit:
            self._trees.move_to_end(source)
            return tree[0], tree[1]
        dist, pred = dijkstra(
            self.adjacency, directed=False, indices=source, return_predecessors=True, limit=limit
        )
        pred = pred.astype(np.int32, copy=False)
        dist.setflags(write=False)
        pred.setflags(write=False)
        self._trees[source] = (dist, pred, limit)
        self._trees.move_to_end(source)
        while len(self._trees) > self._max_trees:
            self._trees.popitem(last=False)
        return dist, pred

    def distances_from(self, source: int, limit: float = math.inf) -> np.ndarray:
        """Water-path distance in metres from ``source`` to every node (inf if unreachable).

        With ``limit``, only nodes within that many metres are searched (the rest read inf): a
        planner that looks no farther than a vehicle's budget pays for the budget's disc, not
        the whole lake.
        """
        return self._tree_from(int(source), limit)[0]

    def distance(self, a: int, b: int) -> float:
        return float(self.distances_from(a)[b])

    def shortest_path(self, a: int, b: int, avoid: frozenset[int] | set[int] = frozenset()) -> list[int]:
        """Nodes from ``a`` to ``b`` inclusive along the shortest water path.

        ``avoid`` removes nodes (other vehicles) from the search; the result is empty when no
        path exists.
        """
        if a == b:
            return [a]
        if not avoid and b in self.neighbors(a):
            return [a, b]  # neighbours: one edge is always the shortest way
        if avoid:
            keep = np.ones(self.n_nodes, dtype=bool)
            keep[list(avoid - {a, b})] = False
            adj = self.adjacency.multiply(keep[:, None]).multiply(keep[None, :]).tocsr()
            adj.eliminate_zeros()  # csgraph treats stored zeros as free edges
            dist, pred = dijkstra(adj, directed=False, indices=a, return_predecessors=True)
        else:
            tree = self._trees.get(a)  # a tree searched only within a budget serves if it reaches b
            if tree is not None and np.isfinite(tree[0][b]):
                self._trees.move_to_end(a)
                dist, pred = tree[0], tree[1]
            else:
                dist, pred = self._tree_from(int(a))
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
        """Store one value per node under ``name`` (an array of N, or a full grid)."""
        values = np.asarray(values)
        if values.shape == self.map.mask.shape:
            values = values[self.rows, self.cols]
        if values.shape != (self.n_nodes,):
            raise GuadalError(
                f"attribute '{name}' needs {self.n_nodes} values or a {self.map.mask.shape} grid, got {values.shape}."
            )
        values = values.copy()
        values.setflags(write=False)
        self._attributes[name] = values

    def node_attribute(self, name: str) -> np.ndarray:
        return self._attributes[name]

    def to_networkx(self):
        """A networkx copy (node attributes included, edges weighted in metres), built on request.

        Nothing in guadal uses it: it is for users who want networkx's algorithms. It costs
        about 1 KB a node, so build it on small maps.
        """
        import networkx as nx

        graph = nx.Graph()
        base = {
            "row": self.rows,
            "col": self.cols,
            "x": self.x,
            "y": self.y,
            "lat": self.lat,
            "lon": self.lon,
        }
        columns = {**base, **self._attributes}
        values = {name: array.tolist() for name, array in columns.items()}
        graph.add_nodes_from((i, {name: v[i] for name, v in values.items()}) for i in range(self.n_nodes))
        upper = sp_triu(self.adjacency, k=1).tocoo()
        graph.add_weighted_edges_from(zip(upper.row.tolist(), upper.col.tolist(), upper.data.tolist()))
        return graph

    def to_grid(self, values, fill=np.nan) -> np.ndarray:
        """Per-node values back on the map's grid (land = ``fill``), for plots and files."""
        grid = np.full(self.map.mask.shape, fill, dtype=float)
        grid[self.rows, self.cols] = values
        return grid

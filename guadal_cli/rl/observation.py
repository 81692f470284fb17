"""What a learned policy sees and what its actions mean: the one place both are defined.

The training environments (:mod:`guadal_cli.rl.env`) and the ``policy`` planner that deploys a
trained policy at any level build their inputs here, from the same planner
:class:`~guadal_cli.envs.base.Observation`, so a policy sees identical inputs in training and in
the field. Only numpy: deploying a policy needs neither Gymnasium nor PettingZoo.

**Image channels** (one stack per vehicle, over the map's grid, float32 in [0, 1], land 0)::

    0 position   1 at the vehicle's own cell
    1 others     1 at the cells of the other vehicles
    2 FIELD_A    the first model field (gp: mean), scaled to [0, 1]
    3 FIELD_B    the second model field (gp: std), scaled to [0, 1]
    4 visited    1 where at least one sample was taken
    5 budget     the vehicle's remaining distance over its budget, on every water cell
    6 water      1 on water cells (the navigation map)

A field is scaled by ``(x - lo) / (max - lo)`` with ``lo = min(0, min x)`` over the water nodes,
at every step: a field that is never negative (std, belief) keeps zero as "nothing there", one
that can be (mean) spans [0, 1]. NaN (age of a never-seen node) reads 0; a flat field reads 0.

**Actions**, sequential mode: ``Discrete(9)``, stay then the 8 neighbours clockwise from north,
in grid terms (row 0 is the map's northern edge)::

    0 stay  1 N (row-1)  2 NE (row-1, col+1)  3 E (col+1)  4 SE (row+1, col+1)
    5 S (row+1)  6 SW (row+1, col-1)  7 W (col-1)  8 NW (row-1, col-1)

An action is valid (mask 1) when it stays, or when its cell is water and the hop fits in the
vehicle's remaining budget. Target mode: ``Discrete(n_nodes)``, a node id; valid when the node
is reachable over water within the remaining budget (staying is always valid).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from ..envs.base import Observation
from ..errors import GuadalError
from ..graph import NavGraph

SEQUENTIAL, TARGET = "sequential", "target"
COMPASS = ("stay", "N", "NE", "E", "SE", "S", "SW", "W", "NW")
#: (row, col) offset of each sequential action, in :data:`COMPASS` order
OFFSETS = ((0, 0), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))
LAYOUTS = ("image", "vector", "dict")
#: the model fields shown by default, first match wins: the GP's, else the detection tasks'
DEFAULT_FIELDS = (("mean", "std"), ("evidence", "observed"))


def default_fields(available: Iterable[str]) -> tuple[str, str]:
    """The two field channels for an environment providing ``available`` fields."""
    names = set(available)
    for pair in DEFAULT_FIELDS:
        if names.issuperset(pair):
            return pair
    if len(names) >= 2:
        return tuple(sorted(names)[:2])
    raise GuadalError(
        f"a policy needs two per-node fields from the environment, which provides only "
        f"{', '.join(sorted(names)) or 'none'}."
    )


def scale_field(values: np.ndarray) -> np.ndarray:
    """One field to [0, 1] (see the module docstring); NaN and flat fields read 0."""
    x = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    lo = min(0.0, float(x.min()))
    span = float(x.max()) - lo
    if span <= 1e-12:
        return np.zeros(x.shape, dtype=np.float32)
    return ((x - lo) / span).astype(np.float32)


class ObservationBuilder:
    """Observations, action masks and action-to-target mapping for one mission's grid and fleet.

    ``fields``: the two per-node fields shown (default: :func:`default_fields` of the
    observation's). ``max_distance``: the per-vehicle budget, to scale the budget channel.
    """

    def __init__(
        self,
        graph: NavGraph,
        n_vehicles: int,
        max_distance: float,
        mode: str = SEQUENTIAL,
        fields: tuple[str, str] | None = None,
    ):
        if mode not in (SEQUENTIAL, TARGET):
            raise GuadalError(f"mode must be '{SEQUENTIAL}' or '{TARGET}', not '{mode}'.")
        self.graph = graph
        self.n_vehicles = int(n_vehicles)
        self.max_distance = float(max_distance)
        self.mode = mode
        self.fields = None if fields is None else tuple(fields)
        self.height, self.width = graph.map.mask.shape
        self.flat = (graph.rows * self.width + graph.cols).astype(np.intp)
        self.water = np.zeros(self.height * self.width, dtype=np.float32)
        self.water[self.flat] = 1.0
        self.n_actions = len(OFFSETS) if mode == SEQUENTIAL else graph.n_nodes
        # sequential: the node each action leads to (-1: land or off the grid) and the hop's length
        index = np.full((self.height + 2, self.width + 2), -1, dtype=np.int64)  # a ring of land
        index[graph.rows + 1, graph.cols + 1] = np.arange(graph.n_nodes)
        self.action_nodes = np.stack(
            [index[graph.rows + 1 + dr, graph.cols + 1 + dc] for dr, dc in OFFSETS], axis=1
        )
        to = np.maximum(self.action_nodes, 0)
        self.action_lengths = np.where(
            self.action_nodes >= 0,
            np.hypot(graph.x[to] - graph.x[:, None], graph.y[to] - graph.y[:, None]),
            0.0,
        )

    # --- what the policy sees ------------------------------------------------------------
    @property
    def channels(self) -> tuple[str, ...]:
        a, b = self.fields or ("field_a", "field_b")
        return ("position", "others", a, b, "visited", "budget", "water")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Shape of one vehicle's image: (channels, rows, cols)."""
        return (len(self.channels), self.height, self.width)

    @property
    def vector_size(self) -> int:
        """Length of one vehicle's vector: every channel but water, at the water nodes."""
        return (len(self.channels) - 1) * self.graph.n_nodes

    def fields_of(self, observation: Observation) -> tuple[str, str]:
        if self.fields is None:
            self.fields = default_fields(observation.fields)
        missing = [f for f in self.fields if f not in observation.fields]
        if missing:
            raise GuadalError(
                f"the policy reads field(s) {', '.join(missing)}, which the environment does not provide "
                f"(it provides: {', '.join(sorted(observation.fields))})."
            )
        return self.fields

    def images(self, observation: Observation, vehicles: Iterable[int] | None = None) -> np.ndarray:
        """``(len(vehicles), C, rows, cols)`` float32: every vehicle's image (default: all)."""
        vehicles = list(range(self.n_vehicles)) if vehicles is None else list(vehicles)
        a, b = self.fields_of(observation)
        hw = self.height * self.width
        shared = np.zeros((4, hw), dtype=np.float32)  # field a, field b, visited, water
        shared[0, self.flat] = scale_field(observation.fields[a])
        shared[1, self.flat] = scale_field(observation.fields[b])
        shared[2, self.flat] = np.asarray(observation.visits) > 0
        shared[3] = self.water
        out = np.zeros((len(vehicles), 7, hw), dtype=np.float32)
        out[:, 2:5] = shared[:3]
        out[:, 6] = shared[3]
        cells = {v: int(self.flat[observation.positions[v]]) for v in observation.positions}
        for i, v in enumerate(vehicles):
            out[i, 0, cells[v]] = 1.0
            for u, cell in cells.items():
                if u != v:
                    out[i, 1, cell] = 1.0
            budget = observation.remaining.get(v, 0.0) / self.max_distance if self.max_distance else 0.0
            out[i, 5] = self.water * np.float32(min(max(budget, 0.0), 1.0))
        return out.reshape(len(vehicles), 7, self.height, self.width)

    def vectors(self, images: np.ndarray) -> np.ndarray:
        """The vector layout of :meth:`images`' output: channels but water, at water nodes."""
        n = images.shape[0]
        flat = images.reshape(n, images.shape[1], -1)[:, :-1, self.flat]
        return np.ascontiguousarray(flat.reshape(n, -1))

    # --- what its actions mean -----------------------------------------------------------
    def action_masks(self, observation: Observation, vehicles: Iterable[int] | None = None) -> np.ndarray:
        """``(len(vehicles), n_actions)`` int8: 1 where the action is valid (see the module doc)."""
        vehicles = list(range(self.n_vehicles)) if vehicles is None else list(vehicles)
        masks = np.zeros((len(vehicles), self.n_actions), dtype=np.int8)
        for i, v in enumerate(vehicles):
            here = observation.positions[v]
            budget = observation.remaining.get(v, 0.0) + 1e-9
            if self.mode == SEQUENTIAL:
                masks[i] = (self.action_nodes[here] >= 0) & (self.action_lengths[here] <= budget)
            else:
                masks[i] = self.graph.distances_from(here) <= budget
            masks[i, 0 if self.mode == SEQUENTIAL else here] = 1  # staying is always valid
        return masks

    def targets(
        self, observation: Observation, actions: Mapping[int, int], masks: np.ndarray | None = None
    ) -> tuple[dict[int, int], dict[int, str]]:
        """``{vehicle: node}`` for the given actions, and the vehicles whose action was invalid
        (they stay where they are) with the sentence saying why. ``masks``: the
        :meth:`action_masks` of these vehicles, where the caller has them already."""
        targets, invalid = {}, {}
        masks = self.action_masks(observation, list(actions)) if masks is None else masks
        for (v, action), mask in zip(actions.items(), masks):
            here = observation.positions[v]
            action = int(action)
            if not 0 <= action < self.n_actions:
                invalid[v] = f"action {action} is not one of 0..{self.n_actions - 1}"
            elif not mask[action]:
                invalid[v] = (
                    f"action {action} ({self.describe(action)}) leads off the water or beyond the "
                    "remaining budget"
                )
            if v in invalid:
                targets[v] = here
            elif self.mode == SEQUENTIAL:
                targets[v] = int(self.action_nodes[here, action])
            else:
                targets[v] = action
        return targets, invalid

    def describe(self, action: int) -> str:
        return COMPASS[action] if self.mode == SEQUENTIAL else f"node {action}"

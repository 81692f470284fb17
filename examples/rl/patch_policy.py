"""A small policy over guadal's observation images, in numpy and as an ONNX graph.

The policy scores each of the 9 sequential actions (stay, N, NE, ... NW) from what lies in that
direction: for every channel, the mean over a few boxes along the direction (the cell the action
leads to, a 3x3 box two cells out, a 7x7 box five cells out). The same small network scores
every direction (21 features -> ``hidden`` ReLU units -> 1), so it has few weights and needs no
notion of where on the lake it is: it finds the vehicle in its ``position`` channel.

``scores(params, images)`` (numpy, for training) and ``to_onnx(params, ...)`` (MatMul, Add,
Relu, ArgMax, Gather...: what onnxruntime runs in ``algorithm: {type: policy}``) compute the
same numbers; ``tests/rl`` checks that they agree.
"""

from __future__ import annotations

import json

import numpy as np

#: (cells out along the action's direction, radius of the box averaged there)
BOXES = ((1, 0), (2, 1), (5, 3))
RADIUS = max(m + r for m, r in BOXES)  # the patch read around the vehicle: 17 x 17 cells
OFFSETS = ((0, 0), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))


def box_matrix() -> np.ndarray:
    """(patch cells, 9 directions * boxes): each column averages one box of the patch."""
    side = 2 * RADIUS + 1
    out = np.zeros((side * side, len(OFFSETS) * len(BOXES)), dtype=np.float32)
    for d, (dr, dc) in enumerate(OFFSETS):
        for b, (m, r) in enumerate(BOXES):
            cr, cc = RADIUS + dr * m, RADIUS + dc * m
            cells = [(cr + i) * side + (cc + j) for i in range(-r, r + 1) for j in range(-r, r + 1)]
            out[cells, d * len(BOXES) + b] = 1.0 / len(cells)
    return out


def n_params(channels: int, hidden: int) -> int:
    features = channels * len(BOXES)
    return features * hidden + hidden + hidden + 1


def unpack(params: np.ndarray, channels: int, hidden: int):
    features = channels * len(BOXES)
    p = np.asarray(params, dtype=np.float32)
    w1 = p[: features * hidden].reshape(features, hidden)
    at = features * hidden
    b1, w2, b2 = p[at : at + hidden], p[at + hidden : at + 2 * hidden].reshape(hidden, 1), p[-1:]
    return w1, b1, w2, b2


def features(images: np.ndarray, matrix: np.ndarray | None = None) -> np.ndarray:
    """(vehicles, 9, channels * boxes): box means per direction, per channel."""
    matrix = box_matrix() if matrix is None else matrix
    n, c, h, w = images.shape
    padded = np.zeros((n, c, h + 2 * RADIUS, w + 2 * RADIUS), dtype=np.float32)
    padded[:, :, RADIUS : RADIUS + h, RADIUS : RADIUS + w] = images
    side = 2 * RADIUS + 1
    where = images[:, 0].reshape(n, -1).argmax(axis=1)
    rows, cols = where // w, where % w
    patches = np.stack([padded[i, :, r : r + side, q : q + side] for i, (r, q) in enumerate(zip(rows, cols))])
    feats = patches.reshape(n, c, side * side) @ matrix  # (n, c, 9 * boxes)
    return feats.reshape(n, c, len(OFFSETS), len(BOXES)).transpose(0, 2, 1, 3).reshape(n, len(OFFSETS), -1)


def scores(
    params: np.ndarray, images: np.ndarray, hidden: int, matrix: np.ndarray | None = None
) -> np.ndarray:
    """(vehicles, 9) action scores."""
    w1, b1, w2, b2 = unpack(params, images.shape[1], hidden)
    return (np.maximum(features(images, matrix) @ w1 + b1, 0.0) @ w2 + b2)[..., 0]


def to_onnx(params: np.ndarray, shape: tuple[int, int, int], hidden: int, metadata: dict):
    """The same policy as an ONNX model: input ``observations`` (batch, C, rows, cols), output
    ``scores`` (batch, 9); ``metadata`` is stored under the key ``guadal``."""
    from onnx import TensorProto, helper, numpy_helper

    c, h, w = shape
    side = 2 * RADIUS + 1
    wp = w + 2 * RADIUS
    w1, b1, w2, b2 = unpack(params, c, hidden)
    cells = np.array([i * wp + j for i in range(side) for j in range(side)], dtype=np.int64)
    consts = {
        "W": np.array([w], np.int64),
        "WP": np.array([wp], np.int64),
        "cells": cells.reshape(1, 1, -1),
        "pads": np.array([0, 0, RADIUS, RADIUS, 0, 0, RADIUS, RADIUS], np.int64),
        "flat_own": np.array([0, h * w], np.int64),
        "flat_padded": np.array([0, c, (h + 2 * RADIUS) * wp], np.int64),
        "ch0": np.array([0], np.int64),
        "ch1": np.array([1], np.int64),
        "one": np.array([1], np.int64),
        "two": np.array([2], np.int64),
        "n_cells": np.array([side * side], np.int64),
        "split": np.array([0, c, len(OFFSETS), len(BOXES)], np.int64),
        "merge": np.array([0, len(OFFSETS), c * len(BOXES)], np.int64),
        "to_scores": np.array([0, len(OFFSETS)], np.int64),
        "boxes": box_matrix(),
        "w1": w1,
        "b1": b1,
        "w2": w2,
        "b2": b2,
    }
    n = helper.make_node
    nodes = [
        # where the vehicle is: the argmax of its position channel
        n("Slice", ["observations", "ch0", "ch1", "one"], ["own"]),
        n("Reshape", ["own", "flat_own"], ["own_flat"]),
        n("ArgMax", ["own_flat"], ["at"], axis=1, keepdims=1),  # (batch, 1)
        n("Div", ["at", "W"], ["row"]),
        n("Mod", ["at", "W"], ["col"]),
        n("Mul", ["row", "WP"], ["row_start"]),
        n("Add", ["row_start", "col"], ["corner"]),  # the patch's top-left cell in the padded grid
        n("Unsqueeze", ["corner", "two"], ["corner3"]),  # (batch, 1, 1)
        n("Add", ["corner3", "cells"], ["index1"]),  # (batch, 1, cells)
        # the patch of every channel around it
        n("Pad", ["observations", "pads"], ["padded"]),
        n("Reshape", ["padded", "flat_padded"], ["padded_flat"]),  # (batch, C, Hp * Wp)
        n("Shape", ["padded_flat"], ["padded_shape"]),
        n("Slice", ["padded_shape", "ch0", "two", "ch0"], ["batch_c"]),
        n("Concat", ["batch_c", "n_cells"], ["index_shape"], axis=0),
        n("Expand", ["index1", "index_shape"], ["index"]),
        n("GatherElements", ["padded_flat", "index"], ["patch"], axis=2),  # (batch, C, cells)
        # box means per direction, then the shared scorer
        n("MatMul", ["patch", "boxes"], ["box_means"]),  # (batch, C, 9 * boxes)
        n("Reshape", ["box_means", "split"], ["split4"]),
        n("Transpose", ["split4"], ["by_direction"], perm=[0, 2, 1, 3]),
        n("Reshape", ["by_direction", "merge"], ["feats"]),  # (batch, 9, C * boxes)
        n("MatMul", ["feats", "w1"], ["h_pre"]),
        n("Add", ["h_pre", "b1"], ["h_bias"]),
        n("Relu", ["h_bias"], ["hidden"]),
        n("MatMul", ["hidden", "w2"], ["out_pre"]),
        n("Add", ["out_pre", "b2"], ["out"]),
        n("Reshape", ["out", "to_scores"], ["scores"]),
    ]
    graph = helper.make_graph(
        nodes,
        "guadal_patch_policy",
        [helper.make_tensor_value_info("observations", TensorProto.FLOAT, ["batch", c, h, w])],
        [helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["batch", len(OFFSETS)])],
        [numpy_helper.from_array(np.ascontiguousarray(v), k) for k, v in consts.items()],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="guadal")
    model.ir_version = 8
    helper.set_model_props(model, {"guadal": json.dumps(metadata)})
    return model

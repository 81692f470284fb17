"""Small policies for the rl tests: ONNX files written with onnx's helpers, and callables."""

from __future__ import annotations

import json

import numpy as np


def linear_onnx(path, input_shape, n_actions: int, seed: int = 0, metadata: dict | None = None, batch="n"):
    """A random linear policy (flatten, MatMul, Add) over inputs of ``input_shape``, saved to ``path``;
    action 0 (stay, in sequential mode) is scored far down, so that boats keep moving."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    size = int(np.prod(input_shape))
    w = numpy_helper.from_array(rng.normal(size=(size, n_actions)).astype(np.float32), "w")
    bias = np.zeros(n_actions, np.float32)
    bias[0] = -1e4
    b = numpy_helper.from_array(bias, "b")
    graph = helper.make_graph(
        [
            helper.make_node("Flatten", ["obs"], ["flat"], axis=1),
            helper.make_node("MatMul", ["flat", "w"], ["xw"]),
            helper.make_node("Add", ["xw", "b"], ["scores"]),
        ],
        "linear_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, [batch, *input_shape])],
        [helper.make_tensor_value_info("scores", TensorProto.FLOAT, [batch, n_actions])],
        [w, b],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    if metadata:
        helper.set_model_props(model, {"guadal": json.dumps(metadata)})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def std_ahead(observations: np.ndarray) -> np.ndarray:
    """A hand-written sequential policy: each action scores the std channel of the cell it leads to."""
    from guadal_cli.rl.observation import OFFSETS

    n, _, rows, cols = observations.shape
    scores = np.zeros((n, len(OFFSETS)), dtype=np.float32)
    for i in range(n):
        r, c = np.unravel_index(int(np.argmax(observations[i, 0])), (rows, cols))
        for a, (dr, dc) in enumerate(OFFSETS):
            if 0 <= r + dr < rows and 0 <= c + dc < cols:
                scores[i, a] = observations[i, 3, r + dr, c + dc]
    return scores


def wrong_width(observations: np.ndarray) -> np.ndarray:
    """A broken policy: five scores per vehicle where nine are due."""
    return np.zeros((observations.shape[0], 5), dtype=np.float32)


def everything_north(observations: np.ndarray) -> np.ndarray:
    """Scores north highest everywhere, land or not: the planner's mask must keep boats on water."""
    scores = np.zeros((observations.shape[0], 9), dtype=np.float32)
    scores[:, 1] = 10.0
    return scores


#: every batch ``recording_std_ahead`` was called with, in order
SEEN: list[np.ndarray] = []


def recording_std_ahead(observations: np.ndarray) -> np.ndarray:
    """``std_ahead``, keeping a copy of what it was shown."""
    SEEN.append(observations.copy())
    return std_ahead(observations)

"""Trained policies as plain functions: a batch of observations in, a batch of action scores out.

A policy is an ONNX file (run by onnxruntime) or a Python callable named ``module:function``.
Either takes float32 observations of shape ``(vehicles, C, rows, cols)`` (image layout) or
``(vehicles, size)`` (vector layout), as :class:`~guadal_cli.rl.observation.ObservationBuilder`
builds them, and returns ``(vehicles, n_actions)`` scores (logits); the planner masks invalid
actions and takes the best. An ONNX file may say how it was trained in its metadata under the
key ``guadal`` (JSON: ``mode``, ``fields``, ``layout``), which the planner then checks against
the mission.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import GuadalError
from ..maps.format import checked_path
from ..plugins import import_object

#: the metadata key an exported policy's training settings are stored under
METADATA_KEY = "guadal"
INSTALL_HINT = "install it with: pip install 'guadal[rl]'"


@dataclass
class Policy:
    """A loaded policy: ``scores = policy(observations)``."""

    source: str
    function: object
    layout: str  # image or vector
    input_shape: tuple | None = None  # without the batch dimension; None when unknown
    metadata: dict = field(default_factory=dict)

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        return np.asarray(self.function(np.ascontiguousarray(observations, dtype=np.float32)))


def is_callable_name(spec: str) -> bool:
    """``module:function`` (a callable) rather than a file path."""
    module, sep, attr = spec.partition(":")
    return bool(sep) and module.replace(".", "").replace("_", "").isalnum() and attr.isidentifier()


def resolve_source(spec: str, base_dir: Path | None) -> str:
    """An ONNX path made absolute against the mission's folder; a callable name unchanged."""
    if is_callable_name(spec):
        return spec
    checked_path(spec, "the policy file")
    path = Path(spec)
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return os.path.abspath(path)


def load_policy(source: str, layout: str = "image") -> Policy:
    """The policy at ``source`` (a resolved path or ``module:function``); one sentence on error."""
    if is_callable_name(source):
        return Policy(source, _import_callable(source), layout)
    return _load_onnx(Path(source))


def _import_callable(name: str):
    obj = import_object(name, f"the policy '{name}'", noun="policy", example="package.module:function")
    if not callable(obj):
        raise GuadalError(f"'{name}' is a {type(obj).__name__}, not a function taking observations.")
    return obj


def _load_onnx(path: Path) -> Policy:
    if path.suffix.lower() != ".onnx":
        raise GuadalError(
            f"'{path.name}' is neither an .onnx file nor a 'module:function' name; give one of the two."
        )
    try:
        exists = path.is_file()
    except OSError as exc:
        raise GuadalError(f"cannot read the policy file '{path}' ({exc.strerror or exc}).") from exc
    if not exists:
        raise GuadalError(f"the policy file '{path}' does not exist.")
    try:
        import onnxruntime as ort
    except ImportError:
        raise GuadalError(
            f"reading an ONNX policy needs onnxruntime, which is not installed; {INSTALL_HINT}."
        ) from None
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1  # one core per mission, as the model updates use
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own types for every kind of bad file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise GuadalError(f"the policy file '{path.name}' is not a readable ONNX model ({first}).") from exc
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if len(inputs) != 1 or not outputs:
        raise GuadalError(
            f"the policy '{path.name}' has {len(inputs)} inputs; a policy takes one (the observations)."
        )
    shape = tuple(d if isinstance(d, int) else None for d in inputs[0].shape[1:])
    layout = {3: "image", 1: "vector"}.get(len(shape))
    if layout is None:
        raise GuadalError(
            f"the policy '{path.name}' takes input of rank {len(shape) + 1}; a policy takes "
            "(vehicles, channels, rows, cols) images or (vehicles, size) vectors."
        )
    meta = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    try:
        metadata = json.loads(meta) if meta else {}
    except ValueError:
        metadata = {}
    in_name = inputs[0].name

    def run(batch: np.ndarray) -> np.ndarray:
        return session.run(None, {in_name: batch})[0]

    return Policy(str(path), run, layout, shape, metadata if isinstance(metadata, dict) else {})

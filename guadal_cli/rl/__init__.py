"""Reinforcement learning over guadal missions (the ``rl`` extra: Gymnasium, PettingZoo, ONNX).

- :mod:`.observation`: what a policy sees and what its actions mean (numpy only), shared by the
  environments and the ``policy`` planner, so training and deployment see identical inputs;
- :mod:`.policy`: trained policies (ONNX files or ``module:function``) as plain functions;
- :mod:`.env`: :class:`MissionParallelEnv` (PettingZoo) and :class:`MissionEnv` (Gymnasium,
  registered as ``guadal/Mission-v0``), both driving :class:`guadal_cli.episode.Episode`.

The environments are imported on first use, so the planner works without Gymnasium installed.
"""

from __future__ import annotations

_LAZY = {"MissionParallelEnv": ".env", "MissionEnv": ".env", "RewardConfig": ".rewards"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""Reinforcement learning over guadal missions (the ``rl`` extra: Gymnasium, PettingZoo, ONNX).

- :mod:`.observation`: what a policy sees and what its actions mean (numpy only), shared by the
  environments and the ``policy`` planner, so training and deployment see identical inputs;
- :mod:`.policy`: trained policies (ONNX files or ``module:function``) as plain functions;
- :mod:`.env`: :class:`MissionParallelEnv` (PettingZoo) and :class:`MissionEnv` (Gymnasium,
  registered as ``guadal/Mission-v0``), both driving :class:`guadal_cli.episode.Episode`.

The environments are imported on first use, so the planner works without Gymnasium installed;
where Gymnasium is installed, importing this package registers ``guadal/Mission-v0`` (its entry
point is a string: the environment module loads only when ``gymnasium.make`` builds one).
"""

from __future__ import annotations

#: the Gymnasium id of :class:`MissionEnv`
GYM_ID = "guadal/Mission-v0"

try:
    import gymnasium as _gymnasium
except ImportError:  # deploying a policy needs no Gymnasium
    _gymnasium = None
if _gymnasium is not None and GYM_ID not in _gymnasium.registry:
    _gymnasium.register(GYM_ID, entry_point="guadal_cli.rl.env:MissionEnv")

_LAZY = {"MissionParallelEnv": ".env", "MissionEnv": ".env", "RewardConfig": ".rewards"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

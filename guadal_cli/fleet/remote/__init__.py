"""The remote levels (``sitl``, ``real``): the Fleet contract over MQTT to one bridge per boat.

    config.py    the backend settings (secrets only by file or environment variable)
    state.py     what the planner knows of each vehicle and each command in flight
    owner.py     FleetOwner: the one loop that owns that state, fed by one queue
    fleet.py     RemoteFleet: the Fleet contract, as requests to the owner
    backends.py  the ``sitl`` (optionally launching a stack) and ``real`` entry points

The wire protocol, the MQTT channel, sessions and broker credentials are shared with the
bridges and live in :mod:`guadal_cli.channel`.
"""

from .backends import RealBackend, SitlBackend
from .config import RealConfig, RemoteConfig, SitlConfig
from .fleet import RemoteFleet

__all__ = ["RealBackend", "RealConfig", "RemoteConfig", "RemoteFleet", "SitlBackend", "SitlConfig"]

"""The ``sitl`` and ``real`` levels: each makes a RemoteFleet; ``sitl`` may launch its own stack."""

from __future__ import annotations

from ...errors import GuadalError
from ...graph import NavGraph
from ..base import Backend, Fleet, Sensor
from .config import RealConfig, RemoteConfig, SitlConfig
from .fleet import RemoteFleet


def _fleet(config: RemoteConfig, graph, fleet_config, sensor, **kw) -> RemoteFleet:
    return RemoteFleet(graph, fleet_config.vehicles, fleet_config.max_distance, sensor, config, **kw)


class SitlBackend(Backend):
    """Entry point of the ``sitl`` level; with ``launch: true`` it owns a whole stack for the run."""

    Config = SitlConfig

    def make_fleet(self, *, graph: NavGraph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        cfg = self.config
        if not cfg.launch:
            return _fleet(cfg, graph, fleet_config, sensor)
        from ...stack import Autopilot, Stack

        if mission is None or getattr(graph.map, "source", None) is None:
            raise GuadalError("backend.launch needs the mission's map file to start the bridges.")
        nodes = mission.resume_nodes or mission.initial_nodes
        homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in nodes]
        stack = Stack.launch(
            map_path=graph.map.source,
            vehicles=fleet_config.vehicles,
            homes=homes,
            speedup=cfg.speedup,
            fleet=cfg.fleet,
            broker_kind=cfg.broker_kind,
            failsafe_timeout=cfg.failsafe_timeout,
            emulator_args=cfg.emulator_args,
            bridge_args=cfg.bridge_args,
            timeout=cfg.stack_timeout,
            autopilot=Autopilot(
                kind=cfg.autopilot,
                binary=cfg.binary,
                defaults=cfg.defaults,
                mavproxy=cfg.mavproxy,
                speed=fleet_config.speed,
                track_rate=cfg.track_rate,
            ),
        )
        try:
            # the stack's own generated planner user and fleet key: nothing secret leaves it
            launched = cfg.model_copy(
                update={
                    "host": stack.broker_host,
                    "port": stack.broker_port,
                    "tls": False,
                    "username": "planner",
                    "password_file": str(stack.secrets.user_password_file("planner")),
                    "password_env": None,
                    "key_file": str(stack.secrets.key_file),
                    "key_env": None,
                }
            )
            return _fleet(launched, graph, fleet_config, sensor, on_close=stack.down)
        except BaseException:
            stack.down()
            raise


class RealBackend(Backend):
    """Entry point of the ``real`` level: the same RemoteFleet, with field-sized timeouts."""

    Config = RealConfig

    def make_fleet(self, *, graph: NavGraph, fleet_config, sensor: Sensor, mission=None) -> Fleet:
        return _fleet(self.config, graph, fleet_config, sensor)

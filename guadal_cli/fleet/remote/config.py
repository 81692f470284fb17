"""The ``sitl`` and ``real`` backend settings (the mission's ``backend:`` section).

Secrets never sit in a mission file: the broker password and the fleet key come from a file
or an environment variable, are held as :class:`~pydantic.SecretStr`-backed values only while
connecting, and the settings written to ``mission.resolved.yaml`` name only where they live.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, SecretStr, model_validator

from ...channel.client import Endpoint
from ...channel.credentials import fleet_key, read_secret
from ..track import DEFAULT_TRACK_RATE_HZ


class RemoteConfig(BaseModel):
    """Settings shared by the ``sitl`` and ``real`` backends."""

    model_config = ConfigDict(extra="forbid")
    level: str
    host: str = Field(default="127.0.0.1", description="MQTT broker host name or address.")
    port: int = Field(default=1883, ge=1, le=65535, description="MQTT broker port (8883 is usual with TLS).")
    username: str | None = Field(default=None, description="Broker user name (the ACL's planner user).")
    password_file: str | None = Field(default=None, description="File holding the broker password.")
    password_env: str | None = Field(
        default=None, description="Environment variable holding the broker password."
    )
    key_file: str | None = Field(
        default=None, description="File holding the fleet key that signs every message."
    )
    key_env: str | None = Field(default=None, description="Environment variable holding the fleet key.")
    tls: bool = Field(default=False, description="Connect with TLS.")
    ca_file: str | None = Field(
        default=None, description="CA certificate file for TLS; default: the system's."
    )
    client_id: str | None = Field(default=None, description="MQTT client id; default: a unique one per run.")
    keepalive: int = Field(default=10, ge=1, le=3600, description="MQTT keepalive, seconds.")
    fleet: str = Field(
        default="guadal", min_length=1, description="Topic prefix shared with the bridges (--fleet)."
    )
    measurements: Literal["synthetic", "vehicle"] = Field(
        default="synthetic", description="synthetic: the environment's sensor; vehicle: ask each bridge."
    )
    arrival_radius: float = Field(
        default=4.0,
        gt=0,
        description="Metres from a node within which a 'reached' ack and the vehicle's telemetry must "
        "place it (at least the bridges' arrival radius and WP_RADIUS).",
    )
    connect_timeout: float = Field(
        default=20.0, gt=0, description="Seconds to reach the broker and see every vehicle online."
    )
    reset_timeout: float = Field(
        default=300.0, gt=0, description="Seconds for the vehicles to reach their start nodes."
    )
    track_rate: float = Field(
        default=DEFAULT_TRACK_RATE_HZ,
        gt=0,
        le=50,
        description="GPS fixes recorded per second of the vehicle's own clock (simulated time at sitl, "
        "whatever the speed-up); stated in the run manifest.",
    )
    hop_timeout: float = Field(default=60.0, gt=0, description="Seconds for one hop (one graph edge).")
    measure_timeout: float = Field(default=30.0, gt=0, description="Seconds for a measurement to come back.")
    offline_grace: float = Field(
        default=10.0,
        gt=0,
        description="Seconds a vehicle whose bridge went offline may take to come back before it is lost.",
    )
    ping_interval: float = Field(
        default=1.0,
        gt=0,
        description="Seconds between messages to each bridge: its unanswered command again, or a ping.",
    )

    def endpoint(self, password: SecretStr | None = None) -> Endpoint:
        """Where and who the planner is on the broker (the password read now, from its source)."""
        if password is None:
            secret = read_secret(file=self.password_file, env=self.password_env, what="backend.password")
            password = SecretStr(secret) if secret is not None else None
        return Endpoint(self.host, self.port, self.tls, self.ca_file, self.username, password)

    def fleet_key(self) -> bytes | None:
        return fleet_key(file=self.key_file, env=self.key_env, what="backend.key")


class SitlConfig(RemoteConfig):
    """Backend ``sitl``: MAVLink boats in software behind real bridges and a real broker."""

    level: str = "sitl"
    measurements: Literal["synthetic", "vehicle"] = "synthetic"
    launch: bool = Field(
        default=False, description="Start broker, emulator and bridges for this run, and stop them after."
    )
    speedup: float = Field(
        default=50.0, gt=0, le=1000, description="Emulator time speed-up when launching (at most 1000)."
    )
    broker_kind: Literal["auto", "mosquitto", "embedded"] = Field(
        default="auto", description="Broker to launch: Mosquitto if installed (auto), or the embedded one."
    )
    failsafe_timeout: float = Field(
        default=30.0, gt=0, description="Bridges' comms-loss failsafe when launching, seconds."
    )
    autopilot: Literal["guadal", "ardupilot"] = Field(
        default="guadal",
        description="What flies each boat when launching: guadal's MAVLink emulator, or ArduPilot's own SITL "
        "(ardurover, started per boat as sim_vehicle.py would; see docs/ardupilot.md).",
    )
    binary: str | None = Field(
        default=None,
        description="autopilot ardupilot: path of ArduPilot's SITL binary (build/sitl/bin/ardurover).",
    )
    defaults: list[str] = Field(
        default_factory=list,
        description="autopilot ardupilot: ArduPilot parameter files read before guadal's own (e.g. rover.parm, motorboat.parm).",
    )
    mavproxy: bool = Field(
        default=False,
        description="autopilot ardupilot: also start MAVProxy per boat, forwarding to UDP 14550+10i for a ground station.",
    )
    emulator_args: list[str] = Field(
        default_factory=list,
        description="Extra options for the autopilot program ('guadal sitl' or ardurover) when launching.",
    )
    bridge_args: list[str] = Field(
        default_factory=list, description="Extra 'guadal bridge' options when launching."
    )
    stack_timeout: float = Field(
        default=60.0, gt=0, description="Seconds for a launched stack to become ready."
    )

    @model_validator(mode="after")
    def _ardupilot_needs_its_binary(self):
        if self.launch and self.autopilot == "ardupilot" and not self.binary:
            raise ValueError(
                "autopilot ardupilot needs binary: the path of ArduPilot's SITL rover (build/sitl/bin/ardurover)"
            )
        return self


class RealConfig(RemoteConfig):
    """Backend ``real``: physical boats; their bridges run on the companion computers."""

    level: str = "real"
    measurements: Literal["synthetic", "vehicle"] = "vehicle"
    hop_timeout: float = 600.0
    reset_timeout: float = 1800.0
    connect_timeout: float = 60.0
    offline_grace: float = 120.0

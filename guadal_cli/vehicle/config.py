"""The bridge's settings: command-line options over an optional YAML file, checked once.

The YAML file uses the option names with underscores (``vehicle_id``, ``failsafe_timeout``...);
a relative ``map`` or sensor path in it is relative to the file, so a deployment directory can
be moved as a whole. Options given on the command line win over the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..channel.client import Endpoint
from ..channel.credentials import fleet_key, read_secret
from ..errors import GuadalError, explain_validation_error
from ..fleet.track import DEFAULT_TRACK_RATE_HZ


class BridgeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    vehicle_id: int = Field(ge=0, description="Vehicle number N in the topics F/vehicle/N/...")
    mavlink: str = Field(
        description="pymavlink connection string: tcp:HOST:PORT, udpin:HOST:PORT, /dev/ttyACM0..."
    )
    baud: int = Field(default=115200, gt=0, description="Baud rate of a serial autopilot link.")
    broker: str = Field(
        default="mqtt://127.0.0.1:1883", description="mqtt://[user@]host:port, or mqtts:// for TLS."
    )
    password_file: str | None = Field(default=None, description="File holding the broker password.")
    password_env: str | None = Field(
        default=None, description="Environment variable holding the broker password."
    )
    key_file: str | None = Field(
        default=None, description="File holding the fleet key that signs every message."
    )
    key_env: str | None = Field(default=None, description="Environment variable holding the fleet key.")
    map: str = Field(description="The guadal map file the planner uses.")
    fleet: str = Field(default="guadal", min_length=1, description="Topic prefix shared with the planner.")
    sensor: str | dict | None = Field(default=None, description="NAME:VALUE or {type: NAME, ...}.")
    arm: bool = Field(default=False, description="Arm at start-up (retried until the autopilot agrees).")
    guided: bool = Field(default=False, description="Set GUIDED at start-up.")
    failsafe_timeout: float = Field(default=10.0, gt=0, description="Seconds of planner silence before HOLD.")
    arrival_radius: float = Field(
        default=2.0, gt=0, description="Metres from the target that count as reached."
    )
    telemetry_hz: float = Field(default=2.0, gt=0, le=50)
    track_rate: float = Field(
        default=DEFAULT_TRACK_RATE_HZ,
        gt=0,
        le=50,
        description="GPS fixes published per second of the autopilot's own clock (simulated time in SITL).",
    )
    refine: int = Field(
        default=3, ge=1, le=10, description="High-resolution factor of the path-planning grid."
    )
    waypoint_command: Literal["position_target", "mission_item"] = Field(
        default="position_target",
        description="SET_POSITION_TARGET_GLOBAL_INT (silent) or MISSION_ITEM_INT current=2 (acknowledged).",
    )
    arm_retry_interval: float = Field(default=5.0, gt=0)
    hold_on_exit: bool = Field(default=True, description="Put the vehicle in HOLD when the bridge stops.")
    connect_timeout: float = Field(
        default=60.0, gt=0, description="Seconds to wait for the autopilot's heartbeat."
    )
    source_system: int = Field(default=255, ge=1, le=255, description="MAVLink system id of the bridge.")
    tls_ca: str | None = Field(
        default=None, description="CA certificate file for mqtts:// (default: system CAs)."
    )
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    # where relative paths in the file are resolved (not a user setting)
    base_dir: Path | None = Field(default=None, exclude=True)
    sensor_base_dir: Path | None = Field(default=None, exclude=True)

    def map_path(self) -> Path:
        return self._resolve(self.map)

    def _resolve(self, name: str) -> Path:
        p = Path(name).expanduser()
        return p if p.is_absolute() or self.base_dir is None else self.base_dir / p

    def endpoint(self) -> Endpoint:
        """The broker and our login; the password from its file or variable, never logged."""
        password = read_secret(
            file=self._resolve(self.password_file) if self.password_file else None,
            env=self.password_env,
            what="password",
        )
        return Endpoint.from_url(self.broker, password=password, ca_file=self.tls_ca)

    def fleet_key(self) -> bytes | None:
        return fleet_key(
            file=self._resolve(self.key_file) if self.key_file else None,
            env=self.key_env,
            what="key",
        )


def load_config(path: Path | None, overrides: dict) -> BridgeConfig:
    """The file's settings (if any) with the command-line ``overrides`` (None = not given) on top."""
    data: dict = {}
    where = "bridge settings"
    if path is not None:
        where = f"config file '{path}'"
        if not path.is_file():
            raise GuadalError(f"{where} does not exist.")
        try:
            loaded = yaml.safe_load(path.read_text())
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise GuadalError(f"{where} is not readable YAML ({exc.__class__.__name__}).") from exc
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise GuadalError(
                f"{where} must be a mapping of settings (vehicle_id: 0, mavlink: ..., map: ...)."
            )
        data.update(loaded)
        data["base_dir"] = path.parent
        data["sensor_base_dir"] = path.parent
    data.update({k: v for k, v in overrides.items() if v is not None})
    if overrides.get("sensor") is not None:
        data["sensor_base_dir"] = None  # a path typed on the command line is relative to where it was typed
    try:
        config = BridgeConfig(**data)
    except ValidationError as exc:
        raise GuadalError(explain_validation_error(exc, BridgeConfig, prefix=where)) from exc
    config.endpoint()  # a bad URL, or a missing password or key file, is said before anything starts
    config.fleet_key()
    return config

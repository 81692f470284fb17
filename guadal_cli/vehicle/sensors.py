"""Sensor sources for the bridge: plugins of the entry-point group ``guadal.sensors``, each a
:class:`~guadal_cli.vehicle.base.Sensor` (the contract, in ``base.py``).

Built in:

- ``synthetic``: a ground-truth CSV grid of the map's shape (the ``file`` ground truth's
  format), read at the map cell under the boat, plus optional Gaussian noise.
- ``replay``: a CSV of past samples (``lat,lon,value`` or ``node,value``); the sample nearest
  to the boat is returned.
- ``serial``: a probe on a serial port speaking one line per reading: the bridge writes
  ``READ\\n``; the probe answers ``VALUE <number>\\n`` or ``ERR <text>\\n``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from ..errors import GuadalError
from ..graph import NavGraph
from .base import Sensor


class SensorError(Exception):
    """A reading that could not be taken, in one sentence."""


@dataclass
class SensorContext:
    """What a sensor may need to know about where it is used."""

    graph: NavGraph
    base_dir: Path | None = None


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _resolve(path: str, base_dir: Path | None) -> Path:
    p = Path(path).expanduser()
    return p if p.is_absolute() or base_dir is None else base_dir / p


class SyntheticSensor(Sensor):
    """Ground truth from a CSV grid, so a SITL boat measures what the simulation would."""

    cli_field = "path"

    class Config(_Config):
        path: str = Field(description="CSV grid of the map's shape (water cells must be numbers).")
        noise_std: float = Field(default=0.0, ge=0, description="Standard deviation of added Gaussian noise.")
        seed: int | None = Field(default=None, description="Seed of the noise generator.")

    def __init__(self, config: SyntheticSensor.Config, context: SensorContext):
        from ..envs.ground_truth import FileField

        self.config = config
        self.graph = context.graph
        field = FileField(FileField.Config(path=str(_resolve(config.path, context.base_dir))))
        try:
            self.values = field.generate(context.graph, np.random.default_rng(0))
        except GuadalError as exc:
            raise exc.within("sensor") from None
        self.rng = np.random.default_rng(config.seed)

    def read(self, lat: float, lon: float) -> float:
        value = float(self.values[self.graph.nearest_node(lat, lon)])
        if self.config.noise_std > 0:
            value += float(self.rng.normal(0.0, self.config.noise_std))
        return value


class ReplaySensor(Sensor):
    """Values recorded on an earlier survey, played back at the nearest recorded place."""

    cli_field = "path"

    class Config(_Config):
        path: str = Field(description="CSV with a header: lat,lon,value or node,value.")

    def __init__(self, config: ReplaySensor.Config, context: SensorContext):
        path = _resolve(config.path, context.base_dir)
        where = f"sensor replay: '{path}'"
        if not path.is_file():
            raise GuadalError(f"{where} does not exist.")
        try:
            rows = list(csv.DictReader(path.read_text().splitlines()))
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise GuadalError(f"{where} is not a readable CSV ({exc}).") from exc
        graph = context.graph
        columns = set(rows[0]) if rows else set()
        xy, values = [], []
        for i, row in enumerate(rows, start=2):
            try:
                value = float(row["value"])
                if {"lat", "lon"} <= columns:
                    x, y = graph.map.projection.to_xy(float(row["lat"]), float(row["lon"]))
                    point = (float(x), float(y))
                elif "node" in columns:
                    node = int(row["node"])
                    if not 0 <= node < graph.n_nodes:
                        raise GuadalError(
                            f"{where} line {i}: node {node} is not on the map (0..{graph.n_nodes - 1})."
                        )
                    point = tuple(graph.xy[node])
                else:
                    raise KeyError("lat")
            except (KeyError, TypeError, ValueError):
                raise GuadalError(
                    f"{where} line {i} must give numbers under a header of lat,lon,value or node,value."
                ) from None
            if not math.isfinite(value):
                raise GuadalError(f"{where} line {i}: value must be a finite number.")
            xy.append(point)
            values.append(value)
        if not values:
            raise GuadalError(
                f"{where} has no samples (header lat,lon,value or node,value, then one row each)."
            )
        self.values = np.array(values)
        self.projection = graph.map.projection
        self.tree = cKDTree(np.array(xy))

    def read(self, lat: float, lon: float) -> float:
        x, y = self.projection.to_xy(lat, lon)
        return float(self.values[self.tree.query([float(x), float(y)])[1]])


class SerialSensor(Sensor):
    """A probe on a serial line: ``READ\\n`` → ``VALUE <number>\\n`` or ``ERR <text>\\n``."""

    cli_field = "port"

    class Config(_Config):
        port: str = Field(description="Serial device (/dev/ttyUSB0) or a pyserial URL.")
        baud: int = Field(default=9600, gt=0)
        timeout: float = Field(default=2.0, gt=0, description="Seconds to wait for the answer.")
        command: str = Field(default="READ", description="Line sent to ask for one reading.")

    def __init__(self, config: SerialSensor.Config, context: SensorContext):
        import serial

        self.config = config
        try:
            self.port = serial.serial_for_url(config.port, baudrate=config.baud, timeout=config.timeout)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise GuadalError(f"sensor serial: cannot open '{config.port}' ({exc}).") from exc

    def read(self, lat: float, lon: float) -> float:
        import serial

        try:
            self.port.reset_input_buffer()  # drop a late answer to an earlier, timed-out request
            self.port.write(f"{self.config.command}\n".encode())
            self.port.flush()
            line = self.port.readline()
        except (serial.SerialException, OSError) as exc:
            raise SensorError(f"serial probe on '{self.config.port}' failed ({exc}).") from exc
        if not line.endswith(b"\n"):
            raise SensorError(
                f"serial probe on '{self.config.port}' did not answer within {self.config.timeout:g} s."
            )
        text = line.decode("ascii", errors="replace").strip()
        word, _, rest = text.partition(" ")
        if word == "VALUE":
            try:
                value = float(rest)
            except ValueError:
                value = math.nan
            if math.isfinite(value):
                return value
        if word == "ERR":
            raise SensorError(
                f"serial probe on '{self.config.port}' reported an error: {rest or 'no reason given'}."
            )
        raise SensorError(
            f"serial probe on '{self.config.port}' answered {text[:60]!r}; expected 'VALUE <number>' or 'ERR <text>'."
        )

    def close(self) -> None:
        self.port.close()


def parse_sensor_option(text: str) -> dict:
    """``NAME:VALUE`` from the command line → a ``{type: NAME, field: VALUE}`` section."""
    from .. import plugins

    name, sep, value = text.partition(":")
    if not sep or not name or not value:
        raise GuadalError(
            f"--sensor '{text}' must be NAME:VALUE, e.g. synthetic:truth.csv, replay:log.csv or serial:/dev/ttyUSB0."
        )
    cls = plugins.load("sensor", name)
    return {"type": name, getattr(cls, "cli_field", "path"): value}


def build_sensor(section, context: SensorContext):
    """The sensor a config section names, built and ready to read."""
    from .. import plugins

    cls, config = plugins.build_config("sensor", section, "sensor")
    return cls(config, context)

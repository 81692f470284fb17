"""The Sensor contract: plugins of the entry-point group ``guadal.sensors`` (the bridge's probes).

A sensor has a pydantic ``Config``, is built as ``cls(config, context)`` and answers
``read(lat, lon) -> float`` for the boat's current position, raising
:class:`~guadal_cli.vehicle.sensors.SensorError` with one sentence when it cannot. ``close()``
releases what it holds. ``cli_field`` names the config field that ``--sensor NAME:VALUE``
fills, so a third-party probe gets the same short form on the command line.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, ClassVar

from pydantic import BaseModel

if TYPE_CHECKING:
    from .sensors import SensorContext


class Sensor(ABC):
    """Reads one value where the boat is."""

    Config: ClassVar[type[BaseModel]]
    cli_field: ClassVar[str]

    def __init__(self, config: BaseModel, context: SensorContext):
        self.config = config

    @abstractmethod
    def read(self, lat: float, lon: float) -> float:
        """The value at the boat's position (raise ``SensorError`` when there is none)."""

    def close(self) -> None:
        """Release ports and files; safe to call twice."""

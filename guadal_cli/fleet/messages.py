"""The MQTT protocol between the planner (RemoteFleet) and the vehicle bridges.

Topics, for fleet ``F`` (default ``guadal``) and vehicle ``N``::

    F/vehicle/N/command      planner -> bridge   goto, measure, hold, ping        QoS 1
    F/vehicle/N/ack          bridge -> planner   accepted, reached, rejected, ... QoS 1
    F/vehicle/N/telemetry    bridge -> planner   position, heading, speed, mode   QoS 0
    F/vehicle/N/measurement  bridge -> planner   one sample, answering "measure"  QoS 1
    F/vehicle/N/status       bridge, retained    online / hold / failsafe; last will: offline
    F/planner/status         planner, retained   online; last will: offline

Every payload is a JSON object with ``"v": 1`` (the protocol version) and a ``"type"``.
Commands carry a ``seq`` that increases per vehicle; acknowledgements and measurements echo
it, so a duplicate or stale reply (an older ``seq``) is recognised and ignored. Anything that
does not parse is rejected by :func:`decode` with one sentence saying why; callers log and
count it and carry on. ``docs/protocol.md`` is the user-facing description.
"""

from __future__ import annotations

import json
import math
import socket

PROTOCOL_VERSION = 1
MAX_PAYLOAD_BYTES = 16_384

COMMAND_TYPES = {"goto", "measure", "hold", "ping"}
ACK_TYPES = {"accepted", "reached", "rejected", "failed"}
STATUS_STATES = {"online", "offline", "hold", "failsafe"}

#: required fields per message type, with the Python types allowed
SCHEMAS: dict[str, dict[str, tuple[type, ...]]] = {
    "goto": {"seq": (int,), "node": (int,), "lat": (int, float), "lon": (int, float)},
    "measure": {"seq": (int,), "node": (int,)},
    "hold": {"seq": (int,)},
    "ping": {"seq": (int,)},
    "ack": {"seq": (int,), "status": (str,)},
    "telemetry": {"t": (int, float), "lat": (int, float), "lon": (int, float)},
    "measurement": {"seq": (int,), "node": (int,), "value": (int, float)},
    "status": {"state": (str,)},
}


class ProtocolError(ValueError):
    """A payload that cannot be used, explained in one sentence."""


def topic(fleet: str, vehicle: int | None, channel: str) -> str:
    if vehicle is None:
        return f"{fleet}/planner/{channel}"
    return f"{fleet}/vehicle/{int(vehicle)}/{channel}"


def parse_topic(fleet: str, name: str) -> tuple[int | None, str]:
    """``(vehicle id or None for the planner, channel)``; raises :class:`ProtocolError`."""
    parts = name.split("/")
    prefix = fleet.split("/")
    if parts[: len(prefix)] != prefix:
        raise ProtocolError(f"topic '{name}' is not under fleet prefix '{fleet}'.")
    rest = parts[len(prefix) :]
    if len(rest) == 2 and rest[0] == "planner":
        return None, rest[1]
    if len(rest) == 3 and rest[0] == "vehicle":
        try:
            return int(rest[1]), rest[2]
        except ValueError as exc:
            raise ProtocolError(f"topic '{name}' has vehicle id '{rest[1]}'; ids are whole numbers.") from exc
    raise ProtocolError(
        f"topic '{name}' is not a guadal topic ({fleet}/vehicle/N/CHANNEL or {fleet}/planner/CHANNEL)."
    )


def encode(kind: str, **fields) -> bytes:
    """A versioned JSON payload; ``kind`` is the message type."""
    return json.dumps({"v": PROTOCOL_VERSION, "type": kind, **fields}, separators=(",", ":")).encode()


def decode(payload: bytes, expected: set[str] | None = None) -> dict:
    """Parse and check a payload; raises :class:`ProtocolError` naming what is wrong."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD_BYTES}-byte limit.")
    try:
        data = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"payload is not UTF-8 JSON ({exc.__class__.__name__}).") from exc
    if not isinstance(data, dict):
        raise ProtocolError("payload must be a JSON object.")
    if data.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(
            f"payload has protocol version {data.get('v')!r}; this guadal speaks version {PROTOCOL_VERSION}."
        )
    kind = data.get("type")
    if kind not in SCHEMAS:
        raise ProtocolError(f"unknown message type {kind!r} (known: {', '.join(sorted(SCHEMAS))}).")
    if expected is not None and kind not in expected:
        raise ProtocolError(
            f"message type '{kind}' is not expected here (expected: {', '.join(sorted(expected))})."
        )
    for name, types in SCHEMAS[kind].items():
        value = data.get(name)
        if isinstance(value, bool) or not isinstance(value, types):
            allowed = " or ".join(t.__name__ for t in types)
            raise ProtocolError(f"'{kind}' message needs field '{name}' of type {allowed} (got {value!r}).")
        if isinstance(value, float) and not math.isfinite(value):
            raise ProtocolError(f"'{kind}' message field '{name}' must be finite (got {value!r}).")
    if kind == "ack" and data["status"] not in ACK_TYPES:
        raise ProtocolError(
            f"ack status {data['status']!r} is unknown (known: {', '.join(sorted(ACK_TYPES))})."
        )
    if kind == "status" and data["state"] not in STATUS_STATES:
        raise ProtocolError(
            f"status state {data['state']!r} is unknown (known: {', '.join(sorted(STATUS_STATES))})."
        )
    if "seq" in data and data["seq"] < 0:
        raise ProtocolError(f"'{kind}' message has negative seq {data['seq']}.")
    return data


def no_delay(client) -> None:
    """Send small MQTT packets at once (call on connect): with Nagle's algorithm on, every
    command and acknowledgement can wait ~40 ms for the previous packet's TCP ack."""
    sock = client.socket()
    if sock is not None and hasattr(sock, "setsockopt"):
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass

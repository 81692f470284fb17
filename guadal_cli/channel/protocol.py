"""The wire protocol between the planner, the vehicle bridges and an operator's console.

Both sides import this module; neither owns it. Topics, for fleet ``F`` (default ``guadal``)
and vehicle ``N``::

    F/vehicle/N/command      planner -> bridge   start, goto, measure, hold, ping   QoS 1
    F/vehicle/N/ack          bridge -> planner   accepted, reached, rejected, ...   QoS 1
    F/vehicle/N/telemetry    bridge -> planner   position, heading, speed, mode     QoS 0
    F/vehicle/N/measurement  bridge -> planner   one sample, answering "measure"    QoS 1
    F/vehicle/N/status       bridge, retained    online / hold / failsafe; last will: offline
    F/planner/status         planner, retained   online + its session; last will: offline
    F/planner/control        operator -> planner pause, resume, abort, hold, release QoS 1

Every payload is a JSON object with ``"v": 1`` (the protocol version) and a ``"type"``. With a
fleet key, every payload also carries ``"sig"``: HMAC-SHA256 over the topic and the canonical
payload (:func:`canonical`), so a message cannot be forged, altered, or moved to another topic.
Commands carry the planner's ``session`` and a ``seq`` that increases per vehicle within it;
the rules a bridge applies to them live in :mod:`guadal_cli.channel.session`. Anything that
does not parse is rejected by :meth:`Codec.decode` with one sentence saying why, and a ``kind``
callers count it under. ``docs/protocol.md`` is the user-facing description.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import math

PROTOCOL_VERSION = 1
MAX_PAYLOAD_BYTES = 16_384

COMMAND_TYPES = {"start", "goto", "measure", "hold", "ping"}
ACK_TYPES = {"accepted", "reached", "rejected", "failed"}
STATUS_STATES = {"online", "offline", "hold", "failsafe"}
CONTROL_ACTIONS = {"pause", "resume", "abort", "hold", "release"}

#: the message types each channel (last topic level) carries
CHANNEL_TYPES: dict[str, set[str]] = {
    "command": COMMAND_TYPES,
    "ack": {"ack"},
    "telemetry": {"telemetry"},
    "measurement": {"measurement"},
    "status": {"status"},
    "control": {"control"},
}

_SESSION = {"session": (str,), "seq": (int,)}
#: required fields per message type, with the Python types allowed
SCHEMAS: dict[str, dict[str, tuple[type, ...]]] = {
    "start": _SESSION,
    "goto": {**_SESSION, "node": (int,), "lat": (int, float), "lon": (int, float)},
    "measure": {**_SESSION, "node": (int,)},
    "hold": _SESSION,
    "ping": _SESSION,
    "ack": {**_SESSION, "status": (str,)},
    "telemetry": {"t": (int, float), "lat": (int, float), "lon": (int, float)},
    "measurement": {**_SESSION, "node": (int,), "value": (int, float)},
    "status": {"state": (str,)},
    "control": {"session": (str,), "id": (str,), "action": (str,)},
}

MIN_KEY_BYTES = 16


class ProtocolError(ValueError):
    """A payload that cannot be used, explained in one sentence; ``kind`` is what it is counted as."""

    def __init__(self, sentence: str, kind: str = "malformed"):
        super().__init__(sentence)
        self.kind = kind


def topic(fleet: str, vehicle: int | None, channel: str) -> str:
    if vehicle is None:
        return f"{fleet}/planner/{channel}"
    return f"{fleet}/vehicle/{int(vehicle)}/{channel}"


def parse_topic(fleet: str, name: str) -> tuple[int | None, str]:
    """``(vehicle id or None for the planner, channel)``; raises :class:`ProtocolError`."""
    parts = name.split("/")
    prefix = fleet.split("/")
    if parts[: len(prefix)] != prefix:
        raise ProtocolError(f"topic '{name}' is not under fleet prefix '{fleet}'.", "topic")
    rest = parts[len(prefix) :]
    if len(rest) == 2 and rest[0] == "planner":
        return None, rest[1]
    if len(rest) == 3 and rest[0] == "vehicle":
        try:
            return int(rest[1]), rest[2]
        except ValueError as exc:
            raise ProtocolError(
                f"topic '{name}' has vehicle id '{rest[1]}'; ids are whole numbers.", "topic"
            ) from exc
    raise ProtocolError(
        f"topic '{name}' is not a guadal topic ({fleet}/vehicle/N/CHANNEL or {fleet}/planner/CHANNEL).",
        "topic",
    )


def canonical(data: dict) -> bytes:
    """The bytes a tag covers: the payload without ``sig``, keys sorted, no spaces."""
    body = {k: v for k, v in data.items() if k != "sig"}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def tag(key: bytes, topic_name: str, data: dict) -> str:
    """HMAC-SHA256 of ``topic`` + newline + :func:`canonical` payload, in hex."""
    return hmac.new(key, topic_name.encode() + b"\n" + canonical(data), hashlib.sha256).hexdigest()


class Codec:
    """Encodes and checks payloads for one fleet key (``None``: messages are neither signed nor
    required to be; the broker's ACL is then the only guard)."""

    def __init__(self, key: bytes | None = None):
        if key is not None and len(key) < MIN_KEY_BYTES:
            raise ValueError(f"a fleet key needs at least {MIN_KEY_BYTES} bytes, got {len(key)}.")
        self._key = key

    @property
    def signing(self) -> bool:
        return self._key is not None

    def encode(self, topic_name: str, kind: str, **fields) -> bytes:
        """A versioned JSON payload of type ``kind``, signed for ``topic_name`` when keyed."""
        data = {"v": PROTOCOL_VERSION, "type": kind, **fields}
        if self._key is not None:
            data["sig"] = tag(self._key, topic_name, data)
        return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()

    def decode(self, topic_name: str, payload: bytes, expected: set[str] | None = None) -> dict:
        """Parse, authenticate and check a payload; raises :class:`ProtocolError` naming what is wrong."""
        data = _parse(payload)
        if self._key is not None:
            sig = data.get("sig")
            if not isinstance(sig, str):
                raise ProtocolError("message is not signed, and this fleet requires signatures.", "unsigned")
            if not hmac.compare_digest(sig, tag(self._key, topic_name, data)):
                raise ProtocolError(
                    "message signature does not match (wrong fleet key, altered, or sent on another topic).",
                    "bad_signature",
                )
        return check(data, expected)


def _parse(payload: bytes) -> dict:
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD_BYTES}-byte limit.")
    try:
        data = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"payload is not UTF-8 JSON ({exc.__class__.__name__}).") from exc
    if not isinstance(data, dict):
        raise ProtocolError("payload must be a JSON object.")
    return data


def check(data: dict, expected: set[str] | None = None) -> dict:
    """The schema checks: version, type, required fields and their types, known values."""
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
    for name, known in (("status", ACK_TYPES), ("state", STATUS_STATES), ("action", CONTROL_ACTIONS)):
        field_kind = {"status": "ack", "state": "status", "action": "control"}[name]
        if kind == field_kind and data[name] not in known:
            raise ProtocolError(
                f"{kind} {name} {data[name]!r} is unknown (known: {', '.join(sorted(known))})."
            )
    if "seq" in data and data["seq"] < 0:
        raise ProtocolError(f"'{kind}' message has negative seq {data['seq']}.")
    return data


def encode(kind: str, **fields) -> bytes:
    """An unsigned payload (tests, and fleets without a key)."""
    return Codec().encode("", kind, **fields)


def decode(payload: bytes, expected: set[str] | None = None) -> dict:
    """Parse and check an unsigned-or-signed payload without authenticating it (monitoring)."""
    return check(_parse(payload), expected)

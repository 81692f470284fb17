"""The channel's pure rules: signatures, session and seq verdicts, generated credentials."""

from __future__ import annotations

import json

import pytest

from guadal_cli.channel.broker import topic_covered
from guadal_cli.channel.credentials import (
    FleetSecrets,
    hash_password,
    parse_acl,
    read_password_file,
    verify_password,
)
from guadal_cli.channel.protocol import Codec, ProtocolError
from guadal_cli.channel.session import MAX_SEQ_AHEAD, Follower

KEY = b"0123456789abcdef0123456789abcdef"
TOPIC = "guadal/vehicle/0/command"


def test_a_signed_message_fails_when_altered_moved_or_keyed_otherwise():
    codec = Codec(KEY)
    payload = codec.encode(TOPIC, "goto", session="s", seq=1, node=3, lat=37.4, lon=-5.9)
    assert codec.decode(TOPIC, payload)["node"] == 3
    altered = json.loads(payload)
    altered["node"] = 4
    cases = [
        (json.dumps(altered).encode(), TOPIC, "bad_signature"),
        (payload, "guadal/vehicle/1/command", "bad_signature"),  # replayed on another boat's topic
        (
            Codec(b"another key of thirty-two bytes!").encode(TOPIC, "ping", session="s", seq=1),
            TOPIC,
            "bad_signature",
        ),
        (Codec().encode(TOPIC, "ping", session="s", seq=1), TOPIC, "unsigned"),
    ]
    for data, topic, kind in cases:
        with pytest.raises(ProtocolError) as err:
            codec.decode(topic, data)
        assert err.value.kind == kind
    with pytest.raises(ValueError, match="at least 16 bytes"):
        Codec(b"short")


def take(f: Follower, kind: str, session: str, seq: int, signed=True, idle=False) -> str:
    data = {"type": kind, "session": session, "seq": seq}
    verdict, _ = f.judge(data, signed=signed, idle=idle)
    if verdict in ("adopt", "new"):
        f.take(data)
    return verdict


def test_a_bridge_follows_one_session_and_no_number_takes_it_over():
    f = Follower()
    assert take(f, "goto", "a", 5) == "foreign"  # nothing before a start
    assert take(f, "start", "a", 1) == "adopt"
    assert take(f, "goto", "a", 2) == "new"
    assert take(f, "goto", "a", 2) == "duplicate"
    assert take(f, "goto", "a", 1) == "stale"
    assert take(f, "goto", "a", 2 + MAX_SEQ_AHEAD + 1) == "ahead"
    assert take(f, "ping", "a", 10**12) == "ahead"
    assert take(f, "ping", "a", 9) == "contact" and f.last_seq == 2  # a ping moves nothing
    assert take(f, "goto", "a", 2) == "duplicate"  # so the answered command is not stale
    assert take(f, "goto", "b", 10**6) == "foreign"
    assert take(f, "start", "b", 1, signed=False) == "foreign"  # unsigned, and the boat is busy
    assert take(f, "start", "b", 1, signed=False, idle=True) == "adopt"  # after a failsafe, in HOLD
    assert take(f, "start", "a", 50) == "foreign"  # a left session never comes back, signed or not
    assert take(f, "start", "c", 1) == "adopt" and f.session == "c"  # a signed start takes over


def test_generated_secrets_are_private_and_both_brokers_read_them(tmp_path):
    secrets = FleetSecrets.generate(tmp_path / "s", "lake", 2)
    assert (secrets.directory.stat().st_mode & 0o777) == 0o700
    files = [p for p in secrets.directory.rglob("*") if p.is_file()]
    assert len(files) == 3 + 5 and all((p.stat().st_mode & 0o777) == 0o600 for p in files)
    hashes = read_password_file(secrets.password_file)
    assert set(hashes) == {"planner", "operator", "watcher", "vehicle-0", "vehicle-1"}
    password = secrets.user_password_file("vehicle-1").read_text().strip()
    assert verify_password(password, hashes["vehicle-1"]) and not verify_password(password, hashes["planner"])
    assert hash_password("x", salt=b"\0" * 12).startswith("$7$101$AAAAAAAAAAAAAAAA$")  # Mosquitto's format
    rules = parse_acl(secrets.acl_file.read_text())
    assert ("write", "lake/vehicle/1/ack") in rules["vehicle-1"]
    assert not any(topic_covered("lake/vehicle/0/command", p) for a, p in rules["vehicle-1"] if a == "read")
    assert any(topic_covered("lake/vehicle/+/ack", p) for a, p in rules["planner"] if a == "read")
    assert not topic_covered("lake/#", "lake/vehicle/+/ack")  # a wider subscription is not covered

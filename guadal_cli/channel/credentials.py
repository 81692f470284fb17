"""Who may say what on a fleet's broker: generated users, their ACL, the fleet key, on disk.

A launched stack (``launch: true`` or ``guadal stack up``) gets fresh secrets every time, in a
folder only its owner can open (0700; every file 0600), removed with the stack:

    passwd              users and PBKDF2-SHA512 hashes, Mosquitto's ``password_file`` format
    acl                 per-user topic rules, Mosquitto's ``acl_file`` format (the embedded broker
                        reads the same file, so both brokers enforce the same rules)
    fleet.key           the HMAC key every message is signed with
    users/NAME.password one user's password, read by the process that logs in as NAME

Users: ``planner`` (writes commands and its status, reads the vehicles, reads operator
controls), ``vehicle-N`` (reads only its commands and the planner's status, writes only its
own ack, telemetry, measurement and status), ``operator`` (writes planner controls, reads
statuses and telemetry) and ``watcher`` (reads everything, writes nothing).
"""

from __future__ import annotations

import base64
import hashlib
import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from ..errors import GuadalError
from .protocol import MIN_KEY_BYTES, topic

PBKDF2_ITERATIONS = 101  # Mosquitto 2's own default for its $7$ hashes
KEY_FILE = "fleet.key"


def private_dir(path: Path) -> Path:
    """Create ``path`` (and parents) and make it readable by its owner only."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    os.chmod(path, 0o700)
    return path


def write_private(path: Path, text: str) -> Path:
    """Write ``text`` to a file that is 0600 from its first byte."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(path, 0o600)
    return path


def hash_password(password: str, salt: bytes | None = None, iterations: int = PBKDF2_ITERATIONS) -> str:
    """Mosquitto's ``$7$`` hash: PBKDF2-HMAC-SHA512, base64 salt and digest."""
    salt = salt if salt is not None else secrets.token_bytes(12)
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, iterations, 64)
    return f"$7${iterations}${base64.b64encode(salt).decode()}${base64.b64encode(digest).decode()}"


def verify_password(password: str, hashed: str) -> bool:
    try:
        _, seven, iterations, salt, _digest = hashed.split("$")
        if seven != "7":
            return False
        expected = hash_password(password, base64.b64decode(salt), int(iterations))
    except (ValueError, TypeError):
        return False
    return secrets.compare_digest(expected, hashed)


def read_password_file(path: Path) -> dict[str, str]:
    """``{user: hash}`` from a ``user:hash`` file."""
    users = {}
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.startswith("#") and ":" in line:
            name, hashed = line.split(":", 1)
            users[name] = hashed.strip()
    return users


def acl_rules(fleet: str, vehicles: int) -> dict[str, list[tuple[str, str]]]:
    """``{user: [(read|write, topic pattern), ...]}``: everything not listed is refused."""

    def every(channel: str) -> str:
        return f"{fleet}/vehicle/+/{channel}"

    rules = {
        "planner": [
            ("write", every("command")),
            ("write", topic(fleet, None, "status")),
            ("read", topic(fleet, None, "control")),
            *[("read", every(c)) for c in ("ack", "telemetry", "measurement", "status")],
        ],
        "operator": [
            ("write", topic(fleet, None, "control")),
            ("read", topic(fleet, None, "status")),
            ("read", every("status")),
            ("read", every("telemetry")),
        ],
        "watcher": [("read", f"{fleet}/#")],
    }
    for i in range(vehicles):
        rules[vehicle_user(i)] = [
            ("read", topic(fleet, i, "command")),
            ("read", topic(fleet, None, "status")),
            *[("write", topic(fleet, i, c)) for c in ("ack", "telemetry", "measurement", "status")],
        ]
    return rules


def render_acl(rules: dict[str, list[tuple[str, str]]]) -> str:
    """Mosquitto's ``acl_file`` text (no rules before the first ``user``: anonymous gets nothing)."""
    blocks = []
    for user, entries in rules.items():
        blocks.append(
            "\n".join([f"user {user}", *(f"topic {access} {pattern}" for access, pattern in entries)])
        )
    return "\n\n".join(blocks) + "\n"


def parse_acl(text: str) -> dict[str, list[tuple[str, str]]]:
    """The inverse of :func:`render_acl` (``user`` and ``topic read|write|readwrite`` lines)."""
    rules: dict[str, list[tuple[str, str]]] = {}
    user = None
    for raw in text.splitlines():
        words = raw.split()
        if not words or words[0].startswith("#"):
            continue
        if words[0] == "user" and len(words) == 2:
            user = words[1]
            rules.setdefault(user, [])
        elif words[0] == "topic" and user is not None:
            access, pattern = (words[1], words[2]) if len(words) == 3 else ("readwrite", words[1])
            rules[user].append((access, pattern))
    return rules


def vehicle_user(vehicle: int) -> str:
    return f"vehicle-{int(vehicle)}"


@dataclass
class FleetSecrets:
    """A fleet's generated users and key, and where they are written."""

    directory: Path

    @classmethod
    def generate(cls, directory: Path, fleet: str, vehicles: int) -> FleetSecrets:
        """Fresh passwords for every user, the ACL, and a 256-bit fleet key, all 0600 in a 0700 folder."""
        directory = private_dir(directory)
        users = private_dir(directory / "users")
        rules = acl_rules(fleet, vehicles)
        hashes = []
        for name in rules:
            password = secrets.token_urlsafe(24)
            write_private(users / f"{name}.password", password + "\n")
            hashes.append(f"{name}:{hash_password(password)}")
        write_private(directory / "passwd", "\n".join(hashes) + "\n")
        write_private(directory / "acl", render_acl(rules))
        write_private(directory / KEY_FILE, secrets.token_hex(32) + "\n")
        return cls(directory)

    @property
    def password_file(self) -> Path:
        return self.directory / "passwd"

    @property
    def acl_file(self) -> Path:
        return self.directory / "acl"

    @property
    def key_file(self) -> Path:
        return self.directory / KEY_FILE

    def user_password_file(self, user: str) -> Path:
        return self.directory / "users" / f"{user}.password"


def read_secret(*, file: str | Path | None = None, env: str | None = None, what: str) -> str | None:
    """A secret from a file (first line) or an environment variable; ``None`` if neither is set.

    ``what`` is the settings' stem in the error sentence: ``backend.password`` names
    ``backend.password_file`` or ``backend.password_env``."""
    if file is not None:
        path = Path(file).expanduser()
        try:
            value = path.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise GuadalError(f"{what}_file: cannot read '{path}' ({exc.strerror or exc}).") from exc
        except UnicodeDecodeError:
            raise GuadalError(
                f"{what}_file: '{path}' is not UTF-8 text; a secret is one line of text."
            ) from None
        if not value:
            raise GuadalError(f"{what}_file: '{path}' is empty.")
        return value
    if env is not None:
        value = os.environ.get(env)
        if value is None:
            raise GuadalError(f"{what}_env: environment variable '{env}' is not set.")
        return value
    return None


def fleet_key(*, file: str | Path | None = None, env: str | None = None, what: str) -> bytes | None:
    """The fleet's HMAC key (its text, UTF-8), checked for length."""
    value = read_secret(file=file, env=env, what=what)
    if value is None:
        return None
    key = value.encode()
    if len(key) < MIN_KEY_BYTES:
        raise GuadalError(
            f"{what}_{'file' if file is not None else 'env'}: the fleet key has {len(key)} bytes; use at least {MIN_KEY_BYTES} "
            "(e.g. the 64 hex digits of 'openssl rand -hex 32')."
        )
    return key

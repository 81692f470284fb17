"""Who may look and who may steer: the console's access policy, decided once at start-up.

- On a loopback address anyone on this machine may *view* without logging in; nothing else does.
- On any other address ``serve`` refuses to start without operator credentials, and then every
  page and API call needs a login.
- Controls always need a login, wherever the console listens.

Credentials come from a file (``name:secret`` per line, or one bare secret for the user
``operator``) or from an environment variable, never from the command line or a URL: browsers
log in with a form that sets an HttpOnly, SameSite=Strict cookie; scripts send
``Authorization: Bearer <secret>``.
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import secrets
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import GuadalError

#: environment variable holding the operator secret (one bare secret, user ``operator``)
TOKEN_ENV = "GUADAL_SERVE_TOKEN"
#: a secret shorter than this is refused: it would be guessed over the network
MIN_SECRET_LENGTH = 12
SESSION_COOKIE = "guadal_session"


def is_loopback(host: str) -> bool:
    """True for ``localhost``, 127.0.0.0/8 and ``::1``: addresses no other machine can reach."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def load_credentials(token_file: Path | None) -> dict[str, str]:
    """``{user: secret}`` from the file if given, else from :data:`TOKEN_ENV`, else empty."""
    if token_file is not None:
        try:
            text = Path(token_file).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise GuadalError(
                f"token file '{token_file}' cannot be read ({exc.__class__.__name__})."
            ) from exc
        where = f"token file '{token_file}'"
    else:
        text = os.environ.get(TOKEN_ENV, "")
        where = f"environment variable {TOKEN_ENV}"
        if not text.strip():
            return {}
    users: dict[str, str] = {}
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    for number, line in enumerate(lines, 1):
        name, sep, secret = line.partition(":")
        if not sep:
            name, secret = "operator", line
        name, secret = name.strip(), secret.strip()
        if not name or not name.replace("-", "").replace("_", "").replace(".", "").isalnum():
            raise GuadalError(
                f"{where}, line {number}: a user name has letters, digits, '-', '_' or '.' only."
            )
        if len(secret) < MIN_SECRET_LENGTH:
            raise GuadalError(
                f"{where}, line {number}: the secret is too short; use at least {MIN_SECRET_LENGTH} characters."
            )
        users[name] = secret
    if not users:
        raise GuadalError(f"{where} holds no secret; write one per line as 'name:secret' or a bare secret.")
    return users


@dataclass
class Access:
    """The policy of one running console: credentials, whether viewing is open, live sessions."""

    users: dict[str, str]
    open_view: bool
    controls: bool
    sessions: dict[str, str] = field(default_factory=dict)

    @classmethod
    def decide(cls, host: str, users: dict[str, str], controls: bool) -> Access:
        """Refuse a start that would expose the console or its controls without a login."""
        loopback = is_loopback(host)
        if not loopback and not users:
            raise GuadalError(
                f"refusing to listen on {host} without operator credentials: anything beyond loopback "
                f"needs a login; give a token file or set {TOKEN_ENV}."
            )
        if controls and not users:
            raise GuadalError(
                f"operator controls need a login; give a token file or set {TOKEN_ENV} (at least "
                f"{MIN_SECRET_LENGTH} characters)."
            )
        return cls(users=users, open_view=loopback, controls=controls)

    def user_for_secret(self, secret: str) -> str | None:
        """The user a secret belongs to, compared in constant time."""
        found = None
        for name, expected in self.users.items():
            if hmac.compare_digest(secret.encode(), expected.encode()):
                found = name
        return found

    def login(self, secret: str) -> str | None:
        """A new session id for a good secret, else None."""
        user = self.user_for_secret(secret)
        if user is None:
            return None
        session = secrets.token_urlsafe(32)
        self.sessions[session] = user
        return session

    def logout(self, session: str | None) -> None:
        self.sessions.pop(session or "", None)

    def user_of(self, authorization: str | None, session: str | None) -> str | None:
        """The logged-in user of a request (bearer header or session cookie), or None."""
        if authorization:
            scheme, _, secret = authorization.partition(" ")
            if scheme.lower() == "bearer" and secret:
                return self.user_for_secret(secret.strip())
        if session:
            return self.sessions.get(session)
        return None

"""Who may start, view and steer the console: refusals before anything listens, 401 without a login."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import pytest
from console_support import SECRET, Console
from support import run_cli

from guadal_cli.errors import GuadalError
from guadal_cli.web.security import TOKEN_ENV, Access, is_loopback, load_credentials


def test_loopback_addresses_are_recognised():
    assert all(is_loopback(h) for h in ("127.0.0.1", "127.0.0.2", "localhost", "::1", "[::1]"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "192.168.1.20", "::", "example.org"))


def test_a_non_loopback_start_without_a_secret_is_refused_in_one_sentence(tmp_path):
    proc = run_cli(
        "serve",
        "--db",
        f"sqlite:///{tmp_path / 'g.db'}",
        "--host",
        "0.0.0.0",
        "--port",
        "0",
        env={TOKEN_ENV: ""},
        timeout=60,
    )
    assert proc.returncode == 2
    assert "refusing to listen on 0.0.0.0 without operator credentials" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


def test_controls_without_a_secret_are_refused_even_on_loopback(tmp_path):
    proc = run_cli(
        "serve",
        "--db",
        f"sqlite:///{tmp_path / 'g.db'}",
        "--control",
        "--port",
        "0",
        env={TOKEN_ENV: ""},
        timeout=60,
    )
    assert proc.returncode == 2
    assert "operator controls need a login" in proc.stderr


def test_secrets_file_names_users_and_refuses_short_or_missing_secrets(tmp_path, monkeypatch):
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    good = tmp_path / "tokens"
    good.write_text("# operators\nalice:alice-secret-123456\nbob:bob-secret-7890123\n")
    assert load_credentials(good) == {"alice": "alice-secret-123456", "bob": "bob-secret-7890123"}
    bare = tmp_path / "bare"
    bare.write_text(SECRET + "\n")
    assert load_credentials(bare) == {"operator": SECRET}
    short = tmp_path / "short"
    short.write_text("alice:abc\n")
    with pytest.raises(GuadalError, match="line 1: the secret is too short"):
        load_credentials(short)
    with pytest.raises(GuadalError, match="cannot be read"):
        load_credentials(tmp_path / "missing")
    monkeypatch.setenv(TOKEN_ENV, SECRET)
    assert load_credentials(None) == {"operator": SECRET}


def test_sessions_and_bearer_secrets_identify_the_operator():
    access = Access.decide("0.0.0.0", {"alice": "alice-secret-123456"}, controls=True)
    assert not access.open_view
    assert access.user_of("Bearer alice-secret-123456", None) == "alice"
    assert access.user_of("Bearer wrong-secret-000000", None) is None
    assert access.login("nope") is None
    session = access.login("alice-secret-123456")
    assert access.user_of(None, session) == "alice"
    access.logout(session)
    assert access.user_of(None, session) is None


def test_viewing_is_open_on_loopback_but_controls_need_the_secret(tmp_path):
    console = Console(f"sqlite:///{tmp_path / 'g.db'}", "--control", env={TOKEN_ENV: SECRET})
    try:
        status, body = console.call("/api/runs")
        assert status == 200 and body == {"runs": []}
        status, body = console.call("/api/runs/1/control", {"action": "pause"})
        assert status == 401 and body["error"] == "operator controls need a login."
        status, body = console.call("/api/runs/1/control", {"action": "pause"}, token="not-the-secret-at-all")
        assert status == 401
        status, body = console.call("/api/runs/1/control", {"action": "pause"}, token=SECRET)
        assert status == 404 and body["error"] == "there is no run 1 in this database."
        status, body = console.call("/api/runs?colour=red")
        assert status == 400 and "unknown run filter 'colour'" in body["error"]
        # a page elsewhere that points its own name at 127.0.0.1 (DNS rebinding) is refused
        assert console.call("/api/runs", headers={"Host": "attacker.example"})[0] == 400
    finally:
        output = console.stop()
    assert SECRET not in output


def test_beyond_loopback_every_page_and_call_needs_the_login(tmp_path):
    console = Console(f"sqlite:///{tmp_path / 'g.db'}", "--host", "0.0.0.0", env={TOKEN_ENV: SECRET})
    console.url = console.url.replace("0.0.0.0", "127.0.0.1")
    try:
        assert console.call("/api/runs")[0] == 401
        assert console.call("/api/runs/stream")[0] == 401
        assert console.call("/api/runs", token=SECRET)[0] == 200
        status, body = console.call("/api/runs/1/control", {"action": "pause"}, token=SECRET)
        assert status == 403 and "without --control" in body["error"]
    finally:
        output = console.stop()
    assert SECRET not in output


def test_malformed_requests_get_one_sentence_and_the_console_keeps_its_footing(tmp_path):
    """Each of these once got a 500 and a traceback in the log, or was silently accepted."""
    import socket
    from urllib.parse import urlsplit

    console = Console(f"sqlite:///{tmp_path / 'g.db'}", "--control", env={TOKEN_ENV: SECRET})
    control = "/api/runs/1/control"
    try:
        cases = [
            (("/api/runs/9223372036854775808",), 404, "there is no run 9223372036854775808"),
            ((control.replace("1", "9" * 30), {"action": "pause"}, SECRET), 404, "there is no run"),
            (("/api/runs/abc",), 404, "there is nothing at /api/runs/abc"),
            (("/api/runs?status=complete&status=running",), 400, "filter 'status' is given more than once"),
        ]
        for args, status, words in cases:
            got, body = console.call(*args)
            assert got == status and words in body["error"] and "\n" not in body["error"], (
                args[0],
                got,
                body,
            )
        token = {"Authorization": f"Bearer {SECRET}"}

        def post(body: bytes, kind="application/json", extra=None):
            request = urllib.request.Request(
                console.url + control, data=body, headers={**token, "Content-Type": kind, **(extra or {})}
            )
            try:
                with urllib.request.urlopen(request, timeout=10) as response:
                    return response.status, json.loads(response.read())
            except urllib.error.HTTPError as exc:
                return exc.code, json.loads(exc.read())

        status, body = post(b'{"action": "hold", "vehicle": ' + b"9" * 5000 + b"}")  # past int's 4300 digits
        assert status == 400 and "must be JSON" in body["error"]
        status, body = post(b"[" * 5000 + b"]" * 5000)  # deeper than the parser goes
        assert status == 400 and "must be JSON" in body["error"]
        status, body = post(b" " * 50_000 + b'{"action": "pause"}')
        assert status == 413 and "larger than 16384 bytes" in body["error"]
        status, body = post(
            b'{"action": "pause"}', kind="text/plain"
        )  # a form or fetch another site may send
        assert status == 415 and "application/json" in body["error"]
        status, body = post(b'{"action": "pause"}', extra={"Sec-Fetch-Site": "same-site"})
        assert status == 403 and "same-site request may not change anything" in body["error"]
        request = urllib.request.Request(console.url + "/api/runs", method="DELETE")
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=10)
        assert (
            refused.value.code == 405
            and "DELETE is not allowed on /api/runs" in json.loads(refused.value.read())["error"]
        )
        # a client that goes away in the middle of its body
        where = urlsplit(console.url)
        with socket.create_connection((where.hostname, where.port)) as raw:
            raw.sendall(
                f"POST {control} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {SECRET}\r\n"
                'Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{"action"'.encode()
            )
        assert console.call("/api/runs")[0] == 200  # still up
    finally:
        output = console.stop()
    assert "Traceback" not in output and " 500" not in output, output

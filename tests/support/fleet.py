"""Helpers for the remote-level tests: a real paho client that records what it receives."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import paho.mqtt.client as mqtt


class Inbox:
    """A connected paho client whose received messages can be waited on (no sleeps)."""

    def __init__(
        self,
        port: int,
        host: str = "127.0.0.1",
        client_id: str = "",
        keepalive: int = 60,
        will=None,
        login: tuple[str, str] | None = None,
    ):
        self.messages: list[mqtt.MQTTMessage] = []
        self._cond = threading.Condition()
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id)
        self.client.on_message = self._on_message
        self.client.on_connect = lambda *a: self._notify()
        if will:
            self.client.will_set(*will)
        if login:
            self.client.username_pw_set(*login)
        self.client.connect(host, port, keepalive=keepalive)
        self.client.loop_start()
        self.wait(self.client.is_connected, 10, "the test client did not connect")

    def _notify(self):
        with self._cond:
            self._cond.notify_all()

    def _on_message(self, client, userdata, msg):
        with self._cond:
            self.messages.append(msg)
            self._cond.notify_all()

    def wait(self, predicate, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"{what} within {timeout} s")
                self._cond.wait(min(left, 0.1))
        return predicate()

    def subscribe(self, *topics: str, qos: int = 1) -> None:
        done = threading.Event()
        self.client.on_subscribe = lambda *a: done.set()
        self.client.subscribe([(t, qos) for t in topics])
        assert done.wait(10), "the broker did not acknowledge the subscription"

    def on(self, topic: str) -> list[mqtt.MQTTMessage]:
        return [m for m in self.messages if m.topic == topic]

    def close(self) -> None:
        """A clean disconnect: DISCONNECT is on the wire before the network loop stops."""
        gone = threading.Event()
        self.client.on_disconnect = lambda *a: gone.set()
        if self.client.is_connected():
            self.client.disconnect()
            gone.wait(5)
        self.client.loop_stop()


def login(stack, user: str) -> tuple[str, str]:
    """A launched stack's generated user and password (as its processes read them)."""
    return user, stack.secrets.user_password_file(user).read_text().strip()


def connect_refused(port: int, login: tuple[str, str] | None = None) -> str:
    """Try to log in; the broker's reason for refusing, or "" if it let the client in."""
    outcome: dict = {}
    done = threading.Event()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    if login:
        client.username_pw_set(*login)

    def on_connect(c, userdata, flags, reason_code, properties=None):
        outcome["reason"] = "" if not reason_code.is_failure else str(reason_code)
        done.set()

    client.on_connect = on_connect
    client.on_disconnect = lambda *a: (outcome.setdefault("reason", "disconnected"), done.set())
    client.connect("127.0.0.1", port, keepalive=10)
    client.loop_start()
    try:
        assert done.wait(10), "the broker neither accepted nor refused the client"
    finally:
        client.disconnect()
        client.loop_stop()
    return outcome["reason"]


def wait_for(predicate, timeout: float, what: str, interval: float = 0.05):
    """Poll a condition until it holds; fail with ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} within {timeout} s")
        time.sleep(interval)


def describe_processes(pids: list[int]) -> str:
    """``pid command line`` of each live process, for a failure message."""
    out = []
    for pid in pids:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        out.append(f"{pid} {cmd.strip()}")
    return "; ".join(out) or "none"


def processes_marked(mark: str) -> list[int]:
    """Pids of live processes whose environment carries ``mark`` (children inherit it)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if mark.encode() in (entry / "environ").read_bytes():
                stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                if stat[0] != "Z":
                    found.append(int(entry.name))
        except OSError:
            continue
    return found

"""An MQTT broker for the sitl stack: Mosquitto where installed, else an embedded one.

Both run as a separate process on a private port, so a stack (or a test) never shares a broker
with anything else and can kill and restart it on the same port. The embedded broker is amqtt
(a pure-Python asyncio MQTT 3.1.1 broker), so a fresh ``pip install guadal`` still runs the
SITL demo on a machine without Mosquitto.

Given a fleet's :class:`~guadal_cli.channel.credentials.FleetSecrets`, both brokers refuse
anonymous clients and enforce the same password file and ACL file (Mosquitto's own
``password_file``/``acl_file``; the embedded broker reads them with :class:`PasswordAuth` and
:class:`TopicAcl`). Run it alone with
``python -m guadal_cli.channel.broker --port 1883 [--password-file F --acl-file F]``.
"""

from __future__ import annotations

import argparse
import functools
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import GuadalError
from .credentials import FleetSecrets

BROKER_KINDS = ("auto", "mosquitto", "embedded")


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nobody listens on right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def mosquitto_binary() -> str | None:
    """Path of the ``mosquitto`` executable, if any (PATH first, then the usual sbin)."""
    return shutil.which("mosquitto") or next(
        (p for p in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto") if os.access(p, os.X_OK)), None
    )


def port_accepts(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


@dataclass
class BrokerProcess:
    """A broker we started: where it listens and how to stop it."""

    kind: str
    host: str
    port: int
    process: subprocess.Popen | None = None
    workdir: Path | None = None
    log_path: Path | None = None
    _own_workdir: bool = field(default=False, repr=False)

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, grace: float = 3.0) -> None:
        """SIGTERM, then SIGKILL after ``grace`` seconds; safe to call twice."""
        if self.process is not None:
            stop_process(self.process, grace)
        if self._own_workdir and self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)
            self._own_workdir = False

    def kill(self) -> None:
        """Abrupt death (SIGKILL), as a crashed broker or a pulled cable."""
        if self.alive():
            self.process.kill()
            self.process.wait(5)


def child_options(detach: bool) -> dict:
    """Popen options for a stack process.

    Every child gets its own session, so a Ctrl-C in the terminal reaches only the planner,
    which then stops the stack in order. A child that is not detached also dies with its
    parent (Linux), so even a killed planner leaves nothing behind.
    """
    options: dict = {"start_new_session": True}
    if not detach and sys.platform.startswith("linux"):
        options["preexec_fn"] = _die_with_parent
    return options


def _die_with_parent() -> None:
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def stop_process(process: subprocess.Popen, grace: float = 3.0) -> None:
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(grace)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(5)


def wait_until_listening(
    host: str, port: int, process: subprocess.Popen, timeout: float, what: str, log: Path | None
) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            tail = log.read_text(errors="replace").strip().splitlines()[-3:] if log and log.exists() else []
            raise GuadalError(
                f"the {what} exited with code {process.returncode} before listening on port {port}"
                + (f" ({' / '.join(tail)})." if tail else ".")
            )
        if port_accepts(host, port):
            return
        time.sleep(0.05)
    stop_process(process)
    raise GuadalError(f"the {what} did not listen on {host}:{port} within {timeout:g} s.")


def _same_user() -> str:
    """Mosquitto started by root switches to its own user, which also cancels "die with the
    parent"; tell it to stay who started it."""
    try:
        import pwd

        return f"user {pwd.getpwuid(os.getuid()).pw_name}\n"
    except (ImportError, KeyError, OSError):
        return ""


def start_broker(
    kind: str = "auto",
    host: str = "127.0.0.1",
    port: int = 0,
    workdir: str | Path | None = None,
    timeout: float = 10.0,
    detach: bool = False,
    secrets: FleetSecrets | None = None,
) -> BrokerProcess:
    """Start a private broker and return once it accepts connections.

    ``kind``: ``mosquitto``, ``embedded`` or ``auto`` (Mosquitto if installed). ``port`` 0 picks a
    free one. ``detach`` lets it outlive the caller (``guadal stack up``). With ``secrets``, only
    the users of its password file get in, each limited by its ACL; without, anyone may do
    anything (tests of the protocol itself, on loopback only).
    """
    if kind not in BROKER_KINDS:
        raise GuadalError(f"broker kind '{kind}' is unknown (allowed: {', '.join(BROKER_KINDS)}).")
    binary = mosquitto_binary()
    if kind == "mosquitto" and binary is None:
        raise GuadalError(
            "broker 'mosquitto' was asked for, but no mosquitto executable is installed; use 'embedded'."
        )
    chosen = "mosquitto" if (kind == "mosquitto" or (kind == "auto" and binary)) else "embedded"
    port = int(port) or free_port(host)
    own = workdir is None
    wd = Path(tempfile.mkdtemp(prefix="guadal-broker-")) if own else Path(workdir)
    wd.mkdir(parents=True, exist_ok=True)
    log_path = wd / f"broker-{port}.log"
    if chosen == "mosquitto":
        if secrets is None:
            access = "allow_anonymous true\n"
        else:
            access = (
                f"allow_anonymous false\npassword_file {secrets.password_file}\nacl_file {secrets.acl_file}\n"
            )
        conf = wd / f"mosquitto-{port}.conf"
        conf.write_text(
            f"{_same_user()}listener {port} {host}\n{access}persistence false\n"
            # small MQTT packets must not wait for Nagle's algorithm (40 ms per hop otherwise)
            f"set_tcp_nodelay true\nmax_packet_size 65536\nlog_dest stderr\nlog_type error\nlog_type warning\n"
        )
        cmd = [binary, "-c", str(conf)]
    else:
        cmd = [sys.executable, "-m", "guadal_cli.channel.broker", "--host", host, "--port", str(port)]
        if secrets is not None:
            cmd += ["--password-file", str(secrets.password_file), "--acl-file", str(secrets.acl_file)]
    with open(log_path, "ab") as log:
        process = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, **child_options(detach)
        )
    broker = BrokerProcess(chosen, host, port, process, wd, log_path, _own_workdir=own)
    try:
        wait_until_listening(host, port, process, timeout, f"{chosen} broker", log_path)
    except BaseException:
        broker.stop()
        raise
    return broker


# --- the embedded broker process ------------------------------------------------------------
def _amqtt_config(host: str, port: int, password_file: str | None, acl_file: str | None) -> dict:
    if password_file is None:
        # anonymous clients, every topic allowed: a private loopback broker for protocol tests
        plugins = {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}}
    else:
        plugins = {
            f"{__name__}.PasswordAuth": {"password_file": password_file},
            f"{__name__}.TopicAcl": {"acl_file": acl_file},
        }
    return {
        "listeners": {"default": {"type": "tcp", "bind": f"{host}:{port}", "max_connections": 256}},
        # a client silent for keepalive + 2 s is dropped (and its will published): see _expire_silent
        "timeout_disconnect_delay": 2,
        "plugins": plugins,  # and no $SYS tree
    }


@functools.cache
def _amqtt_plugins():
    """The embedded broker's auth and ACL plugins (amqtt is imported only where it runs)."""
    from dataclasses import dataclass as _dataclass

    from amqtt.contexts import Action
    from amqtt.plugins.base import BaseAuthPlugin, BaseTopicPlugin

    from .credentials import parse_acl, read_password_file, verify_password

    class PasswordAuth(BaseAuthPlugin):
        """Users and ``$7$`` hashes from the same password file Mosquitto reads; no anonymous."""

        @_dataclass
        class Config:
            password_file: str = ""

        def __init__(self, context) -> None:
            super().__init__(context)
            self._users = read_password_file(Path(self.config.password_file))

        async def authenticate(self, *, session) -> bool:
            hashed = self._users.get(session.username or "")
            return hashed is not None and verify_password(session.password or "", hashed)

    class TopicAcl(BaseTopicPlugin):
        """Mosquitto's ``acl_file`` rules: read = subscribe and receive, write = publish."""

        @_dataclass
        class Config:
            acl_file: str = ""

        def __init__(self, context) -> None:
            super().__init__(context)
            self._rules = parse_acl(Path(self.config.acl_file).read_text())

        async def topic_filtering(self, *, session=None, topic=None, action=None) -> bool:
            need = "write" if action == Action.PUBLISH else "read"
            rules = self._rules.get(getattr(session, "username", None) or "", [])
            return topic is not None and any(
                access in (need, "readwrite") and topic_covered(topic, pattern) for access, pattern in rules
            )

    return PasswordAuth, TopicAcl


def topic_covered(name: str, pattern: str) -> bool:
    """Whether topic (or subscription filter) ``name`` lies within ACL ``pattern`` (+ and # wildcards)."""
    want, allowed = name.split("/"), pattern.split("/")
    for i, level in enumerate(allowed):
        if level == "#":
            return True
        if i >= len(want) or want[i] == "#":
            return False  # shorter, or a wider subscription than allowed
        if level != "+" and want[i] != level:
            return False  # also a "+" asked where one name is allowed
    return len(want) == len(allowed)


def __getattr__(name: str):
    if name in ("PasswordAuth", "TopicAcl"):
        return dict(zip(("PasswordAuth", "TopicAcl"), _amqtt_plugins()))[name]
    raise AttributeError(name)


def _expire_silent_clients() -> None:
    """Make amqtt drop a client whose keepalive ran out (MQTT 3.1.1 §3.1.2.10).

    amqtt notices the read timeout but does nothing with it, so a bridge whose link died
    without a FIN would stay "online" for ever; closing the session publishes its will.
    """
    import asyncio

    from amqtt.mqtt.protocol.broker_handler import BrokerProtocolHandler

    def expire(handler) -> None:
        asyncio.get_running_loop().create_task(handler.handle_connection_closed())

    BrokerProtocolHandler.handle_read_timeout = expire


def _keep_clean_disconnects() -> None:
    """Make amqtt honour a DISCONNECT that arrives before its session loop starts waiting for it.

    amqtt forgets the DISCONNECT packet once it has resolved the waiter; if the client
    disconnected while the broker was still busy after CONNACK, the loop then sees "no packet"
    and publishes the will of a client that left cleanly (MQTT 3.1.1 §3.14.4 says it must not).
    """
    from amqtt.mqtt.protocol.broker_handler import BrokerProtocolHandler

    handle_disconnect = BrokerProtocolHandler.handle_disconnect

    async def remember(self, disconnect) -> None:
        if getattr(self, "_clean_disconnect", None) is None:
            self._clean_disconnect = disconnect
        await handle_disconnect(self, disconnect)

    async def wait_disconnect(self):
        if self._disconnect_waiter is None:  # already resolved: answer what it was resolved with
            return getattr(self, "_clean_disconnect", None)
        return await self._disconnect_waiter

    BrokerProtocolHandler.handle_disconnect = remember
    BrokerProtocolHandler.wait_disconnect = wait_disconnect


def _retained_only_to_subscribers() -> None:
    """Send a connecting client the retained messages of its own subscriptions only.

    On every CONNECT amqtt replays retained messages for *every* subscription in the broker,
    including other clients' ones, to the new client, which never asked for them.
    """
    from amqtt.broker import Broker

    publish = Broker._publish_retained_messages_for_subscription

    async def only_if_subscribed(self, subscription, session) -> None:
        if any(s.client_id == session.client_id for s, _ in self._subscriptions.get(subscription[0], ())):
            await publish(self, subscription, session)

    Broker._publish_retained_messages_for_subscription = only_if_subscribed


def run_embedded(host: str, port: int, password_file: str | None = None, acl_file: str | None = None) -> None:
    """Serve until SIGTERM/SIGINT (blocking)."""
    import asyncio
    import logging

    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    for name in ("amqtt", "transitions"):
        logging.getLogger(name).setLevel(logging.ERROR)
    from amqtt.broker import Broker

    _expire_silent_clients()
    _keep_clean_disconnects()
    _retained_only_to_subscribers()

    async def serve() -> None:
        broker = Broker(_amqtt_config(host, port, password_file, acl_file))
        await broker.start()
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        print(f'{{"ready": true, "url": "mqtt://{host}:{port}"}}', flush=True)
        await stop.wait()
        await broker.shutdown()

    asyncio.run(serve())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m guadal_cli.channel.broker", description="guadal's embedded MQTT broker"
    )
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=1883)
    parser.add_argument("--password-file", help="users and $7$ hashes (Mosquitto's password_file format)")
    parser.add_argument("--acl-file", help="topic rules per user (Mosquitto's acl_file format)")
    args = parser.parse_args(argv)
    if (args.password_file is None) != (args.acl_file is None):
        parser.error("--password-file and --acl-file go together")
    run_embedded(args.host, args.port, args.password_file, args.acl_file)


if __name__ == "__main__":
    main()

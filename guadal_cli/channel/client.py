"""The one MQTT client of guadal: the planner, every bridge and the stack's watcher use it.

A :class:`Channel` logs in (user, password from a file or the environment, TLS), sets the last
will, subscribes again on every reconnect, signs what it sends and authenticates what it
receives (:class:`~guadal_cli.channel.protocol.Codec`). It owns no protocol state: every event
goes into the caller's queue, and the one loop that owns the caller's state handles it::

    ("connected",)                        subscribed; publish your retained status now
    ("disconnected", reason)              paho reconnects by itself
    ("refused", reason)                   the broker said no (bad user or password) or is unreachable
    ("message", vehicle, channel, data)   a checked, authenticated payload (vehicle None: planner)
    ("dropped", kind, sentence)           an unusable one: count ``kind``, log ``sentence``
"""

from __future__ import annotations

import queue
import socket
import ssl
import threading
from dataclasses import dataclass
from urllib.parse import quote, unquote, urlsplit

import paho.mqtt.client as mqtt
from pydantic import SecretStr

from ..errors import GuadalError
from . import protocol


@dataclass(frozen=True)
class Endpoint:
    """Where the broker is and who we are there. The password never appears in :attr:`url`."""

    host: str = "127.0.0.1"
    port: int = 1883
    tls: bool = False
    ca_file: str | None = None
    username: str | None = None
    password: SecretStr | None = None

    @property
    def url(self) -> str:
        """``mqtt[s]://[user@]host:port``: safe to log."""
        user = f"{quote(self.username, safe='')}@" if self.username else ""
        return f"mqtt{'s' if self.tls else ''}://{user}{self.host}:{self.port}"

    @classmethod
    def from_url(cls, url: str, password: str | None = None, ca_file: str | None = None) -> Endpoint:
        """``mqtt://[user[:password]@]host[:port]`` (``mqtts://`` for TLS); ``password`` wins over
        one written in the URL (kept only for old configurations: a URL ends up in logs and
        process lists, a file or an environment variable does not)."""
        try:
            parts = urlsplit(url)
            port = parts.port
        except ValueError as exc:
            raise GuadalError(
                f"broker URL '{redact(url)}' is not valid ({exc}); use mqtt://host:port or mqtt://user@host:port."
            ) from exc
        if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
            raise GuadalError(
                f"broker URL '{redact(url)}' must look like mqtt://host:port or mqtt://user@host:port "
                "(mqtts:// for TLS)."
            )
        tls = parts.scheme == "mqtts"
        secret = password if password is not None else (unquote(parts.password) if parts.password else None)
        return cls(
            host=parts.hostname,
            port=port or (8883 if tls else 1883),
            tls=tls,
            ca_file=ca_file,
            username=unquote(parts.username) if parts.username else None,
            password=SecretStr(secret) if secret is not None else None,
        )


def redact(url: str) -> str:
    """A URL with any password replaced by ``***``."""
    try:
        parts = urlsplit(url)
        if parts.password is None:
            return url
        netloc = parts.netloc.replace(f":{parts.password}@", ":***@", 1)
        return parts._replace(netloc=netloc).geturl()
    except ValueError:
        return "<unparsable URL>"


class Channel:
    """One authenticated, signing MQTT connection feeding events into ``inbox``."""

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        fleet: str,
        client_id: str,
        inbox: queue.Queue,
        subscriptions: list[tuple[str, int]],
        codec: protocol.Codec | None = None,
        will: tuple[str, str, dict] | None = None,
        keepalive: int = 10,
        max_reconnect_delay: float = 2.0,
    ):
        self.endpoint = endpoint
        self.fleet = fleet
        self.codec = codec or protocol.Codec()
        self.inbox = inbox
        self._subscriptions = list(subscriptions)
        self._keepalive = keepalive
        self._connected = threading.Event()
        self._started = False
        client = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=True, protocol=mqtt.MQTTv311
        )
        if endpoint.username is not None:
            password = endpoint.password.get_secret_value() if endpoint.password is not None else None
            client.username_pw_set(endpoint.username, password)
        if endpoint.tls:
            try:
                client.tls_set(ca_certs=endpoint.ca_file, cert_reqs=ssl.CERT_REQUIRED)
            except (OSError, ssl.SSLError, ValueError) as exc:
                raise GuadalError(f"cannot load the CA certificate '{endpoint.ca_file}' ({exc}).") from exc
        if will is not None:
            will_topic, kind, fields = will
            client.will_set(will_topic, self.codec.encode(will_topic, kind, **fields), qos=1, retain=True)
        client.reconnect_delay_set(min_delay=0.1, max_delay=max_reconnect_delay)
        client.max_inflight_messages_set(100)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_connect_fail = lambda c, u: self.inbox.put(("refused", "connection refused or unreachable"))
        client.on_message = self._on_message
        self._client = client

    @property
    def url(self) -> str:
        return self.endpoint.url

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def start(self) -> None:
        """Connect in the background (paho's thread reconnects for ever after)."""
        if self._started:
            return
        self._started = True
        try:
            self._client.connect_async(self.endpoint.host, self.endpoint.port, keepalive=self._keepalive)
        except (OSError, ValueError) as exc:
            raise GuadalError(f"cannot connect to the MQTT broker at {self.url}: {exc}.") from exc
        self._client.loop_start()

    def send(self, topic_name: str, kind: str, *, qos: int = 1, retain: bool = False, **fields):
        """Sign and publish one message; returns paho's message info (``wait_for_publish``)."""
        return self._client.publish(
            topic_name, self.codec.encode(topic_name, kind, **fields), qos=qos, retain=retain
        )

    def publish_payload(self, topic_name: str, payload: bytes, *, qos: int = 1, retain: bool = False):
        """Publish bytes already encoded (a repeated answer is repeated byte for byte)."""
        return self._client.publish(topic_name, payload, qos=qos, retain=retain)

    def close(self, pending=(), timeout: float = 2.0) -> None:
        """Wait up to ``timeout`` for ``pending`` publishes, then disconnect cleanly."""
        if not self._started:
            return
        if self.connected:
            for info in pending:
                try:
                    info.wait_for_publish(timeout)
                except (RuntimeError, ValueError):
                    break
        self._connected.clear()
        self._client.disconnect()
        self._client.loop_stop()

    # --- paho's thread: decode and hand over, nothing else -------------------------------------
    def _on_connect(self, client, userdata, flags, reason_code, properties=None) -> None:
        if reason_code.is_failure:
            self.inbox.put(("refused", f"the broker refused the connection: {reason_code}"))
            return
        sock = client.socket()
        if sock is not None and hasattr(sock, "setsockopt"):
            try:  # small packets must not wait ~40 ms for Nagle's algorithm
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
        if self._subscriptions:
            client.subscribe(self._subscriptions)  # again on every connect: a restarted broker forgot us
        self._connected.set()
        self.inbox.put(("connected",))

    def _on_disconnect(self, client, userdata, flags, reason_code, properties=None) -> None:
        was = self._connected.is_set()
        self._connected.clear()
        if was:
            self.inbox.put(("disconnected", str(reason_code)))

    def _on_message(self, client, userdata, message) -> None:
        try:
            vehicle, channel = protocol.parse_topic(self.fleet, message.topic)
            expected = protocol.CHANNEL_TYPES.get(channel)
            if expected is None:
                raise protocol.ProtocolError(
                    f"topic '{message.topic}' has no guadal channel '{channel}'.", "topic"
                )
            data = self.codec.decode(message.topic, message.payload, expected)
        except protocol.ProtocolError as exc:
            self.inbox.put(("dropped", exc.kind, f"{message.topic}: {exc}"))
            return
        self.inbox.put(("message", vehicle, channel, data))

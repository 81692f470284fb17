"""The wires one emulated vehicle speaks MAVLink over: a TCP server (like SITL's serial 0), an
optional UDP stream out, an optional serial device or pseudo-terminal.

Every endpoint is non-blocking and registered with the runner's selector.  Bytes a peer sends are
decoded by a parser of the endpoint's own (a stream of garbage on one wire cannot corrupt another);
what the vehicle sends goes to every open endpoint.  A peer too slow to read loses whole packets,
never half of one, as an autopilot's full UART buffer does.
"""

from __future__ import annotations

import errno
import os
import selectors
import socket
import termios
import tty
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

#: bytes queued for one slow peer before new packets are dropped
MAX_BACKLOG = 64 * 1024

Deliver = Callable[[list], None]  # decoded messages (good and bad) from one read


def _parser() -> mavlink.MAVLink:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True  # bad bytes become MAVLink_bad_data instead of exceptions
    return parser


class Link:
    """One vehicle's endpoints; also the file its pymavlink encoder writes to."""

    def __init__(self, sysid: int, selector: selectors.BaseSelector):
        self.sysid = sysid
        self.selector = selector
        self.endpoints: list[_Endpoint] = []
        self.dropped_packets = 0
        self.mav = mavlink.MAVLink(self, srcSystem=sysid, srcComponent=mavlink.MAV_COMP_ID_AUTOPILOT1)
        self.deliver: Deliver = lambda msgs: None

    # pymavlink calls this with each packed message
    def write(self, packet: bytes) -> None:
        for endpoint in list(self.endpoints):
            endpoint.send(packet)

    @property
    def has_peers(self) -> bool:
        return any(e.has_peer for e in self.endpoints)

    def add(self, endpoint: _Endpoint) -> None:
        self.endpoints.append(endpoint)

    def remove(self, endpoint: _Endpoint) -> None:
        if endpoint in self.endpoints:
            self.endpoints.remove(endpoint)

    def close(self) -> None:
        for endpoint in list(self.endpoints):
            endpoint.close()


class _Endpoint:
    """A readable, writable byte stream with a parser and a bounded send backlog."""

    has_peer = True

    def __init__(self, link: Link, fileobj):
        self.link = link
        self.fileobj = fileobj
        self.parser = _parser()
        self.backlog = bytearray()
        self.closed = False
        link.selector.register(fileobj, selectors.EVENT_READ, self._on_event)
        link.add(self)

    # subclasses provide raw I/O
    def _read(self) -> bytes | None:  # None: would block; b"": peer gone
        raise NotImplementedError

    def _write(self, data: bytes) -> int:
        raise NotImplementedError

    def _on_event(self, mask: int) -> None:
        if mask & selectors.EVENT_WRITE:
            self._flush()
        if mask & selectors.EVENT_READ and not self.closed:
            try:
                data = self._read()
            except OSError:
                data = b""
            if data == b"":
                self._peer_gone()
            elif data:
                self.feed(data)

    def feed(self, data: bytes) -> None:
        try:
            msgs = self.parser.parse_buffer(data) or []
        except Exception:  # pymavlink can still raise on some malformed frames
            msgs = [mavlink.MAVLink_bad_data(bytearray(data), "unparseable")]
            self.parser = _parser()
        if msgs:
            self.link.deliver(msgs)

    def send(self, packet: bytes) -> None:
        if self.closed or not self.has_peer:
            return
        if self.backlog:
            if len(self.backlog) + len(packet) > MAX_BACKLOG:
                self.link.dropped_packets += 1
            else:
                self.backlog += packet
            return
        try:
            sent = self._write(packet)
        except BlockingIOError:
            sent = 0
        except OSError:
            self._peer_gone()
            return
        if sent < len(packet):
            self.backlog += packet[sent:]
            self._want_write(True)

    def _flush(self) -> None:
        try:
            sent = self._write(bytes(self.backlog))
        except BlockingIOError:
            return
        except OSError:
            self._peer_gone()
            return
        del self.backlog[:sent]
        if not self.backlog:
            self._want_write(False)

    def _want_write(self, on: bool) -> None:
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if on else 0)
        try:
            self.link.selector.modify(self.fileobj, events, self._on_event)
        except (KeyError, ValueError):
            pass

    def _peer_gone(self) -> None:
        self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.link.selector.unregister(self.fileobj)
        except (KeyError, ValueError):
            pass
        self.link.remove(self)
        self._close_raw()

    def _close_raw(self) -> None:
        self.fileobj.close()


class TcpClient(_Endpoint):
    """One accepted TCP connection; when it drops, the listener keeps waiting for the next."""

    def __init__(self, link: Link, sock: socket.socket):
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        super().__init__(link, sock)

    def _read(self) -> bytes | None:
        try:
            return self.fileobj.recv(65536)
        except BlockingIOError:
            return None

    def _write(self, data: bytes) -> int:
        return self.fileobj.send(data)


class TcpListener:
    """A TCP server socket like SITL's ``tcp:127.0.0.1:5760``; accepts clients (and re-connects)
    at any time, each becoming a :class:`TcpClient` of the same vehicle."""

    def __init__(self, link: Link, host: str, port: int):
        self.link = link
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((host, port))
        except OSError:
            self.sock.close()
            raise
        self.sock.listen(4)
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        link.selector.register(self.sock, selectors.EVENT_READ, self._on_accept)

    def _on_accept(self, mask: int) -> None:
        try:
            conn, _ = self.sock.accept()
        except OSError:
            return
        TcpClient(self.link, conn)

    def close(self) -> None:
        try:
            self.link.selector.unregister(self.sock)
        except (KeyError, ValueError):
            pass
        self.sock.close()


class UdpOut(_Endpoint):
    """Sends every packet to ``host:port`` (like MAVProxy's ``--out``) and takes commands from
    whoever answers on that socket."""

    def __init__(self, link: Link, host: str, port: int):
        address = socket.gethostbyname(host)  # once, not per packet
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1" if address.startswith("127.") else "0.0.0.0", 0))
        sock.setblocking(False)
        self.destination = (address, port)
        super().__init__(link, sock)

    def _read(self) -> bytes | None:
        try:
            data, _ = self.fileobj.recvfrom(65536)
        except (BlockingIOError, ConnectionRefusedError):
            return None  # ICMP "port unreachable" from an earlier send: nobody listening yet
        return data or None

    def _write(self, data: bytes) -> int:
        try:
            return self.fileobj.sendto(data, self.destination)
        except ConnectionRefusedError:
            return len(data)

    def _peer_gone(self) -> None:
        """Datagram sockets have no peer to lose."""


class SerialPort(_Endpoint):
    """A serial device, or with ``path="pty"`` a fresh pseudo-terminal whose other end
    (:attr:`path`) a bridge opens as if it were the autopilot's UART."""

    def __init__(self, link: Link, path: str, baud: int = 115200):
        self._held_slave: int | None = None
        if path == "pty":
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no line discipline: MAVLink is binary
            self.path = os.ttyname(slave)
            self._held_slave = slave  # keeps the master readable while no client has it open
            fd = master
        else:
            fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            speed = getattr(termios, f"B{baud}", None)
            if speed is None:
                os.close(fd)
                raise ValueError(f"unsupported baud rate {baud}")
            attrs[4] = attrs[5] = speed
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            self.path = path
        os.set_blocking(fd, False)
        self.fd = fd
        super().__init__(link, fd)

    def _read(self) -> bytes | None:
        try:
            return os.read(self.fd, 65536) or None
        except BlockingIOError:
            return None
        except OSError as exc:
            if exc.errno == errno.EIO:  # pty with no reader on the other side
                return None
            raise

    def _write(self, data: bytes) -> int:
        return os.write(self.fd, data)

    def _peer_gone(self) -> None:
        """A serial line stays open: the far end may come back."""

    def _close_raw(self) -> None:
        os.close(self.fd)
        if self._held_slave is not None:
            os.close(self._held_slave)

"""Real parts for the bridge tests: the MAVLink boat emulator and the bridge as subprocesses, and
a paho client acting as the planner."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

from guadal_cli.channel import protocol as messages
from guadal_cli.graph import NavGraph
from support.fleet import Inbox

GUADAL = [sys.executable, "-m", "guadal_cli"]


# 5 m cells; a land tongue (column 4, rows 1-4) splits the lake into a west and an east basin
LAKE = [
    "000000000",
    "011101110",
    "011101110",
    "011101110",
    "011101110",
    "011111110",
    "000000000",
]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def read_json_line(proc: subprocess.Popen, timeout: float, what: str) -> dict:
    """The first JSON line a process prints, without blocking past ``timeout``."""
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: lines.put(proc.stdout.readline()), daemon=True).start()
    try:
        line = lines.get(timeout=timeout)
    except queue.Empty:
        raise AssertionError(f"{what} printed nothing within {timeout} s") from None
    assert line, f"{what} exited ({proc.poll()}) before printing its ready line"
    return json.loads(line)


class Emulator:
    """``guadal sitl`` for one boat, plus a UDP listener on its telemetry stream (to see its modes)."""

    def __init__(self, home, speedup=40.0, serial=False, max_speed=2.0):
        os.environ["MAVLINK20"] = "1"  # the emulator speaks MAVLink 2, as ArduPilot does
        from pymavlink import mavutil

        self.stream = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=250)
        udp_port = self.stream.port.getsockname()[1]
        cmd = GUADAL + [
            "sitl",
            "--vehicles",
            "1",
            "--home",
            f"{home[0]},{home[1]}",
            "--speedup",
            str(speedup),
            "--base-port",
            "0",
            "--max-speed",
            str(max_speed),
            "--udp-out",
            f"127.0.0.1:{udp_port}",
        ]
        if serial:
            cmd += ["--serial", "pty"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.ready = read_json_line(self.proc, 20, "guadal sitl")
        self.vehicle = self.ready["vehicles"][0]
        self.tcp = f"tcp:127.0.0.1:{self.vehicle['tcp']}"

    def heartbeat(self, predicate, timeout: float, what: str):
        """Wait for an emulator heartbeat that satisfies ``predicate``."""
        import time

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.stream.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
            if msg is not None and predicate(msg):
                return msg
        raise AssertionError(f"{what} within {timeout} s")

    def set_param(self, name: str, value: float) -> None:
        """PARAM_SET from outside the bridge (a ground station), confirmed by PARAM_VALUE."""
        import time

        self.heartbeat(lambda hb: True, 5, "no heartbeat from the emulator")  # learn its UDP address
        self.stream.mav.param_set_send(1, 1, name.encode(), value, 9)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            msg = self.stream.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None and msg.param_id == name and msg.param_value == value:
                return
        raise AssertionError(f"the emulator did not confirm {name} = {value}")

    def set_mode(self, mode: int) -> None:
        """Change the boat's mode from outside the bridge (a ground station, an RC switch)."""
        self.heartbeat(lambda hb: True, 5, "no heartbeat from the emulator")  # learn its UDP address
        self.stream.mav.command_long_send(1, 1, 176, 0, 1, mode, 0, 0, 0, 0, 0)
        self.heartbeat(lambda hb: hb.custom_mode == mode, 5, f"the emulator did not enter mode {mode}")

    def close(self):
        _stop(self.proc)
        self.stream.close()


class Planner(Inbox):
    """The planner's side of the protocol, on a real paho client."""

    def __init__(self, broker, fleet: str, vehicle: int = 0, **kw):
        self.fleet, self.vehicle, self.seq = fleet, vehicle, 0
        self.session = uuid.uuid4().hex[:16]
        self._seq_lock = threading.Lock()
        self._pinging = threading.Event()
        super().__init__(broker.port, **kw)
        self.subscribe(f"{fleet}/vehicle/{vehicle}/#")

    def forget(self) -> None:
        """Drop what was received so far, except the newest status (it is retained state)."""
        with self._cond:
            status = self.on(self.topic("status"))[-1:]
            self.messages[:] = status

    def topic(self, channel):
        return messages.topic(self.fleet, self.vehicle, channel)

    def send(self, kind: str, seq: int | None = None, **fields) -> int:
        with self._seq_lock:
            if seq is None:
                self.seq += 1
                seq = self.seq
            fields.setdefault("session", self.session)
            self.raw(messages.encode(kind, seq=seq, **fields))
        return seq

    def start_session(self, timeout: float = 30.0) -> int:
        """Make the bridge follow this planner (the first thing a planner does), sending the
        start again every 2 s until it is accepted, as guadal's planner does with anything
        unanswered (a bridge answers a repeated seq by repeating its answer)."""
        seq = self.send("start")
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.wait_ack(seq, "accepted", min(2.0, max(deadline - time.monotonic(), 0.0)))
                return seq
            except AssertionError:
                if time.monotonic() >= deadline:
                    raise
                self.send("start", seq=seq)

    def publish_status(self, state: str) -> None:
        self.client.publish(
            messages.topic(self.fleet, None, "status"),
            messages.encode("status", state=state, session=self.session),
            qos=1,
            retain=True,
        ).wait_for_publish(5)

    def keep_alive(self, interval: float = 0.3) -> None:
        """Ping in the background, as a live planner does, until :meth:`stop_pinging`."""
        self._pinging.set()

        def loop():
            while self._pinging.is_set():
                self.send("ping", seq=self.seq)  # a ping carries the last seq, it never takes a new one
                self._pinging_wait.wait(interval)

        self._pinging_wait = threading.Event()
        threading.Thread(target=loop, daemon=True).start()

    def stop_pinging(self) -> None:
        self._pinging.clear()
        if hasattr(self, "_pinging_wait"):
            self._pinging_wait.set()

    def raw(self, payload: bytes) -> None:
        self.client.publish(self.topic("command"), payload, qos=1).wait_for_publish(5)

    def decoded(self, channel: str) -> list[dict]:
        return [json.loads(m.payload) for m in self.on(self.topic(channel)) if m.payload]

    def acks(self, seq: int | None = None, status: str | None = None) -> list[dict]:
        return [
            a
            for a in self.decoded("ack")
            if (seq is None or a["seq"] == seq) and (status is None or a["status"] == status)
        ]

    def wait_ack(self, seq: int, status: str, timeout: float = 15.0) -> dict:
        self.wait(lambda: self.acks(seq, status), timeout, f"no '{status}' ack for seq {seq}")
        return self.acks(seq, status)[-1]

    def status(self) -> dict | None:
        found = self.decoded("status")
        return found[-1] if found else None

    def wait_status(self, predicate, timeout: float, what: str) -> dict:
        self.wait(lambda: (s := self.status()) is not None and predicate(s), timeout, what)
        return self.status()

    def goto(self, node: int, graph: NavGraph, **fields) -> int:
        return self.send("goto", node=node, lat=float(graph.lat[node]), lon=float(graph.lon[node]), **fields)


class Stack:
    """Emulator + bridge + planner client for one test, torn down in reverse order."""

    def __init__(
        self,
        broker,
        lake,
        tmp_path: Path,
        home_node: int,
        bridge_args=(),
        serial=False,
        speedup=40.0,
        fleet=None,
        route=None,
        start_planner_online=True,
        telemetry_hz=10,
        before_bridge=None,
        wait_armed=True,
        max_speed=2.0,
    ):
        self.map, self.graph, self.map_path = lake
        self.broker = broker
        self.fleet = fleet or f"t{uuid.uuid4().hex[:8]}"
        home = (float(self.graph.lat[home_node]), float(self.graph.lon[home_node]))
        self.emulator = Emulator(home, speedup=speedup, serial=serial, max_speed=max_speed)
        self.planner = Planner(broker, self.fleet)
        if start_planner_online:
            self.planner.publish_status("online")
        if before_bridge is not None:
            before_bridge(self.emulator)
        self.extra: list[subprocess.Popen] = []
        if route is not None:  # something between bridge and emulator (a MAVLink router)
            link, router = route(self.emulator, tmp_path)
            self.extra.append(router)
        else:
            link = self.emulator.vehicle["serial"] if serial else self.emulator.tcp
        self.log_path = tmp_path / "bridge.log"
        cmd = GUADAL + [
            "bridge",
            "--vehicle-id",
            "0",
            "--mavlink",
            link,
            "--broker",
            broker.url,
            "--map",
            str(self.map_path),
            "--fleet",
            self.fleet,
            "--arm",
            "--telemetry-hz",
            str(telemetry_hz),
            "--connect-timeout",
            "15",
            *bridge_args,
        ]
        self._log = open(self.log_path, "w")
        self.bridge = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, text=True)
        self.planner.wait_status(
            lambda s: s["state"] == "online" and (s.get("armed") or not wait_armed),
            20,
            f"bridge not online and armed (log: {self.log()})",
        )
        self.planner.start_session()

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def close(self):
        self.planner.stop_pinging()
        _stop(self.bridge)
        self._log.close()
        self.planner.close()
        for proc in self.extra:
            _stop(proc)
        self.emulator.close()


class Probe(threading.Thread):
    """A water-quality probe at the far end of a pseudo-terminal, speaking the documented protocol."""

    def __init__(self, fd: int, answers: list[bytes | None]):
        super().__init__(daemon=True)
        self.fd, self.answers, self.requests = fd, list(answers), []

    def run(self):
        buf = b""
        while self.answers:
            try:
                chunk = os.read(self.fd, 64)
            except OSError:
                return
            buf += chunk
            while b"\n" in buf and self.answers:
                line, buf = buf.split(b"\n", 1)
                self.requests.append(line)
                answer = self.answers.pop(0)
                if answer is not None:
                    os.write(self.fd, answer)

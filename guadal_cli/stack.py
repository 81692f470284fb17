"""The sitl stack in one call: broker, MAVLink boat emulator and one bridge per boat.

What the paper packaged as containers: ``guadal stack up`` (or a mission with
``backend: {level: sitl, launch: true}``) starts the processes, waits until each says it is
ready (the emulator's ready line, every bridge's retained ``online`` status — never a fixed
sleep), and records them in a state file; ``guadal stack down`` stops them all, SIGTERM first
and SIGKILL after a grace period.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .errors import GuadalError
from .fleet import messages as msg
from .fleet.broker import child_options, start_broker

STATE_FILE = "stack.json"


def default_state_dir() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / "guadal" / "stack"


def _proc_stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (state first), or None."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _start_ticks(pid: int) -> str | None:
    """The kernel's start time of a process: with the pid, it names the process uniquely."""
    stat = _proc_stat(pid)
    return stat[19] if stat and len(stat) > 19 else None


@dataclass
class StackProcess:
    """One process of the stack, identified well enough to be stopped from another process."""

    name: str
    pid: int
    log: str
    started: str | None = None
    popen: subprocess.Popen | None = field(default=None, repr=False, compare=False)

    def alive(self) -> bool:
        if self.popen is not None:
            return self.popen.poll() is None
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        stat = _proc_stat(self.pid)
        if stat is None:
            return True  # no /proc: trust the signal
        if stat[0] == "Z":
            return False  # exited; waits for a parent that may never reap it
        # a reused pid is another process: not ours to report (or to kill)
        return self.started is None or len(stat) <= 19 or stat[19] == self.started

    def signal(self, sig: int) -> None:
        if not self.alive():
            return
        try:
            os.killpg(self.pid, sig)  # each stack process leads its own session
        except (ProcessLookupError, PermissionError):
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def wait(self, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        if self.popen is not None:
            try:
                self.popen.wait(max(timeout, 0))
                return True
            except subprocess.TimeoutExpired:
                return False
        while self.alive():
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def tail(self, lines: int = 3) -> str:
        try:
            text = Path(self.log).read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return " / ".join(text[-lines:])


def stop_all(processes: list[StackProcess], grace: float = 5.0) -> None:
    """SIGTERM every process, wait up to ``grace`` seconds, then SIGKILL the stragglers."""
    for p in processes:
        p.signal(signal.SIGTERM)
    deadline = time.monotonic() + grace
    for p in processes:
        if not p.wait(max(deadline - time.monotonic(), 0.0)):
            p.signal(signal.SIGKILL)
            p.wait(5.0)


def _guadal(*args: str) -> list[str]:
    return [sys.executable, "-m", "guadal_cli", *args]


def _emulator(*args: str) -> list[str]:
    """``guadal sitl`` without loading the rest of the CLI: it starts faster."""
    return [sys.executable, "-m", "guadal_cli.sitl", *args]


class Stack:
    """A running (or recorded) sitl stack."""

    def __init__(self, state_dir: Path, info: dict, processes: list[StackProcess], own_dir: bool = False):
        self.state_dir = Path(state_dir)
        self.info = info
        self.processes = processes
        self._own_dir = own_dir
        self._down = False

    @property
    def broker_host(self) -> str:
        return self.info["broker"]["host"]

    @property
    def broker_port(self) -> int:
        return int(self.info["broker"]["port"])

    @property
    def broker_url(self) -> str:
        return f"mqtt://{self.broker_host}:{self.broker_port}"

    def pids(self) -> list[int]:
        return [p.pid for p in self.processes]

    # --- start -----------------------------------------------------------------------------
    @classmethod
    def launch(
        cls,
        *,
        map_path: str | Path,
        vehicles: int,
        homes: list[tuple[float, float]],
        speedup: float = 50.0,
        fleet: str = "guadal",
        broker_kind: str = "auto",
        broker_port: int = 0,
        failsafe_timeout: float = 30.0,
        emulator_args: Sequence[str] = (),
        bridge_args: Sequence[str] = (),
        timeout: float = 60.0,
        state_dir: Path | None = None,
        detach: bool = False,
    ) -> Stack:
        """Start broker, emulator and bridges; return when every bridge is online."""
        if len(homes) != vehicles:
            raise GuadalError(f"the stack needs one home per vehicle ({vehicles}), got {len(homes)}.")
        own = state_dir is None
        state_dir = Path(tempfile.mkdtemp(prefix="guadal-stack-")) if own else Path(state_dir)
        logs = state_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        info = {
            "fleet": fleet,
            "map": str(Path(map_path).resolve()),
            "vehicles": vehicles,
            "speedup": speedup,
            "homes": [list(h) for h in homes],
        }
        stack = cls(state_dir, info, [], own_dir=own)
        try:
            stack._start(
                map_path,
                vehicles,
                homes,
                speedup,
                fleet,
                broker_kind,
                broker_port,
                failsafe_timeout,
                list(emulator_args),
                list(bridge_args),
                timeout,
                detach,
            )
        except BaseException:
            stack.down()
            raise
        return stack

    def _spawn(self, name: str, cmd: list[str], detach: bool) -> StackProcess:
        log = self.state_dir / "logs" / f"{name}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        with open(log, "wb") as out:  # fresh: the ready line read later must be this run's
            popen = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
                **child_options(detach),
            )
        proc = StackProcess(name, popen.pid, str(log), _start_ticks(popen.pid), popen)
        self.processes.append(proc)
        return proc

    def _start(
        self,
        map_path,
        vehicles,
        homes,
        speedup,
        fleet,
        broker_kind,
        broker_port,
        failsafe_timeout,
        emulator_args,
        bridge_args,
        timeout,
        detach,
    ) -> None:
        deadline = time.monotonic() + timeout
        broker = start_broker(
            broker_kind,
            port=broker_port,
            workdir=self.state_dir / "logs",
            timeout=min(timeout, 15.0),
            detach=detach,
        )
        self.processes.append(
            StackProcess("broker", broker.pid, str(broker.log_path), _start_ticks(broker.pid), broker.process)
        )
        self.info["broker"] = {
            "kind": broker.kind,
            "host": broker.host,
            "port": broker.port,
            "url": broker.url,
        }

        fmt = lambda h: f"{h[0]:.8f},{h[1]:.8f}"  # noqa: E731
        emulator = self._spawn(
            "emulator",
            _emulator(
                "--vehicles",
                str(vehicles),
                "--home",
                fmt(homes[0]),
                "--homes",
                ";".join(map(fmt, homes)),
                "--speedup",
                f"{speedup:g}",
                "--base-port",
                "0",
                *emulator_args,
            ),
            detach,
        )
        ready = _wait_ready_line(emulator, deadline)
        endpoints = mavlink_endpoints(ready, vehicles)
        self.info["emulator"] = {"ready": ready, "mavlink": endpoints}

        watcher = StatusWatcher(broker.host, broker.port, fleet, vehicles)
        try:
            for i, endpoint in enumerate(endpoints):
                self._spawn(
                    f"bridge-{i}",
                    _guadal(
                        "bridge",
                        "--vehicle-id",
                        str(i),
                        "--mavlink",
                        endpoint,
                        "--broker",
                        broker.url,
                        "--map",
                        self.info["map"],
                        "--fleet",
                        fleet,
                        "--arm",
                        "--failsafe-timeout",
                        f"{failsafe_timeout:g}",
                        *bridge_args,
                    ),
                    detach,
                )
            watcher.wait_all_online(deadline, self.processes)
        finally:
            watcher.close()

    # --- state file ------------------------------------------------------------------------
    def save(self) -> Path:
        path = self.state_dir / STATE_FILE
        data = {
            **self.info,
            "processes": [
                {"name": p.name, "pid": p.pid, "log": p.log, "started": p.started} for p in self.processes
            ],
        }
        path.write_text(json.dumps(data, indent=2))
        return path

    @classmethod
    def load(cls, state_dir: Path) -> Stack | None:
        path = Path(state_dir) / STATE_FILE
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text())
            processes = [StackProcess(**p) for p in data.pop("processes")]
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise GuadalError(
                f"{path}: not a guadal stack state file ({exc.__class__.__name__}); remove it."
            ) from exc
        return cls(state_dir, data, processes)

    # --- stop ------------------------------------------------------------------------------
    def down(self, grace: float = 5.0) -> None:
        """Stop bridges, then the emulator, then the broker; safe to call twice."""
        if self._down:
            return
        self._down = True
        order = {"bridge": 0, "emulator": 1, "broker": 2}
        groups: dict[int, list[StackProcess]] = {}
        for p in self.processes:
            groups.setdefault(order.get(p.name.split("-")[0], 0), []).append(p)
        for key in sorted(groups):
            stop_all(groups[key], grace)
        state = self.state_dir / STATE_FILE
        if state.exists():
            state.unlink()
        if self._own_dir:
            shutil.rmtree(self.state_dir, ignore_errors=True)


def _wait_ready_line(proc: StackProcess, deadline: float) -> dict:
    """The first JSON object the emulator prints on stdout."""
    log = Path(proc.log)
    while True:
        try:
            lines = log.read_text(errors="replace").splitlines()
        except OSError:
            lines = []
        for line in lines:
            line = line.strip()
            if line.startswith("{"):
                try:
                    data = json.loads(line)
                except ValueError:
                    continue
                if isinstance(data, dict):
                    return data
        if not proc.alive():
            raise GuadalError(
                f"the MAVLink emulator exited before it was ready: {proc.tail() or 'no output'}."
            )
        if time.monotonic() > deadline:
            raise GuadalError(
                f"the MAVLink emulator printed no ready line in time: {proc.tail() or 'no output'}."
            )
        time.sleep(0.05)


def mavlink_endpoints(ready: dict, vehicles: int) -> list[str]:
    """One pymavlink connection string per vehicle, from the emulator's ready line."""
    entries = ready.get("vehicles")
    if not isinstance(entries, list):
        entries = [{"port": p} for p in ready.get("ports", [])]
    host = ready.get("host", "127.0.0.1")
    out = []
    for entry in entries:
        if isinstance(entry, int):
            entry = {"port": entry}
        if not isinstance(entry, dict):
            continue
        conn = entry.get("mavlink")
        port = entry.get("tcp", entry.get("port"))
        if not conn and isinstance(port, int):
            conn = f"tcp:{entry.get('host', host)}:{port}"
        if conn:
            out.append(str(conn))
    if len(out) != vehicles:
        raise GuadalError(
            f"the MAVLink emulator's ready line names {len(out)} vehicle links, not {vehicles}: {json.dumps(ready)}."
        )
    return out


class StatusWatcher:
    """Subscribes to every vehicle's retained status, to know when all bridges are online."""

    def __init__(self, host: str, port: int, fleet: str, vehicles: int):
        import paho.mqtt.client as mqtt

        self.vehicles = vehicles
        self.states: dict[int, str] = {}
        self._cond = threading.Condition()
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"guadal-stack-{os.getpid()}")
        self._client.on_connect = lambda c, *a: c.subscribe(f"{fleet}/vehicle/+/status", qos=1)
        self._client.on_message = self._on_message
        self._fleet = fleet
        self._client.connect(host, port, keepalive=10)
        self._client.loop_start()

    def _on_message(self, client, userdata, message) -> None:
        try:
            vid, _ = msg.parse_topic(self._fleet, message.topic)
            state = msg.decode(message.payload, {"status"})["state"]
        except msg.ProtocolError:
            return
        with self._cond:
            self.states[vid] = state
            self._cond.notify_all()

    def wait_all_online(self, deadline: float, processes: list[StackProcess]) -> None:
        def missing():
            return [i for i in range(self.vehicles) if self.states.get(i) != "online"]

        with self._cond:
            while missing():
                dead = [p for p in processes if not p.alive()]
                if dead:
                    raise GuadalError(
                        f"stack process '{dead[0].name}' exited while starting: {dead[0].tail() or 'no output'}."
                    )
                left = deadline - time.monotonic()
                if left <= 0:
                    late = missing()
                    tail = next((p.tail() for p in processes if p.name == f"bridge-{late[0]}"), "")
                    raise GuadalError(
                        f"bridge{'s' if len(late) > 1 else ''} {', '.join(map(str, late))} not online in time"
                        + (f": {tail}." if tail else ".")
                    )
                self._cond.wait(min(left, 0.2))

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()


def stack_up(
    *,
    map_path: Path,
    vehicles: int,
    speedup: float,
    broker_port: int = 0,
    state_dir: Path | None = None,
    fleet: str = "guadal",
    broker_kind: str = "auto",
    failsafe_timeout: float = 30.0,
    timeout: float = 60.0,
) -> Stack:
    """``guadal stack up``: homes on distinct water nodes near the lake's centre (where
    ``initial_positions: auto`` starts a mission), processes detached, a state file written."""
    from .graph import NavGraph
    from .maps.format import load_map
    from .mission import auto_positions

    state_dir = Path(state_dir) if state_dir else default_state_dir()
    existing = Stack.load(state_dir)
    if existing is not None and any(p.alive() for p in existing.processes):
        raise GuadalError(
            f"a stack is already up ({existing.broker_url}, state in {state_dir}); run 'guadal stack down' first."
        )
    graph = NavGraph(load_map(Path(map_path)))
    homes = [(float(graph.lat[n]), float(graph.lon[n])) for n in auto_positions(graph, vehicles)]
    stack = Stack.launch(
        map_path=map_path,
        vehicles=vehicles,
        homes=homes,
        speedup=speedup,
        fleet=fleet,
        broker_kind=broker_kind,
        broker_port=broker_port,
        failsafe_timeout=failsafe_timeout,
        timeout=timeout,
        state_dir=state_dir,
        detach=True,
    )
    try:
        stack.save()
    except BaseException:
        stack.down()
        raise
    return stack


def stack_down(state_dir: Path | None = None, grace: float = 5.0) -> Stack | None:
    """``guadal stack down``: stop what the state file records (None if nothing is recorded)."""
    stack = Stack.load(Path(state_dir) if state_dir else default_state_dir())
    if stack is not None:
        stack.down(grace)
    return stack

"""The sitl stack in one call: broker, MAVLink boat emulator and one bridge per boat.

What the paper packaged as containers: ``guadal stack up`` (or a mission with
``backend: {level: sitl, launch: true}``) starts the processes, waits until each says it is
ready (the emulator's ready line, every bridge's retained ``online`` status — never a fixed
sleep), and records them in a state file; ``guadal stack down`` stops them all, SIGTERM first
and SIGKILL after a grace period.

Every stack gets fresh broker users, an ACL and a fleet key (:mod:`guadal_cli.channel.credentials`)
in ``STATE_DIR/secrets`` (0700, files 0600), removed by ``down``. Each process kind has one
start function (:meth:`Stack.start_broker`, :meth:`Stack.start_emulator`,
:meth:`Stack.start_bridge`), so another autopilot (ArduPilot's own SITL) plugs in beside them.
"""

from __future__ import annotations

import json
import os
import queue
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

from pydantic import SecretStr

from .channel import protocol as msg
from .channel.broker import child_options, start_broker
from .channel.client import Channel, Endpoint
from .channel.credentials import FleetSecrets, private_dir, vehicle_user
from .errors import GuadalError
from .fleet.track import DEFAULT_TRACK_RATE_HZ

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
    cmd: list[str] = field(default_factory=list)
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


@dataclass
class Autopilot:
    """Which program flies each boat: guadal's emulator (one process) or ArduPilot's SITL
    (``ardurover``, one process per boat, started as ``sim_vehicle.py`` would)."""

    kind: str = "guadal"  # guadal | ardupilot (AUTOPILOTS below)
    binary: str | None = None  # ardurover, for ardupilot
    defaults: Sequence[str] = ()  # ArduPilot parameter files read before guadal's own
    mavproxy: bool = False  # ardupilot: MAVProxy per boat, forwarding to UDP 14550+10i
    speed: float = 0.5  # the fleet's nominal speed: ArduPilot's WP_SPEED and CRUISE_SPEED
    track_rate: float = DEFAULT_TRACK_RATE_HZ  # GPS fixes per second of the autopilot's clock


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

    @property
    def secure(self) -> bool:
        return self.info.get("secure", True)

    @property
    def secrets(self) -> FleetSecrets:
        return FleetSecrets(self.state_dir / "secrets")

    def planner_backend(self) -> dict:
        """The mission ``backend:`` settings that reach this stack as its planner user."""
        settings = {
            "level": "sitl",
            "host": self.broker_host,
            "port": self.broker_port,
            "fleet": self.info["fleet"],
        }
        if self.secure:
            settings["username"] = "planner"
            settings["password_file"] = str(self.secrets.user_password_file("planner"))
            settings["key_file"] = str(self.secrets.key_file)
        return settings

    def endpoint(self, user: str) -> Endpoint:
        """How ``user`` (planner, operator, watcher, vehicle-N) logs in to this stack's broker."""
        if not self.secure:
            return Endpoint(self.broker_host, self.broker_port)
        password = self.secrets.user_password_file(user).read_text().strip()
        return Endpoint(self.broker_host, self.broker_port, username=user, password=SecretStr(password))

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
        secure: bool = True,
        autopilot: Autopilot | None = None,
    ) -> Stack:
        """Start broker, emulator and bridges; return when every bridge is online.

        ``secure=False`` (benchmarks only: the baseline the security's cost is measured against)
        starts an anonymous broker and bridges that neither sign nor check signatures."""
        if len(homes) != vehicles:
            raise GuadalError(f"the stack needs one home per vehicle ({vehicles}), got {len(homes)}.")
        own = state_dir is None
        state_dir = Path(tempfile.mkdtemp(prefix="guadal-stack-")) if own else private_dir(Path(state_dir))
        logs = state_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        info = {
            "fleet": fleet,
            "map": str(Path(map_path).resolve()),
            "vehicles": vehicles,
            "speedup": speedup,
            "homes": [list(h) for h in homes],
            "secure": secure,
            "autopilot": (autopilot or Autopilot()).kind,
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
                autopilot or Autopilot(),
            )
        except BaseException:
            stack.down()
            raise
        return stack

    def _spawn(self, name: str, cmd: list[str], detach: bool, cwd: Path | None = None) -> StackProcess:
        log = self.state_dir / "logs" / f"{name}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        existing = next((p for p in self.processes if p.name == name), None)
        with open(log, "wb") as out:  # fresh: the ready line read later must be this run's
            popen = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=cwd,
                **child_options(detach),
            )
        proc = StackProcess(name, popen.pid, str(log), _start_ticks(popen.pid), list(cmd), popen)
        if existing is not None:
            self.processes[self.processes.index(existing)] = proc
        else:
            self.processes.append(proc)
        return proc

    def restart(self, name: str, grace: float = 5.0) -> StackProcess:
        """Stop one process of the stack and start it again with the same command (same ports)."""
        proc = next((p for p in self.processes if p.name == name), None)
        if proc is None or not proc.cmd:
            raise GuadalError(f"the stack has no restartable process '{name}'.")
        stop_all([proc], grace)
        return self._spawn(name, proc.cmd, detach=False)

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
        autopilot: Autopilot,
    ) -> None:
        deadline = time.monotonic() + timeout
        if self.secure:
            FleetSecrets.generate(self.state_dir / "secrets", fleet, vehicles)
        self.start_broker(broker_kind, broker_port, min(timeout, 15.0), detach)
        self.info["planner"] = self.planner_backend()
        if autopilot.kind not in AUTOPILOTS:
            raise GuadalError(f"autopilot must be one of {', '.join(AUTOPILOTS)} (got '{autopilot.kind}').")
        endpoints = AUTOPILOTS[autopilot.kind](
            self, homes, speedup, autopilot, emulator_args, deadline, detach
        )
        bridge_args = ["--track-rate", f"{autopilot.track_rate:g}", *bridge_args]
        watcher = StatusWatcher(
            self.endpoint("watcher"),
            fleet,
            vehicles,
            self.secrets.key_file.read_bytes().strip() if self.secure else None,
        )
        try:
            for i, endpoint in enumerate(endpoints):
                self.start_bridge(i, endpoint, fleet, failsafe_timeout, bridge_args, detach)
            watcher.wait_all_online(deadline, self.processes)
        finally:
            watcher.close()

    def start_broker(self, kind: str, port: int, timeout: float, detach: bool) -> None:
        """The broker, with this stack's users and ACL (no anonymous client gets in)."""
        broker = start_broker(
            kind,
            port=port,
            workdir=self.state_dir / "logs",
            timeout=timeout,
            detach=detach,
            secrets=self.secrets if self.secure else None,
        )
        self.processes.append(
            StackProcess(
                "broker", broker.pid, str(broker.log_path), _start_ticks(broker.pid), [], broker.process
            )
        )
        self.info["broker"] = {
            "kind": broker.kind,
            "host": broker.host,
            "port": broker.port,
            "url": broker.url,
        }

    def start_emulator(
        self, homes, speedup, autopilot: Autopilot, emulator_args, deadline: float, detach: bool
    ) -> list[str]:
        """The MAVLink boat emulator; returns one pymavlink connection string per boat."""
        fmt = lambda h: f"{h[0]:.8f},{h[1]:.8f}"  # noqa: E731
        emulator = self._spawn(
            "emulator",
            _guadal(
                "sitl",
                "--vehicles",
                str(len(homes)),
                "--home",
                fmt(homes[0]),
                "--homes",
                ";".join(map(fmt, homes)),
                "--speedup",
                f"{speedup:g}",
                "--base-port",
                "0",
                "--track-rate",
                f"{autopilot.track_rate:g}",
                *emulator_args,
            ),
            detach,
        )
        ready = _wait_ready_line(emulator, deadline)
        endpoints = mavlink_endpoints(ready, len(homes))
        self.info["emulator"] = {"ready": ready, "mavlink": endpoints}
        return endpoints

    def start_ardupilot(
        self, homes, speedup, autopilot: Autopilot, emulator_args, deadline: float, detach: bool
    ) -> list[str]:
        """One ``ardurover`` per boat, each in its own folder, as ``sim_vehicle.py`` starts them;
        returns their serial-0 TCP endpoints once each listens there (SITL waits for its client)."""
        from .sitl.ardupilot import plan_rover_fleet

        if not autopilot.binary:
            raise GuadalError("autopilot ardupilot needs the path of ArduPilot's SITL binary (ardurover).")
        plan = plan_rover_fleet(
            binary=autopilot.binary,
            homes=homes,
            speedup=speedup,
            speed=autopilot.speed,
            state_dir=self.state_dir,
            extra_defaults=list(autopilot.defaults),
        )
        rovers = []
        for i, rover in enumerate(plan.instances):
            cmd = [*rover.command(), *emulator_args]
            rovers.append(self._spawn(f"ardupilot-{i}", cmd, detach, cwd=plan.workdirs[i]))
        for rover, proc in zip(plan.instances, rovers):
            _wait_listening(proc, rover.port, deadline)
        if autopilot.mavproxy:
            for i in range(len(plan.instances)):
                self._spawn(f"mavproxy-{i}", plan.mavproxy_command(i), detach)
        endpoints = [rover.mavlink_url for rover in plan.instances]
        self.info["ardupilot"] = {
            "instances": [rover.instance for rover in plan.instances],
            "defaults": str(plan.defaults_file),
            "mavlink": endpoints,
        }
        return endpoints

    def start_bridge(
        self, vehicle: int, mavlink: str, fleet: str, failsafe_timeout: float, bridge_args, detach
    ):
        """One bridge, logged in as ``vehicle-N`` with its password file and the fleet key."""
        user = vehicle_user(vehicle)
        login = [
            "--broker",
            f"mqtt://{user}@{self.broker_host}:{self.broker_port}",
            "--password-file",
            str(self.secrets.user_password_file(user)),
            "--key-file",
            str(self.secrets.key_file),
        ]
        if not self.secure:
            login = ["--broker", self.broker_url]
        return self._spawn(
            f"bridge-{vehicle}",
            _guadal(
                "bridge",
                "--vehicle-id",
                str(vehicle),
                "--mavlink",
                mavlink,
                *login,
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

    # --- state file ------------------------------------------------------------------------
    def save(self) -> Path:
        path = self.state_dir / STATE_FILE
        data = {
            **self.info,
            "processes": [
                {"name": p.name, "pid": p.pid, "log": p.log, "started": p.started, "cmd": p.cmd}
                for p in self.processes
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
        shutil.rmtree(self.state_dir / "secrets", ignore_errors=True)
        if self._own_dir:
            shutil.rmtree(self.state_dir, ignore_errors=True)


def _wait_until(proc: StackProcess, ready, deadline: float, *, exited: str, late: str):
    """Poll ``ready()`` until it returns something; one sentence (``exited`` or ``late``, then the
    process's last output) if ``proc`` dies first or the deadline passes."""
    while (value := ready()) is None:
        if not proc.alive():
            raise GuadalError(f"{exited}: {proc.tail() or 'no output'}.")
        if time.monotonic() > deadline:
            raise GuadalError(f"{late}: {proc.tail() or 'no output'}.")
        time.sleep(0.05)
    return value


def _wait_ready_line(proc: StackProcess, deadline: float) -> dict:
    """The first JSON object the emulator prints on stdout."""
    return _wait_until(
        proc,
        lambda: _first_json_object(Path(proc.log)),
        deadline,
        exited="the MAVLink emulator exited before it was ready",
        late="the MAVLink emulator printed no ready line in time",
    )


def _first_json_object(log: Path) -> dict | None:
    try:
        lines = log.read_text(errors="replace").splitlines()
    except OSError:
        return None
    for line in lines:
        line = line.strip()
        if line.startswith("{"):
            try:
                data = json.loads(line)
            except ValueError:
                continue
            if isinstance(data, dict):
                return data
    return None


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


#: how the stack starts each kind of autopilot: Stack method returning one MAVLink endpoint per boat
AUTOPILOTS = {"guadal": Stack.start_emulator, "ardupilot": Stack.start_ardupilot}


def _listening(port: int) -> bool:
    """Is something listening on TCP ``port`` here? Read from /proc, without connecting: SITL
    takes its first client on serial 0 as the one it serves."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 3 and fields[3] == "0A" and int(fields[1].rsplit(":", 1)[1], 16) == port:
                return True
    return False


def _wait_listening(proc: StackProcess, port: int, deadline: float) -> None:
    _wait_until(
        proc,
        lambda: True if _listening(port) else None,
        deadline,
        exited=f"{proc.name} exited before it listened on port {port}",
        late=f"{proc.name} did not listen on port {port} in time",
    )


class StatusWatcher:
    """Subscribes to every vehicle's retained status, to know when all bridges are online."""

    def __init__(self, endpoint: Endpoint, fleet: str, vehicles: int, key: bytes | None = None):
        self.vehicles = vehicles
        self.states: dict[int, str] = {}
        self._cond = threading.Condition()
        self._events: queue.Queue = queue.Queue()
        self._channel = Channel(
            endpoint,
            fleet=fleet,
            client_id=f"guadal-stack-{os.getpid()}",
            inbox=self._events,
            subscriptions=[(f"{fleet}/vehicle/+/status", 1)],
            codec=msg.Codec(key),
        )
        self._channel.start()
        self._reader = threading.Thread(target=self._read, name="guadal-stack-watcher", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        """The one loop that changes :attr:`states`."""
        while True:
            event = self._events.get()
            if event is None:
                return
            if event[0] == "message" and event[2] == "status" and event[1] is not None:
                with self._cond:
                    self.states[event[1]] = event[3]["state"]
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
        self._channel.close()
        self._events.put(None)


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
    autopilot: Autopilot | None = None,
    emulator_args: Sequence[str] = (),
    bridge_args: Sequence[str] = (),
) -> Stack:
    """``guadal stack up``: homes on distinct water nodes near the lake's centre (where
    ``initial_positions: auto`` starts a mission), processes detached, a state file written.
    ``emulator_args`` and ``bridge_args`` go to every autopilot and bridge, as a mission's
    ``backend: {launch: true}`` passes them."""
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
        emulator_args=emulator_args,
        bridge_args=bridge_args,
        timeout=timeout,
        state_dir=state_dir,
        detach=True,
        autopilot=autopilot,
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

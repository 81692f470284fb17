"""ArduPilot's own SITL (``ardurover``) as the sitl level's autopilot: its command line and defaults.

The command line is the one ArduPilot's ``Tools/autotest/sim_vehicle.py -v Rover -f motorboat``
runs for each instance::

    ardurover -S --model motorboat --speedup K --sysid N --defaults FILES -I i --home LAT,LON,ALT,HDG

``-S`` uses the synthetic clock (needed for ``--speedup``), ``-I i`` moves every port by ``10 i``
(serial 0, where a bridge connects, is ``tcp:127.0.0.1:5760+10i``; SITL waits there for its first
client), ``--sysid`` is what ``sim_vehicle.py --auto-sysid`` passes, and ``--defaults`` takes
comma-separated parameter files, later files overriding earlier ones. guadal writes the last file:
the settings a boat driven in GUIDED by guadal's bridge needs. Each instance runs in a folder of
its own, as ``sim_vehicle.py -n`` arranges, because SITL keeps its parameters (``eeprom.bin``) and
logs in the working directory.

``guadal sitl`` accepts the same options, so either program can stand in for the other.
"""

from __future__ import annotations

import socket
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import GuadalError

#: ArduPilot's SITL model of a motor boat (``sim_vehicle.py -v Rover -f motorboat``)
BOAT_MODEL = "motorboat"
#: serial 0 of instance 0; every instance adds 10 to each of its ports
SERIAL0_PORT = 5760
#: ports of one instance besides serial 0: serials 1 and 2 (TCP) and the simulator's RC input (UDP)
OTHER_TCP_PORTS = (5762, 5763)
RC_INPUT_UDP_PORT = 5501
#: highest instance number tried when looking for free ports
MAX_INSTANCE = 200


def serial0_port(instance: int) -> int:
    return SERIAL0_PORT + 10 * instance


def home_text(lat: float, lon: float, alt: float = 0.0, heading: float = 0.0) -> str:
    """SITL's ``--home``: latitude, longitude, altitude (m) and heading (degrees)."""
    return f"{lat:.8f},{lon:.8f},{alt:g},{heading:g}"


def guided_defaults(speed: float, wp_radius: float) -> str:
    """The parameter file guadal adds after ArduPilot's own: a boat that guadal's bridge drives in GUIDED."""
    lines = [
        "# written by guadal: an ArduPilot Rover boat driven in GUIDED by guadal's bridge",
        "FRAME_CLASS 2       # boat: heartbeats say MAV_TYPE_SURFACE_BOAT, boats loiter on arrival",
        f"WP_SPEED {speed:g}  # the mission's fleet speed, m/s",
        f"CRUISE_SPEED {speed:g}",
        f"WP_RADIUS {wp_radius:g}  # inside the bridge's arrival radius: steering goes on until the bridge counts the hop",
        "FS_ACTION 2         # failsafe: Hold",
        "FS_GCS_ENABLE 1     # the bridge's heartbeat is the ground station: if it stops, the boat holds",
        "FS_TIMEOUT 5",
        "FS_THR_ENABLE 0     # no radio transmitter in SITL",
        "",
    ]
    return "\n".join(lines)


@dataclass
class RoverInstance:
    """One ``ardurover`` process: what ``sim_vehicle.py`` would run for instance ``instance``."""

    binary: str
    instance: int
    home: tuple[float, float]
    speedup: float
    defaults: Sequence[Path | str]
    sysid: int
    model: str = BOAT_MODEL
    extra_args: Sequence[str] = field(default_factory=tuple)

    @property
    def port(self) -> int:
        """Serial 0, where the bridge connects."""
        return serial0_port(self.instance)

    @property
    def mavlink_url(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def command(self) -> list[str]:
        return [
            self.binary,
            "-S",
            "--model",
            self.model,
            "--speedup",
            f"{self.speedup:g}",
            "--sysid",
            str(self.sysid),
            "--defaults",
            ",".join(str(p) for p in self.defaults),
            *self.extra_args,
            f"-I{self.instance}",
            "--home",
            home_text(*self.home),
        ]


def _tcp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def instance_free(instance: int) -> bool:
    """Are all the ports of an instance free on this machine right now?"""
    shift = 10 * instance
    return all(_tcp_free(p + shift) for p in (SERIAL0_PORT, *OTHER_TCP_PORTS)) and _udp_free(
        RC_INPUT_UDP_PORT + shift
    )


def free_instances(count: int, first: int = 0) -> list[int]:
    """``count`` consecutive instance numbers from ``first`` up whose ports are all free.

    Several stacks (or several users) share a machine: SITL's ports are fixed per instance, so
    the instances are chosen where nothing listens yet.
    """
    start = first
    while start + count - 1 <= MAX_INSTANCE:
        block = list(range(start, start + count))
        busy = [i for i in block if not instance_free(i)]
        if not busy:
            return block
        start = busy[-1] + 1
    raise GuadalError(
        f"no {count} consecutive SITL instances with free ports between {first} and {MAX_INSTANCE} "
        f"(instance i uses TCP {SERIAL0_PORT}+10i and the ports after it); stop other simulators."
    )


#: MAVProxy, where a user wants a console or a ground station: serial 1 of instance i (5762+10i)
#: in, UDP 14550+10i out, as sim_vehicle.py forwards it
MAVPROXY_IN_PORT = 5762
MAVPROXY_OUT_PORT = 14550


@dataclass
class RoverFleet:
    """Everything needed to start one ``ardurover`` per vehicle: written files, commands, folders."""

    instances: list[RoverInstance]
    workdirs: list[Path]
    defaults_file: Path

    def mavproxy_command(self, i: int, executable: str = "mavproxy.py") -> list[str]:
        """MAVProxy on serial 1 of vehicle ``i``, forwarding to UDP 14550+10i (QGroundControl's port)."""
        shift = 10 * self.instances[i].instance
        return [
            executable,
            "--master",
            f"tcp:127.0.0.1:{MAVPROXY_IN_PORT + shift}",
            "--out",
            f"udp:127.0.0.1:{MAVPROXY_OUT_PORT + shift}",
            "--daemon",
        ]


def plan_rover_fleet(
    *,
    binary: str | Path,
    homes: Sequence[tuple[float, float]],
    speedup: float,
    speed: float,
    state_dir: Path,
    wp_radius: float = 1.0,
    extra_defaults: Sequence[str | Path] = (),
    model: str = BOAT_MODEL,
    first_instance: int | None = None,
) -> RoverFleet:
    """Write guadal's parameter file and one working folder per vehicle; return the commands.

    ``extra_defaults`` (e.g. ArduPilot's ``Tools/autotest/default_params/rover.parm`` and
    ``motorboat.parm``, which ``sim_vehicle.py`` passes) come first; guadal's file comes last and
    wins. With ``first_instance`` None the instances are the first ones whose ports are free.
    """
    binary = str(Path(binary).expanduser())
    if not Path(binary).is_file():
        raise GuadalError(
            f"the ArduPilot SITL binary '{binary}' does not exist; build it in an ArduPilot checkout with "
            "'./waf configure --board sitl && ./waf rover' and give build/sitl/bin/ardurover."
        )
    missing = [str(p) for p in extra_defaults if not Path(p).expanduser().is_file()]
    if missing:
        raise GuadalError(f"the ArduPilot parameter file '{missing[0]}' does not exist.")
    state_dir = Path(state_dir)
    state_dir.mkdir(parents=True, exist_ok=True)
    defaults_file = state_dir / "guadal-rover.parm"
    defaults_file.write_text(guided_defaults(speed, wp_radius))
    numbers = (
        free_instances(len(homes))
        if first_instance is None
        else list(range(first_instance, first_instance + len(homes)))
    )
    instances, workdirs = [], []
    for v, (home, number) in enumerate(zip(homes, numbers)):
        workdir = state_dir / f"ardupilot-{v}"  # eeprom.bin and logs of this instance
        workdir.mkdir(exist_ok=True)
        workdirs.append(workdir)
        instances.append(
            RoverInstance(
                binary=binary,
                instance=number,
                home=home,
                speedup=speedup,
                defaults=[*(Path(p).expanduser().resolve() for p in extra_defaults), defaults_file.resolve()],
                sysid=v + 1,
                model=model,
            )
        )
    return RoverFleet(instances=instances, workdirs=workdirs, defaults_file=defaults_file)

"""``guadal sitl``: run MAVLink boat emulators (ArduPilot Rover/Boat semantics) for the sitl level."""

from __future__ import annotations

import json
import signal
import sys
from typing import Annotated

import typer

from ..console import flags
from ..errors import GuadalError

app = typer.Typer()

#: SitlOptions' fields, as this command's flags
_FLAGS = {
    "vehicles": "--vehicles",
    "homes": "--homes",
    "base_port": "--base-port",
    "udp_out": "--udp-out",
    "speedup": "--speedup",
    "max_speed": "--max-speed",
    "max_rate": "--max-rate",
    "serial": "--serial",
    "sysid": "--sysid",
    "track_rate": "--track-rate",
    "gps_noise_m": "--gps-noise",
    "current_en": "--current",
}


def _latlon(text: str, option: str) -> tuple[float, float]:
    """LAT,LON, or ArduPilot SITL's LAT,LON,ALT,HEADING (altitude and heading are not modelled)."""
    try:
        numbers = [float(part) for part in text.split(",")]
        if len(numbers) not in (2, 4):
            raise ValueError
        lat, lon = numbers[:2]
    except ValueError:
        raise GuadalError(
            f"{option} {text!r} must be LAT,LON (or LAT,LON,ALT,HEADING as ArduPilot SITL takes it) in decimal "
            "degrees, e.g. 37.41795,-5.98345."
        ) from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise GuadalError(f"{option} {text!r} is outside -90..90 latitude / -180..180 longitude.")
    return lat, lon


def _pair(text: str, option: str) -> tuple[float, float]:
    try:
        east, north = (float(part) for part in text.split(","))
    except ValueError:
        raise GuadalError(f"{option} {text!r} must be two numbers E,N in m/s, e.g. 0.05,-0.02.") from None
    return east, north


def _host_port(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise GuadalError(f"--udp-out {text!r} must be HOST:PORT, e.g. 127.0.0.1:14550.")
    return host, int(port)


@app.command("sitl")
def sitl(
    vehicles: Annotated[
        int, typer.Option("--vehicles", "-n", help="Number of boats; vehicle i gets system id i+1.")
    ] = 1,
    home: Annotated[
        str, typer.Option(help="LAT,LON of vehicle 1; the others start 5 m apart eastwards.")
    ] = "37.41795,-5.98345",
    homes: Annotated[
        str | None, typer.Option(help="LAT,LON;LAT,LON;... one home per vehicle (overrides --home).")
    ] = None,
    speedup: Annotated[float, typer.Option(help="Simulated seconds per wall second.")] = 1.0,
    base_port: Annotated[
        int, typer.Option(help="TCP port of vehicle 1; vehicle i listens on base+10*i. 0 picks free ports.")
    ] = 5760,
    host: Annotated[str, typer.Option(help="Address the TCP servers listen on.")] = "127.0.0.1",
    max_speed: Annotated[
        float, typer.Option(help="Top speed of the hull in m/s (also WP_SPEED's default).")
    ] = 0.5,
    gps_noise: Annotated[
        float, typer.Option(help="Standard deviation of reported GPS positions, metres.")
    ] = 0.0,
    current: Annotated[str, typer.Option(help="Water current E,N in m/s that drifts every boat.")] = "0,0",
    udp_out: Annotated[
        str | None, typer.Option(help="Also stream to HOST:PORT (+10*i for vehicle i).")
    ] = None,
    serial: Annotated[
        list[str] | None,
        typer.Option(help="Serial device per vehicle (repeat), or 'pty' for a fresh pseudo-terminal each."),
    ] = None,
    baud: Annotated[int, typer.Option(help="Baud rate for --serial devices.")] = 115200,
    seed: Annotated[int, typer.Option(help="Seed of the GPS noise.")] = 0,
    max_rate: Annotated[
        float, typer.Option(help="Cap on wall-clock messages per second of each telemetry stream.")
    ] = 20.0,
    track_rate: Annotated[
        float,
        typer.Option(
            help="Position fixes (GLOBAL_POSITION_INT) kept per simulated second whatever the speed-up, "
            "when asked for at least that rate; the --max-rate cap does not thin them below it."
        ),
    ] = 1.0,
    instance: Annotated[
        int | None,
        typer.Option(
            "-I",
            "--instance",
            help="As ardurover's -I: vehicle 1 listens on 5760+10*I (instead of --base-port).",
        ),
    ] = None,
    model: Annotated[
        str, typer.Option(help="As ardurover's --model: motorboat, boat or sailboat (a boat), or rover.")
    ] = "motorboat",
    defaults: Annotated[
        str | None,
        typer.Option(
            help="As ardurover's --defaults: comma-separated parameter files (NAME VALUE per line), later ones win."
        ),
    ] = None,
    sysid: Annotated[int, typer.Option(help="System id of vehicle 1; vehicle i gets SYSID+i-1.")] = 1,
    synthetic_clock: Annotated[
        bool,
        typer.Option(
            "-S", "--synthetic-clock", help="Accepted as ardurover takes it (the emulator's clock always is)."
        ),
    ] = False,
    wipe: Annotated[
        bool,
        typer.Option(
            "-w", "--wipe", help="Accepted as ardurover takes it (the emulator keeps no parameters on disk)."
        ),
    ] = False,
) -> None:
    """Run N emulated MAVLink boats; prints one JSON line when every endpoint is listening."""
    # a launcher may signal us while we start: remember it, and stop quietly once started
    early_stop: list[int] = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda signum, _frame: early_stop.append(signum))
    if instance is not None:
        if not 0 <= instance <= (65535 - 5760) // 10 - vehicles:
            raise GuadalError(f"-I {instance} must be an instance number from 0 (ports 5760+10*I).")
        base_port = 5760 + 10 * instance
    from ..sitl.params import MODELS, read_param_files

    if model not in MODELS:
        raise GuadalError(f"--model {model!r} is not one of {', '.join(MODELS)}.")
    param_defaults = {"FRAME_CLASS": float(MODELS[model])}
    param_defaults.update(read_param_files([p for p in (defaults or "").split(",") if p.strip()]))
    fields = dict(
        vehicles=vehicles,
        home=_latlon(home, "--home"),
        homes=[_latlon(part.strip(), "--homes") for part in homes.split(";") if part.strip()]
        if homes
        else None,
        speedup=speedup,
        base_port=base_port,
        host=host,
        max_speed=max_speed,
        gps_noise_m=gps_noise,
        current_en=_pair(current, "--current"),
        udp_out=_host_port(udp_out) if udp_out else None,
        serial=list(serial or []),
        baud=baud,
        seed=seed,
        max_rate=max_rate,
        sysid=sysid,
        track_rate=track_rate,
        param_defaults=param_defaults,
    )
    if gps_noise < 0:
        raise GuadalError(f"--gps-noise must be zero or positive (got {gps_noise}).")
    from ..sitl.server import SitlOptions, SitlServer, stats  # after the cheap checks: pymavlink is slow

    with flags(_FLAGS):
        server = SitlServer(SitlOptions(**fields))
        ready = server.open()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: server.request_stop())
    if early_stop:
        server.request_stop()
    sys.stdout.write(json.dumps(ready) + "\n")
    sys.stdout.flush()
    try:
        server.run()
    finally:
        summary = stats(server)
        server.close()
    sys.stderr.write(json.dumps({"stopped": True, "vehicles": summary}) + "\n")

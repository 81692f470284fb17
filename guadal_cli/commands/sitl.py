"""``guadal sitl``: run MAVLink boat emulators (ArduPilot Rover/Boat semantics) for the sitl level."""

from __future__ import annotations

import json
import signal
import sys

import typer

from ..errors import GuadalError


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


def sitl(
    vehicles: int = typer.Option(
        1, "--vehicles", "-n", help="Number of boats; vehicle i gets system id i+1."
    ),
    home: str = typer.Option(
        "37.41795,-5.98345", "--home", help="LAT,LON of vehicle 1; the others start 5 m apart eastwards."
    ),
    homes: str | None = typer.Option(
        None, "--homes", help="LAT,LON;LAT,LON;... one home per vehicle (overrides --home)."
    ),
    speedup: float = typer.Option(1.0, "--speedup", help="Simulated seconds per wall second."),
    base_port: int = typer.Option(
        5760, "--base-port", help="TCP port of vehicle 1; vehicle i listens on base+10*i. 0 picks free ports."
    ),
    host: str = typer.Option("127.0.0.1", "--host", help="Address the TCP servers listen on."),
    max_speed: float = typer.Option(
        0.5, "--max-speed", help="Top speed of the hull in m/s (also WP_SPEED's default)."
    ),
    gps_noise: float = typer.Option(
        0.0, "--gps-noise", help="Standard deviation of reported GPS positions, metres."
    ),
    current: str = typer.Option("0,0", "--current", help="Water current E,N in m/s that drifts every boat."),
    udp_out: str | None = typer.Option(
        None, "--udp-out", help="Also stream to HOST:PORT (+10*i for vehicle i)."
    ),
    serial: list[str] | None = typer.Option(
        None,
        "--serial",
        help="Serial device per vehicle (repeat), or 'pty' for a fresh pseudo-terminal each.",
    ),
    baud: int = typer.Option(115200, "--baud", help="Baud rate for --serial devices."),
    seed: int = typer.Option(0, "--seed", help="Seed of the GPS noise."),
    max_rate: float = typer.Option(
        20.0, "--max-rate", help="Cap on wall-clock messages per second of each telemetry stream."
    ),
    track_rate: float = typer.Option(
        1.0,
        "--track-rate",
        help="Position fixes (GLOBAL_POSITION_INT) kept per simulated second whatever the speed-up, "
        "when asked for at least that rate; the --max-rate cap does not thin them below it.",
    ),
    instance: int | None = typer.Option(
        None,
        "-I",
        "--instance",
        help="As ardurover's -I: vehicle 1 listens on 5760+10*I (instead of --base-port).",
    ),
    model: str = typer.Option(
        "motorboat", "--model", help="As ardurover's --model: motorboat, boat or sailboat (a boat), or rover."
    ),
    defaults: str | None = typer.Option(
        None,
        "--defaults",
        help="As ardurover's --defaults: comma-separated parameter files (NAME VALUE per line), later ones win.",
    ),
    sysid: int = typer.Option(1, "--sysid", help="System id of vehicle 1; vehicle i gets SYSID+i-1."),
    synthetic_clock: bool = typer.Option(
        False,
        "-S",
        "--synthetic-clock",
        help="Accepted as ardurover takes it (the emulator's clock always is).",
    ),
    wipe: bool = typer.Option(
        False,
        "-w",
        "--wipe",
        help="Accepted as ardurover takes it (the emulator keeps no parameters on disk).",
    ),
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
    from ..sitl.server import (  # after the cheap checks: pymavlink is slow to import
        SitlOptions,
        SitlServer,
        stats,
    )

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


def register(app: typer.Typer) -> None:
    app.command("sitl")(sitl)

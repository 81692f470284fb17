"""``guadal bridge``: one vehicle's MQTT <-> MAVLink bridge (runs on the boat's companion computer)."""

from __future__ import annotations

import logging
import signal
from pathlib import Path
from typing import Annotated

import typer

from ..errors import GuadalError

app = typer.Typer()


class _Stopped(BaseException):
    """SIGTERM/SIGINT before the bridge was serving (a BaseException, so no "except Exception" swallows it)."""


@app.command("bridge")
def bridge(
    vehicle_id: Annotated[int | None, typer.Option(help="Vehicle number N (topics F/vehicle/N/...).")] = None,
    mavlink: Annotated[
        str | None, typer.Option(help="tcp:HOST:PORT, udpin:HOST:PORT, /dev/ttyACM0 ...")
    ] = None,
    broker: Annotated[
        str | None, typer.Option(help="mqtt://host:port or mqtt://user@host:port (mqtts:// for TLS).")
    ] = None,
    password_file: Annotated[
        str | None, typer.Option(help="File holding the broker password (or password_env in --config).")
    ] = None,
    key_file: Annotated[
        str | None, typer.Option(help="File holding the fleet key that signs every message (or key_env).")
    ] = None,
    map_path: Annotated[
        str | None, typer.Option("--map", help="The guadal map file the planner uses.")
    ] = None,
    fleet: Annotated[
        str | None, typer.Option(help="Topic prefix shared with the planner (default: guadal).")
    ] = None,
    sensor: Annotated[
        str | None, typer.Option(help="synthetic:CSV, replay:CSV or serial:/dev/ttyUSB0.")
    ] = None,
    baud: Annotated[
        int | None, typer.Option(help="Baud rate of a serial autopilot (default: 115200).")
    ] = None,
    arm: Annotated[
        bool | None,
        typer.Option("--arm/--no-arm", help="Arm at start-up, retrying until the autopilot agrees."),
    ] = None,
    arm_retry_interval: Annotated[
        float | None, typer.Option(help="Seconds between arming attempts (default: 5).")
    ] = None,
    guided: Annotated[
        bool | None, typer.Option("--guided/--no-guided", help="Set GUIDED at start-up.")
    ] = None,
    failsafe_timeout: Annotated[
        float | None, typer.Option(help="Seconds of planner silence before HOLD (default: 10).")
    ] = None,
    arrival_radius: Annotated[
        float | None, typer.Option(help="Metres that count as reached (default: 2).")
    ] = None,
    telemetry_hz: Annotated[
        float | None, typer.Option(help="Telemetry messages per second (default: 2).")
    ] = None,
    track_rate: Annotated[
        float | None,
        typer.Option(
            help="GPS fixes published per second of the autopilot's clock, simulated time in SITL (default: 1)."
        ),
    ] = None,
    refine: Annotated[
        int | None, typer.Option(help="High-resolution factor of the path grid (default: 3).")
    ] = None,
    waypoint_command: Annotated[str | None, typer.Option(help="position_target or mission_item.")] = None,
    hold_on_exit: Annotated[
        bool | None,
        typer.Option("--hold-on-exit/--no-hold-on-exit", help="HOLD when the bridge stops (default: on)."),
    ] = None,
    connect_timeout: Annotated[
        float | None, typer.Option(help="Seconds to wait for the autopilot's heartbeat (default: 60).")
    ] = None,
    log_level: Annotated[
        str | None, typer.Option(help="debug, info, warning or error (default: info).")
    ] = None,
    config: Annotated[
        Path | None, typer.Option(help="YAML file with the same settings (underscored names).")
    ] = None,
) -> None:
    """Bridge one vehicle: planner commands over MQTT in, guided waypoints over MAVLink out."""
    from ..vehicle.config import load_config

    overrides = {
        "vehicle_id": vehicle_id,
        "mavlink": mavlink,
        "broker": broker,
        "password_file": password_file,
        "key_file": key_file,
        "map": map_path,
        "fleet": fleet,
        "sensor": sensor,
        "baud": baud,
        "arm": arm,
        "guided": guided,
        "failsafe_timeout": failsafe_timeout,
        "arrival_radius": arrival_radius,
        "telemetry_hz": telemetry_hz,
        "track_rate": track_rate,
        "refine": refine,
        "waypoint_command": waypoint_command,
        "hold_on_exit": hold_on_exit,
        "log_level": log_level,
        "connect_timeout": connect_timeout,
        "arm_retry_interval": arm_retry_interval,
    }
    settings = load_config(config, overrides)
    logging.basicConfig(
        level=settings.log_level.upper(),
        format=f"%(asctime)s vehicle {settings.vehicle_id} %(levelname)s %(message)s",
    )
    running = {"bridge": None}

    def on_signal(signum, frame):
        if running["bridge"] is None:
            raise _Stopped()
        running["bridge"].stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    link = None
    try:
        bridge_obj, link = _build(settings)
        running["bridge"] = bridge_obj
        bridge_obj.run()
    except (_Stopped, GuadalError) as exc:
        if link is not None:
            link.close()
        if isinstance(exc, _Stopped):
            raise typer.Exit(0) from None
        raise
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _build(settings):
    """Everything that can fail on bad input, checked before the vehicle is touched."""
    from ..graph import NavGraph
    from ..maps.format import load_map
    from ..vehicle.bridge import Bridge
    from ..vehicle.lowlevel import LowLevelPlanner
    from ..vehicle.mavlink_link import AutopilotLink
    from ..vehicle.sensors import SensorContext, build_sensor, parse_sensor_option

    log = logging.getLogger("guadal.bridge")
    map_ = load_map(settings.map_path())
    graph = NavGraph(map_)
    planner = LowLevelPlanner(map_, settings.refine, graph=graph)
    sensor = None
    if settings.sensor is not None:
        section = (
            parse_sensor_option(settings.sensor) if isinstance(settings.sensor, str) else settings.sensor
        )
        sensor = build_sensor(section, SensorContext(graph=graph, base_dir=settings.sensor_base_dir))
    link = AutopilotLink(settings.mavlink, settings.baud, source_system=settings.source_system)
    log.info("waiting for the autopilot on %s", settings.mavlink)
    try:
        link.wait_vehicle(settings.connect_timeout)
    except BaseException:
        link.close()
        raise
    s = link.snapshot()
    log.info("autopilot system %d in %s, %s", link.target_system, s.mode, "armed" if s.armed else "disarmed")
    return Bridge(settings, planner, link, sensor), link

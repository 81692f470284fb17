"""``guadal stack up|down|status``: the whole sitl stack as background processes."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..console import GuadalGroup, console, print_json, print_table
from ..errors import GuadalError

app = typer.Typer(
    name="stack",
    cls=GuadalGroup,
    help="Start and stop a sitl stack: broker, MAVLink emulator, one bridge per boat.",
    no_args_is_help=True,
)

StateDir = Annotated[
    Path | None,
    typer.Option(help="Folder of the stack's state file and logs (default: ~/.local/state/guadal/stack)."),
]


@app.command("up")
def up(
    map_path: Annotated[Path, typer.Option("--map", help="guadal map file the bridges plan on.")],
    vehicles: Annotated[int, typer.Option(min=1, max=64, help="Number of boats.")] = 3,
    speedup: Annotated[float, typer.Option(min=0.01, help="Emulator time speed-up.")] = 10.0,
    broker_port: Annotated[int, typer.Option(min=0, max=65535, help="Broker port (0: a free one).")] = 0,
    broker: Annotated[
        str, typer.Option(help="auto (Mosquitto if installed), mosquitto or embedded.")
    ] = "auto",
    fleet: Annotated[str, typer.Option(help="Topic prefix of the stack.")] = "guadal",
    failsafe_timeout: Annotated[
        float, typer.Option(min=0.1, help="Bridges' comms-loss failsafe, seconds.")
    ] = 30.0,
    state_dir: StateDir = None,
    autopilot: Annotated[
        str,
        typer.Option(
            help="guadal (the MAVLink emulator) or ardupilot (ArduPilot's SITL, one ardurover per boat)."
        ),
    ] = "guadal",
    binary: Annotated[
        Path | None,
        typer.Option(help="--autopilot ardupilot: ArduPilot's SITL binary (build/sitl/bin/ardurover)."),
    ] = None,
    defaults: Annotated[
        list[Path] | None,
        typer.Option(help="--autopilot ardupilot: ArduPilot parameter file read before guadal's (repeat)."),
    ] = None,
    mavproxy: Annotated[
        bool, typer.Option(help="--autopilot ardupilot: MAVProxy per boat, forwarding to UDP 14550+10i.")
    ] = False,
    speed: Annotated[
        float,
        typer.Option(min=0.01, help="Boats' cruise speed, m/s (ArduPilot's WP_SPEED; the emulator's hull)."),
    ] = 0.5,
    track_rate: Annotated[
        float, typer.Option(min=0.01, max=50, help="GPS fixes per second of the autopilots' clock.")
    ] = 1.0,
    sensor: Annotated[
        str | None, typer.Option(help="Every bridge's sensor: synthetic:CSV, replay:CSV or serial:DEVICE.")
    ] = None,
    emulator_arg: Annotated[
        list[str] | None,
        typer.Option(help="Extra option for the autopilot program (repeat), as backend.emulator_args."),
    ] = None,
    bridge_arg: Annotated[
        list[str] | None, typer.Option(help="Extra option for every bridge (repeat), as backend.bridge_args.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the stack as JSON.")] = False,
) -> None:
    """Start the stack in the background and print the broker URL once every bridge is online."""
    from ..stack import AUTOPILOTS, Autopilot, stack_up

    if not map_path.is_file():
        raise GuadalError(f"--map: map file '{map_path}' does not exist.")
    if autopilot not in AUTOPILOTS:
        raise GuadalError(f"--autopilot must be one of {', '.join(AUTOPILOTS)} (got '{autopilot}').")
    if autopilot == "ardupilot" and binary is None:
        raise GuadalError("--autopilot ardupilot needs --binary, the path of ArduPilot's SITL ardurover.")
    bridge_args = list(bridge_arg or []) + (["--sensor", sensor] if sensor else [])
    emulator_args = list(emulator_arg or [])
    if autopilot == "guadal":
        emulator_args = ["--max-speed", f"{speed:g}", *emulator_args]
    stack = stack_up(
        map_path=map_path,
        vehicles=vehicles,
        speedup=speedup,
        broker_port=broker_port,
        state_dir=state_dir,
        fleet=fleet,
        broker_kind=broker,
        failsafe_timeout=failsafe_timeout,
        autopilot=Autopilot(
            kind=autopilot,
            binary=str(binary) if binary else None,
            defaults=[str(p) for p in defaults or []],
            mavproxy=mavproxy,
            speed=speed,
            track_rate=track_rate,
        ),
        emulator_args=emulator_args,
        bridge_args=bridge_args,
    )
    if as_json:
        print_json({**stack.info, "state_dir": str(stack.state_dir), "pids": stack.pids()})
        return
    console.print(
        f"stack up: {vehicles} boats, {stack.info['broker']['kind']} broker, state in {stack.state_dir}"
    )
    settings = ", ".join(f"{k}: {v}" for k, v in stack.planner_backend().items())
    console.print(f"broker: {stack.broker_url}  (missions: backend: {{{settings}}})")
    typer.echo(stack.broker_url)


@app.command("down")
def down(
    state_dir: StateDir = None,
    grace: Annotated[float, typer.Option(min=0.0, help="Seconds between SIGTERM and SIGKILL.")] = 5.0,
) -> None:
    """Stop every process of the stack (SIGTERM, then SIGKILL after the grace period)."""
    from ..stack import stack_down

    stack = stack_down(state_dir, grace)
    if stack is None:
        console.print("no stack is recorded there; nothing to stop.")
    else:
        console.print(f"stack down: stopped {len(stack.processes)} processes.")


@app.command("status")
def status(
    state_dir: StateDir = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """The recorded stack's processes and whether each is alive."""
    from ..stack import Stack, default_state_dir

    stack = Stack.load(state_dir or default_state_dir())
    if stack is None:
        raise GuadalError("no stack is recorded there; start one with 'guadal stack up'.")
    rows = [(p.name, p.pid, "alive" if p.alive() else "stopped", p.log) for p in stack.processes]
    print_table(f"stack at {stack.broker_url}", ["process", "pid", "state", "log"], rows, as_json=as_json)

"""Rover mode numbers and the mode families ArduPilot treats alike (MAVLINK.md, "Identity")."""

MANUAL, ACRO, STEERING, HOLD, LOITER, FOLLOW, SIMPLE, DOCK, CIRCLE = 0, 1, 3, 4, 5, 6, 7, 8, 9
AUTO, RTL, SMART_RTL, GUIDED, INITIALISING = 10, 11, 12, 15, 16

MODE_NAMES = {
    MANUAL: "MANUAL",
    ACRO: "ACRO",
    STEERING: "STEERING",
    HOLD: "HOLD",
    LOITER: "LOITER",
    FOLLOW: "FOLLOW",
    SIMPLE: "SIMPLE",
    DOCK: "DOCK",
    CIRCLE: "CIRCLE",
    AUTO: "AUTO",
    RTL: "RTL",
    SMART_RTL: "SMART_RTL",
    GUIDED: "GUIDED",
    INITIALISING: "INITIALISING",
}
#: modes the emulator can enter; AUTO is refused (no mission upload), like a vehicle without one
ENTERABLE_MODES = {MANUAL, ACRO, STEERING, HOLD, LOITER, GUIDED, RTL, SMART_RTL}
#: heartbeat carries GUIDED_ENABLED in these
AUTOPILOT_MODES = {LOITER, AUTO, RTL, SMART_RTL, GUIDED}
#: heartbeat carries MANUAL_INPUT_ENABLED in these
MANUAL_INPUT_MODES = {MANUAL, ACRO, STEERING}
#: arming here fails unless forced
UNARMABLE_MODES = {RTL, SMART_RTL}

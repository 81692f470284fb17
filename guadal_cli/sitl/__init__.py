"""MAVLink boat emulator: N boats that answer like ArduPilot Rover/Boat SITL for the subset the
vehicle bridge relies on (``MAVLINK.md``), with a speed-up factor and no ArduPilot install.

``server.SitlServer`` runs the fleet; ``vehicle.EmulatedBoat`` is one autopilot; ``physics`` the
hull; ``telemetry`` what it reports; ``link`` the TCP/UDP/serial endpoints.  Nothing is imported
here, so ``guadal sitl`` can refuse bad options before loading pymavlink.
"""

"""Fleets: the local (sim) one here, the remote (MQTT) one for sitl and real levels."""

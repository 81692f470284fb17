"""The vehicle side of the remote levels: the MQTT <-> MAVLink bridge, its path planning and sensors."""

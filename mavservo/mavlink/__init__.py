"""MAVLink side of the bridge: link, commands in, telemetry out, gimbal device."""

"""MAVLink units <-> servo angles: the channel mapping (reverse, trim, limits, slew) and the
servo backend that turns the MAVLink side's commands into scheduler setpoints and the scheduler's
servo state back into what the MAVLink side publishes."""

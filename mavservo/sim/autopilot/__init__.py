"""The simulated autopilot (``mavservo sitl``): a MAVLink stream simulator with scripted mission
commands and a gimbal manager, a ``.tlog`` replayer, and the parameter files and launcher for a
real ArduPilot SITL (package data next to this module)."""

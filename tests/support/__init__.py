"""Helpers shared by the tests: real bridges, MAVLink doubles, waits, paths (never collected)."""

"""Tests of mavservo/sim/autopilot."""

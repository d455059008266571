"""Tests of mavservo/servos/dronecan."""

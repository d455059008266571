"""Tests of mavservo/servos/odrive."""

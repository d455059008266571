"""Tests of mavservo/servos/rmdx."""

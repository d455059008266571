"""Tests of mavservo/servos/damiao."""

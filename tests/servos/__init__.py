"""Tests of mavservo/servos."""

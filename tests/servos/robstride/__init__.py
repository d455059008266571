"""Tests of mavservo/servos/robstride."""

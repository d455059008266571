"""Tests of mavservo/servos/lk."""

"""Tests of mavservo/sim."""

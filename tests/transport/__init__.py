"""Tests of mavservo/transport."""

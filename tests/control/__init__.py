"""Tests of mavservo/control."""

"""Tests of mavservo/mavlink."""

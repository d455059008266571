"""Tests of mavservo/records."""

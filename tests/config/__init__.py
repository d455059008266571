"""Tests of mavservo/config."""

"""Tests of mavservo/scheduling."""

"""Tests of mavservo/app."""

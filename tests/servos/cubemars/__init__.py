"""Tests of mavservo/servos/cubemars."""

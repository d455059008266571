"""Attacks and hostile input: each finding of a red team, replayed against the fix."""

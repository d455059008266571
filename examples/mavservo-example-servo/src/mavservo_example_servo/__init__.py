"""A worked mavservo servo-profile plug-in (see README.md)."""

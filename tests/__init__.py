"""The test suite: folders mirror the packages of mavservo (docs/engineering/architecture.md)."""

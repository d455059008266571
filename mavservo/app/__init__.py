"""The application layer: the bridge's wiring and life cycle, ``mavservo run``, the console, the
live monitor, ``mavservo check`` and run reports. The only layer that knows every other one."""

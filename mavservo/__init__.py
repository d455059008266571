"""mavservo: a MAVLink <-> CAN servo bridge for drone companion computers.

Layers (one direction of flow each): MAVLink link -> mapping -> scheduler -> servo profile ->
python-can bus (the project's own ``aa55`` interface or any other) -> AA-55 codec.
"""

__version__ = "0.1.0"

"""DroneCAN actuators: the profile (``profile.py``), the bridge's bus node (``node.py``), dynamic
node-id allocation (``alloc.py``), the DSDL wire helpers (``wire.py``) and the simulated node
(``sim.py``).

Kept empty on purpose: the built-in table in :mod:`mavservo.servos.registry` imports the
profile on first use and the simulated device only when a simulation asks for it.
"""

"""Damiao DM-J (MIT mode): the profile (``profile.py``) and its simulated device (``sim.py``).

Kept empty on purpose: the built-in table in :mod:`mavservo.servos.registry` imports the
profile on first use and the simulated device only when a simulation asks for it.
"""

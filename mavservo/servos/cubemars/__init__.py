"""CubeMars AK, one vendor and two modes: servo mode (``profile.py``, ``sim.py``) and MIT mode
(``mit_mode.py``, ``mit_mode_sim.py``), which reads the error-code table of servo mode.

Kept empty on purpose: the built-in table in :mod:`mavservo.servos.registry` imports the
profile on first use and the simulated device only when a simulation asks for it.
"""

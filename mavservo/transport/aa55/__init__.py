"""The AA-55 USB-CAN adapter: :mod:`.codec` (bytes <-> frames, sans-I/O, imports nothing of the
project) and :mod:`.bus` (the python-can ``aa55`` interface over pyserial)."""

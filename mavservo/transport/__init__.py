"""Frames on the wire: the AA-55 USB-CAN adapter (:mod:`mavservo.transport.aa55`) and the bus
wrapper that survives an unplugged adapter."""

"""Who gets the bus when: the pure policy core, the runner thread that owns the only writer to
the bus, the bus-load arithmetic (paper eq. 4), reply matching and the servo outage log."""

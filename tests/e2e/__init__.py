"""End-to-end tests: the whole bridge, real sockets and ptys on loopback, simulated servos."""

"""``python -m mavservo.sim.autopilot``: see :mod:`mavservo.sim.autopilot.sitl_command`."""

import sys

from mavservo.sim.autopilot.sitl_command import main

sys.exit(main())

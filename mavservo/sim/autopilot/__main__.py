"""``python -m mavservo.sim.autopilot``: see :mod:`mavservo.sim.autopilot.cli`."""

import sys

from mavservo.sim.autopilot.cli import main

sys.exit(main())

"""``python -m mavservo`` is the ``mavservo`` command."""

import sys

from mavservo.cli import main

sys.exit(main())

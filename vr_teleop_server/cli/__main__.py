"""`python -m vr_teleop_server.cli`."""

import sys

from . import main

sys.exit(main())

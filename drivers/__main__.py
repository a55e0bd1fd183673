"""``python -m drivers``: the emulated drives on a CAN bus (see :mod:`drivers.cli`)."""

import sys

from drivers.cli import main

sys.exit(main())

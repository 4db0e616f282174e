"""``python -m fd_monitor``: see :mod:`fd_monitor.cli`."""

import sys

from fd_monitor.cli import main

sys.exit(main())

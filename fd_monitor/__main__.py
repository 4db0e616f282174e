"""``python -m fd_monitor``: see :mod:`fd_monitor.commands.cli`."""

import sys

from fd_monitor.commands.cli import main

sys.exit(main())

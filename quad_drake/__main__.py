"""``python -m quad_drake``: the same command line as ``quad-drake``."""

import sys

from .cli import main

sys.exit(main())

"""``python -m qcontrol.cli``: the ``qcontrol`` command (the same entry point as the console script)."""

import sys

from .._entry import main

sys.exit(main())

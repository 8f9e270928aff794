"""``python -m qcontrol.cli``: the ``qcontrol`` command."""

import sys

from .dispatch import main

sys.exit(main())

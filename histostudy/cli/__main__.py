"""``python -m histostudy.cli``: the ``histostudy`` command."""

import sys

from . import main

sys.exit(main())

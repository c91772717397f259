"""``python -m histostudy.robot.controller``: the simulated UR controller's command line."""

import sys

from ._process import main

sys.exit(main())

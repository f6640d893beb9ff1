"""``python -m swarm.mission.study``: the same as ``swarm study``."""

import sys

from swarm.mission.study.command import main

sys.exit(main())

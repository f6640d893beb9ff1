"""``python -m swarm.cli``: the same as ``swarm``."""

import sys

from swarm.child_command import leave_interrupts_to_the_runner

leave_interrupts_to_the_runner()  # first: a role a runner started leaves Ctrl-C to the runner

from swarm.cli.main import main  # noqa: E402

sys.exit(main())

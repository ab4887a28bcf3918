"""`python -m swarm.cli ...`: the `swarm` command (what `swarm up` runs for each child)."""

import sys

from swarm.cli.main import main

sys.exit(main())

"""swarm: decentralized formation control of differential-drive robots over Eclipse Zenoh (README.md).

`swarm.simulate(...)` runs a scenario in this process, for scripts and notebooks (swarm.api); everything else
is the `swarm` command (swarm.cli)."""

from typing import Any


def simulate(*args: Any, **kwargs: Any) -> Any:
    """swarm.api.simulate: loaded on first use (a robot process importing swarm never loads numpy)."""
    from swarm.api import simulate as run

    return run(*args, **kwargs)


simulate.__doc__ = "Run a scenario in this process: see swarm.api.simulate (docs/control.md, \"From Python\")."

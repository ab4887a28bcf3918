"""The compiled law (swarm/core/_law.c, built by setup.py where a C compiler is found): see swarm.core.fastlaw."""

from types import ModuleType

from swarm.core.law import robot_command as robot_command

def configure(law: ModuleType, /) -> None: ...

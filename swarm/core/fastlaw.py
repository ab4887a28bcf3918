"""The law as a robot process runs it: swarm.core.law.robot_command, compiled (swarm/core/_law.c, built by
setup.py where a C compiler is found) or, without it or with SWARM_PURE_PYTHON set, the Python itself.

The compiled copy is a transcription held to the same bits as law.py on every branch
(tests/unit/test_law_compiled.py); law.py stays the one statement of the law and what the simulator
compiles with numba. A robot logs which one it runs."""

from __future__ import annotations

import os
from types import ModuleType

from swarm.core import law

_law: ModuleType | None
try:
    from swarm.core import _law
except ImportError:  # not built here: the Python law
    _law = None

if os.environ.get("SWARM_PURE_PYTHON"):
    _law = None

if _law is not None:
    _law.configure(law)
    robot_command = _law.robot_command
else:
    robot_command = law.robot_command

COMPILED = _law is not None

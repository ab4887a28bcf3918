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

# The constants and layouts the compiled law takes from law.py (one place holds them), handed to it by name: it
# looks up no attribute of its own.
CONSTANTS = ("PI", "TWO_PI", "LN2", "COLLISION_EPS", "GOVERNOR_FRACTION", "MAX_SPEED", "MAX_TURN", "THRESHOLD_OFF",
             "THRESHOLD_FROZEN", "KIND_ROBOT", "P_K1", "P_K2", "P_K3", "P_TU", "P_VT", "P_THRESHOLD", "P_GOVERNOR",
             "P_DT", "P_SENSE", "P_REACH", "P_OBSTACLE_R", "P_V_MAX", "P_W_MAX", "P_SIZE", "M_FROZEN", "M_SNAP_X",
             "M_SNAP_Y", "M_SNAP_TH", "M_T_SNAP", "M_EX", "M_EY", "M_ETH", "M_SCALE", "M_SIZE")

if _law is not None:
    _law.configure({name: getattr(law, name) for name in CONSTANTS})
    robot_command = _law.robot_command
else:
    robot_command = law.robot_command

COMPILED = _law is not None

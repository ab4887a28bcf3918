"""A user's control law in the runtime's place (docs/control.md): `plugin_command` has the very signature of
swarm.core.law.robot_command, so the simulator's kernels and a robot's agent call it where they call the paper's.

Scalar style, like swarm.core.law: this source runs as plain Python, and swarm.core.userlaw executes it a second
time per law with numba's `njit` as `_jit` (the law's compiled twin). What it is run with comes in as module
globals set before its source runs: `__swarm_law__` (swarm.core.law, or its compiled twin) and
`__swarm_law_call__`, the user's law behind one fixed signature, call(me, ref, bodies, params, t, mem, kinds).

What the user's law sees (the contract of docs/control.md):
- me = [x, y, theta], the robot's pose; ref = [x, y, theta, v, w], its slot on the leader's path (the leader's
  pose plus the robot's offset, with the slot's speeds: the offsets are fixed in the world frame);
- bodies, rows [x, y, r, R], and kinds (BODY_ROBOT, BODY_OBSTACLE, BODY_DEAD): the live robots closer than reach,
  then the obstacles and then the dead or stopped robots closer than the cell side, in the order the paper's law
  sums them (robots by id, obstacles by index), which every run (simulated or distributed) shares;
- params = p[P_SIZE:], the scenario's [control] params; mem = mem[M_SIZE:], its robot's own memory.
Its (v, w) then goes through what the paper's goes through: the threshold (only with threshold = "always": a
user's law never freezes), the speed bound and the governor (swarm.core.law.bound_command), and, with the
governor on, one rule more: a body it touches allows only motion away from it (_contact).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from swarm.core.jit import Jit

_jit: Jit = globals().get("__swarm_jit__", lambda f: f)
_law: Any = globals().get("__swarm_law__")
_call: Any = globals().get("__swarm_law_call__")
if _law is None:  # imported as itself (docs, type checks): the plain law, no user law bound
    from swarm.core import law as _law

_bound = _law.bound_command
_threshold = _law.apply_threshold
_wrap = _law.wrap_angle
KIND_ROBOT = _law.KIND_ROBOT
KIND_OBSTACLE = _law.KIND_OBSTACLE
P_REACH = _law.P_REACH
P_VT = _law.P_VT
P_THRESHOLD = _law.P_THRESHOLD
P_GOVERNOR = _law.P_GOVERNOR
P_SIZE = _law.P_SIZE
M_FROZEN = _law.M_FROZEN
M_SNAP_X = _law.M_SNAP_X
M_T_SNAP = _law.M_T_SNAP
M_EX = _law.M_EX
M_EY = _law.M_EY
M_ETH = _law.M_ETH
M_SCALE = _law.M_SCALE
M_SIZE = _law.M_SIZE

# The kinds a user's law is told (the `kinds` argument): the contract's order.
BODY_ROBOT = 0
BODY_OBSTACLE = 1
BODY_DEAD = 2


# A body whose clearance is below this [m] is touched: the governor lets no law move toward it (_contact).
CONTACT_M = 1e-6


@_jit
def _contact(v: float, x: float, y: float, th: float, r_self: float, nx: Any, ny: Any, nr: Any, nk: Any,
             n: int) -> float:
    """v, or 0.0 when the robot touches a body (clearance below CONTACT_M) and v moves it toward that body.

    The governor lets a step close half a clearance (law.governor_speed_limit), and sets no limit inside a body,
    where the paper's repulsion pushes out. A law that keeps pushing toward a body (nothing in the contract says
    it may not) would halve its clearance step after step down to rounding, then drive in: for a user's law, a
    touched body allows only motion away from it (turning in place is always allowed)."""
    sv = 1.0 if v > 0.0 else -1.0
    hx = sv * math.cos(th)
    hy = sv * math.sin(th)
    for k in range(n):
        dx = x - nx[k]
        dy = y - ny[k]
        l = math.sqrt(dx * dx + dy * dy)
        contact = max(r_self, nr[k]) if nk[k] == KIND_ROBOT else nr[k]
        if l - contact < CONTACT_M and -dx * hx - dy * hy > 0.0:
            return 0.0
    return v


@_jit
def plugin_command(x: float, y: float, th: float, ox: float, oy: float, r_self: float, t: float, xl: float,
                   yl: float, thl: float, vl: float, wl: float, nx: Any, ny: Any, nr: Any, nR: Any, nk: Any, na: Any,
                   n: int, mem: Any, p: Any) -> tuple[float, float]:
    """One control step of one robot under the user's law: robot_command's arguments and result (swarm.core.law).

    mem[M_SNAP_X] is 1.0 while the user's law runs and mem[M_T_SNAP] its step's time: after an exception they
    say which robot and step raised it. mem[M_EX], [M_EY], [M_ETH] keep the slot's error in the robot's frame (the
    status it reports), mem[M_SCALE] the governor's scale, mem[M_FROZEN] stays 0.
    """
    reach = p[P_REACH]
    count = 0
    for k in range(n):
        if nk[k] == KIND_ROBOT:
            dx = x - nx[k]
            dy = y - ny[k]
            if math.sqrt(dx * dx + dy * dy) < reach:
                count += 1
        else:
            count += 1
    bodies = np.empty((count, 4))
    kinds = np.empty(count, np.int64)
    c = 0
    for k in range(n):
        if nk[k] == KIND_ROBOT:
            dx = x - nx[k]
            dy = y - ny[k]
            if not math.sqrt(dx * dx + dy * dy) < reach:
                continue
            kinds[c] = BODY_ROBOT
        elif nk[k] == KIND_OBSTACLE:
            kinds[c] = BODY_OBSTACLE
        else:
            kinds[c] = BODY_DEAD
        bodies[c, 0] = nx[k]
        bodies[c, 1] = ny[k]
        bodies[c, 2] = nr[k]
        bodies[c, 3] = nR[k]
        c += 1
    me = np.empty(3)
    me[0] = x
    me[1] = y
    me[2] = th
    ref = np.empty(5)
    ref[0] = xl + ox
    ref[1] = yl + oy
    ref[2] = thl
    ref[3] = vl
    ref[4] = wl
    mem[M_SNAP_X] = 1.0
    mem[M_T_SNAP] = t
    v, w = _call(me, ref, bodies, p[P_SIZE:], t, mem[M_SIZE:], kinds)
    v = float(v)
    w = float(w)
    mem[M_SNAP_X] = 0.0
    mem[M_FROZEN] = 0.0
    if not (math.isfinite(v) and math.isfinite(w)):
        return v, w  # unfiltered (no filter may turn it into a number): every run ends there, naming the law
    v = _threshold(v, p[P_VT], int(p[P_THRESHOLD]), False)
    v, w, scale = _bound(v, w, x, y, th, r_self, nx, ny, nr, nk, na, n, p)
    if p[P_GOVERNOR] != 0.0 and v != 0.0:
        v = _contact(v, x, y, th, r_self, nx, ny, nr, nk, n)
    px = ref[0] - x
    py = ref[1] - y
    c0 = math.cos(th)
    s0 = math.sin(th)
    mem[M_EX] = c0 * px + s0 * py
    mem[M_EY] = -s0 * px + c0 * py
    mem[M_ETH] = _wrap(thl - th)
    mem[M_SCALE] = scale
    return v, w

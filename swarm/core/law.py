"""The formation control law (docs/design.md), for one robot at a time.

Scalar style on purpose: this exact source runs as plain Python in a robot process (no
compiler loaded, a few tens of microseconds a tick) and, compiled by numba through
`swarm.core.jit.compiled("swarm.core.law")`, inside the batched simulator. Keep to what numba
compiles: `math`, floats, ints, 1-D numpy arrays indexed by ints, tuples. No imports
of other swarm modules (the compiled copy would call their uncompiled versions).

Units: metres, radians, seconds. Neighbour arrays are in summation order: robots by
ascending id, then obstacles by ascending index (the same order everywhere, so a
distributed run adds the same floats in the same order as the simulator).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import MutableSequence, Sequence

    import numpy as np
    import numpy.typing as npt

    from swarm.core.jit import Jit

    _Floats = Sequence[float] | npt.NDArray[np.float64]
    _Kinds = Sequence[int] | npt.NDArray[np.int64]
    _Memory = MutableSequence[float] | npt.NDArray[np.float64]

_jit: Jit = globals().get("__swarm_jit__", lambda f: f)

PI = math.pi
TWO_PI = 2.0 * math.pi
LN2 = math.log(2.0)

# A centre distance below r is evaluated at r + COLLISION_EPS: inside a body the
# repulsion stays at its (huge) value next to the border instead of vanishing (the
# paper's B = 0 for l < r would switch avoidance off exactly when it is needed most).
COLLISION_EPS = 1e-4  # m

# Threshold rule of Assumption 3 (control.threshold).
THRESHOLD_OFF = 0
THRESHOLD_FROZEN = 1
THRESHOLD_ALWAYS = 2

# Safety governor: over one step a robot closes at most GOVERNOR_FRACTION of its
# clearance to a static body, and half of that to another robot (which may close too).
GOVERNOR_FRACTION = 0.5
BRAKE_S = 0.25  # s: a world without a robot's new command holds its last one a period, then brakes over this long

# Layout of the float64 parameter vector `p` (build it with swarm.core.scenario.Control.vector).
P_K1 = 0
P_K2 = 1
P_K3 = 2
P_TU = 3
P_VT = 4
P_THRESHOLD = 5  # one of THRESHOLD_*
P_GOVERNOR = 6  # 1.0 on, 0.0 off
P_DT = 7  # s, the control period
P_SENSE = 8  # m, bodies closer than this are known (the cell side): callers pass them to the law
P_REACH = 9  # m, bodies closer than this act on the command (the largest R); farther known ones are ignored
P_OBSTACLE_R = 10  # m, the largest r of any obstacle (0 without obstacles): bounds a step toward unseen ones
P_V_MAX = 11  # m/s, the speed bound control.v_max (0: none but the physical bound MAX_SPEED)
P_W_MAX = 12  # rad/s, control.w_max (0: none but MAX_TURN)
P_SIZE = 13

# The physical bounds every command respects (the protocol refuses anything beyond them): with no
# speed bound set, (v, w) is still scaled down to these. They bind only inside a collision, where
# the clamped repulsion is huge; the paper's runs never reach them.
MAX_SPEED = 100.0  # m/s
MAX_TURN = 100.0  # rad/s

# Layout of the per-robot memory vector `mem` (freeze state), updated in place.
M_FROZEN = 0  # 1.0 while frozen
M_SNAP_X = 1  # reference snapshot held while frozen
M_SNAP_Y = 2
M_SNAP_TH = 3
M_T_SNAP = 4  # s, when the snapshot was taken
M_EX = 5  # diagnostics of the last command: E_x, E_y [m], e_theta [rad]
M_EY = 6
M_ETH = 7
M_SCALE = 8  # governor scale applied to (v, w), 1.0 when it did not act
M_SIZE = 9

# Neighbour kinds in the `nk` array. A dead (or stopped) robot is a static body: the paper's law takes it as an
# obstacle (every test of a kind here is `== KIND_ROBOT`); a user's law (swarm.core.lawplug) is told which it is.
KIND_OBSTACLE = 0
KIND_ROBOT = 1
KIND_DEAD = 2


@_jit
def wrap_angle(a: float) -> float:
    """Wrap an angle [rad] into (-pi, pi]."""
    if -PI < a <= PI:
        return a  # exact: no rounding for angles already in range
    if -2.0 * TWO_PI < a < 2.0 * TWO_PI:
        # Python's a % TWO_PI without fmod (a call): fmod(a, TWO_PI) is a, or a -+ TWO_PI for |a| >= TWO_PI,
        # which is exact there (Sterbenz: TWO_PI <= |a| <= 2 TWO_PI); then float %'s own step to [0, TWO_PI)
        # as in CPython's float_rem: the same bits as the line below (a zero here is +0.0, as %'s)
        w = a - TWO_PI if a >= TWO_PI else (a + TWO_PI if a <= -TWO_PI else a)
        if w < 0.0:
            w += TWO_PI
    else:
        w = a % TWO_PI  # Python's float modulo is exact: [0, 2 pi) for every finite a
    if w > PI:
        w -= TWO_PI
    return w


@_jit
def exp_pair(u: float) -> tuple[float, float]:
    """(B, 1 - B) with B = e^u, for u <= 0 (the potential's u), with one libm call and each within an ulp of
    the exact value. Below -ln 2, B < 1/2 and 1 - B is exact enough from B (it is above 1/2: no cancellation);
    above, expm1 gives 1 - B without the cancellation that 1 - exp(u) would have near u = 0 (a body at the
    robot's own border), and B = 1 + expm1(u) is above 1/2. exp and expm1 both, as the paper's formula reads,
    cost the crowded simulator a third of its time (docs/design.md, "One libm call a body")."""
    if u < -LN2:
        b = math.exp(u)
        return b, 1.0 - b
    e = math.expm1(u)
    return 1.0 + e, -e


@_jit
def potential(l: float, r: float, R: float) -> float:
    """V(l) = B/(1-B) of a body with radii r < R at centre distance l [m] (>= 0, 0 beyond R)."""
    if l >= R:
        return 0.0
    if l < r + COLLISION_EPS:
        l = r + COLLISION_EPS
    b, one_minus_b = exp_pair((l - r) / (l - R))
    return b / one_minus_b


@_jit
def potential_slope(l: float, r: float, R: float) -> float:
    """dV/dl [1/m] (<= 0): B (r - R) / ((l - R)^2 (1 - B)^2), clamped at r + eps."""
    if l >= R:
        return 0.0
    if l < r + COLLISION_EPS:
        l = r + COLLISION_EPS
    d = l - R
    b, one_minus_b = exp_pair((l - r) / d)
    if b == 0.0:  # far side of the region: also avoids 0/0 when (l - R)^2 underflows
        return 0.0
    return b * (r - R) / (d * d * one_minus_b * one_minus_b)


@_jit
def repulsion_gradient(xi: float, yi: float, xj: float, yj: float, r: float, R: float) -> tuple[float, float]:
    """(dV/dx_i, dV/dy_i) of body j (radii r, R) at robot i's position.

    Coincident centres have no direction; the gradient then points along -x, so the
    correction pushes robot i along +x (a degenerate case; counted as a collision).
    """
    dx = xi - xj
    dy = yi - yj
    l = math.sqrt(dx * dx + dy * dy)
    if l >= R:
        return 0.0, 0.0
    s = potential_slope(l, r, R)
    if l < 1e-12:
        return s, 0.0  # s < 0: the gradient points along -x, the correction P = p - grad along +x
    return s * dx / l, s * dy / l


@_jit
def sgn_gain(vl: float) -> float:
    """The factor of k2 E_y: sgn(v_l), but +1 when v_l = 0 (the paper keeps k2 E_y there)."""
    if vl > 0.0:
        return 1.0
    if vl < 0.0:
        return -1.0
    return 1.0


@_jit
def tracking_command(x: float, y: float, th: float, xd: float, yd: float, thd: float, vl: float, wl: float,
                     gx: float, gy: float, k1: float, k2: float, k3: float) -> tuple[float, float, float, float, float]:
    """Eq. (16) with the corrections of Eq. (8).

    (x, y, th): robot pose; (xd, yd, thd): its desired pose (leader + offset);
    (vl, wl): the leader's velocities used in the law (0, 0 while frozen);
    (gx, gy): the summed repulsion gradient. Returns v [m/s], w [rad/s], E_x, E_y, e_theta.
    """
    px = xd - x
    py = yd - y
    eth = wrap_angle(thd - th)
    cx = px - gx
    cy = py - gy
    c = math.cos(th)
    s = math.sin(th)
    ex = c * cx + s * cy
    ey = -s * cx + c * cy
    kx = k1 * ex
    if vl == 0.0 and kx != 0.0 and eth == eth:
        # frozen (the law then takes v_l = 0): v_l cos(e_theta) is a signed zero, and kx plus a zero is kx, bit
        # for bit (round to nearest); so no cos, the cost of most robot-steps in a crowd (NaN e_theta: below)
        v = kx
    else:
        v = vl * math.cos(eth) + kx
    w = wl + k2 * sgn_gain(vl) * ey + k3 * eth
    return v, w, ex, ey, eth


@_jit
def apply_threshold(v: float, vt: float, mode: int, frozen: bool) -> float:
    """Assumption 3: |v| < vt becomes S(v) vt (S(0) = +1) when the mode says it applies."""
    if mode == THRESHOLD_OFF or (mode == THRESHOLD_FROZEN and not frozen):
        return v
    if abs(v) < vt:
        return vt if v >= 0.0 else -vt
    return v


@_jit
def freeze_update(mem: _Memory, inside: bool, t: float, xl: float, yl: float, thl: float, tu: float) -> bool:
    """Assumption 2, the freeze state machine of one robot; updates `mem` in place.

    inside: the robot is within R_j of some other robot j at time t [s].
    Entering takes a snapshot of the live reference (xl, yl, thl); while inside it is
    refreshed every tu seconds; leaving releases at once. Returns True while frozen.
    """
    if not inside:
        mem[M_FROZEN] = 0.0
        return False
    if mem[M_FROZEN] == 0.0 or t - mem[M_T_SNAP] >= tu * (1.0 - 1e-9):
        mem[M_SNAP_X] = xl
        mem[M_SNAP_Y] = yl
        mem[M_SNAP_TH] = thl
        mem[M_T_SNAP] = t
    mem[M_FROZEN] = 1.0
    return True


@_jit
def speed_bound_scale(v: float, w: float, v_max: float, w_max: float) -> float:
    """The factor in (0, 1] that brings |v| under v_max and |w| under w_max together (0 bound: the
    physical one), keeping the curvature w / v; 1.0 when (v, w) is within both."""
    vb = v_max if v_max > 0.0 else MAX_SPEED
    wb = w_max if w_max > 0.0 else MAX_TURN
    s = 1.0
    if abs(v) > vb:
        s = vb / abs(v)
    if abs(w) * s > wb:
        s = wb / abs(w)
    return s


@_jit
def clip(x: float, b: float) -> float:
    """x held within [-b, b] by comparisons, not min/max: a NaN stays NaN (min(b, nan) is b and would hide
    it: a law that overflows must be refused, never driven at the bound)."""
    if x > b:
        return b
    if x < -b:
        return -b
    return x


@_jit
def governor_speed_limit(x: float, y: float, r_self: float, nx: _Floats, ny: _Floats, nr: _Floats, nk: _Kinds,
                         na: _Floats, n: int, dt: float, reach: float, sense: float, obstacle_r: float, v_max: float,
                         hx: float, hy: float) -> tuple[float, float]:
    """Largest |v| [m/s] with which one step of length dt keeps every body safe, and whether the
    robot must not move toward some body at all (1.0) or may (0.0).

    Over a step the robot moves at most |v| dt (an arc is no shorter than its chord).
    A static body may take GOVERNOR_FRACTION of the clearance l - r per step, another
    robot half of that (it may close by as much). Clearance then shrinks at most
    geometrically and never reaches zero. Robots at `reach` or farther are left out (a
    distributed robot is sure to know only those closer: docs/runtime.md), obstacles at
    `sense` or farther (every robot knows every obstacle); to keep those safe too, |v| dt
    is also held below the same share of (reach - r_self), and below GOVERNOR_FRACTION of
    (sense - obstacle_r), the least clearance an obstacle beyond `sense` can have.
    A body already inside (clearance <= 0) sets no limit: the clamped repulsion
    pushes the robot out and stopping it there would trap it.

    Under faults (docs/faults.md) a known body may be stale: na[k] [s] is the age of what this
    robot knows of it (0: current). It may have moved since, by at most na[k] times the speed
    bound (v_max; 0: the per-step bound below, over dt): that distance is taken off its clearance
    (never added to r or R, which the law uses unchanged), and a body it can reach counts even
    beyond `reach`. A stale body with no clearance left allows only motion away: the second
    result is 1.0 when the motion (hx, hy) (the unit direction of travel) points toward it.
    """
    per_step = min(0.5 * GOVERNOR_FRACTION * (reach - r_self), GOVERNOR_FRACTION * (sense - obstacle_r))
    limit = per_step / dt
    vb = v_max if v_max > 0.0 else per_step / dt
    blocked = 0.0
    for k in range(n):
        dx = x - nx[k]
        dy = y - ny[k]
        l = math.sqrt(dx * dx + dy * dy)
        drift = na[k] * vb  # how far a stale body may have come since
        if l - drift >= (reach if nk[k] == KIND_ROBOT else sense):
            continue
        if nk[k] == KIND_ROBOT:
            c = l - max(r_self, nr[k])
            share = 0.5 * GOVERNOR_FRACTION
        else:
            c = l - nr[k]
            share = GOVERNOR_FRACTION
        if c > 0.0:
            c -= drift
            if c > 0.0:
                cap = share * c / dt
                if cap < limit:
                    limit = cap
            elif -dx * hx - dy * hy > 0.0:  # stale, no clearance left, and the robot heads toward it
                blocked = 1.0
    return limit, blocked


@_jit
def bound_command(v: float, w: float, x: float, y: float, th: float, r_self: float, nx: _Floats, ny: _Floats,
                  nr: _Floats, nk: _Kinds, na: _Floats, n: int, p: _Floats) -> tuple[float, float, float]:
    """The filters every law's output goes through, after its threshold: the speed bound (control.v_max and
    w_max, or the physical bounds), then, when p[P_GOVERNOR] is on, the safety governor over the known bodies
    (governor_speed_limit). Returns (v, w, the governor's scale: 1.0 when it did not act)."""
    bound = speed_bound_scale(v, w, p[P_V_MAX], p[P_W_MAX])
    if bound < 1.0:  # the speed bound: after the threshold, before the governor
        v *= bound
        w *= bound
        # b / |x| * x can land one rounding above b: clip, or a receiver checking the bound refuses it;
        vb = p[P_V_MAX] if p[P_V_MAX] > 0.0 else MAX_SPEED
        wb = p[P_W_MAX] if p[P_W_MAX] > 0.0 else MAX_TURN
        v = clip(v, vb)
        w = clip(w, wb)
    scale = 1.0
    if p[P_GOVERNOR] != 0.0:
        sv = 1.0 if v >= 0.0 else -1.0
        limit, blocked = governor_speed_limit(x, y, r_self, nx, ny, nr, nk, na, n, p[P_DT], p[P_REACH],
                                              p[P_SENSE], p[P_OBSTACLE_R], p[P_V_MAX], sv * math.cos(th),
                                              sv * math.sin(th))
        if abs(v) > limit:
            scale = limit / abs(v)
            v *= scale
            w *= scale
        if blocked != 0.0:
            v = 0.0  # only motion away from a stale body with no clearance left: turn in place
    return v, w, scale


@_jit
def robot_command(x: float, y: float, th: float, ox: float, oy: float, r_self: float, t: float, xl: float, yl: float,
                  thl: float, vl: float, wl: float, nx: _Floats, ny: _Floats, nr: _Floats, nR: _Floats, nk: _Kinds,
                  na: _Floats, n: int, mem: _Memory, p: _Floats) -> tuple[float, float]:
    """One control step of one robot: freeze rule, law, threshold, speed bound, governor.

    x, y, th: the robot's pose; (ox, oy): its formation offset d_i; r_self: its radius;
    t: the step time [s]; (xl, yl, thl, vl, wl): the live leader reference;
    nx, ny, nr, nR, nk: the first n entries are the known bodies (closer than p[P_SENSE])
    in summation order, with radii and kind (KIND_ROBOT / KIND_OBSTACLE); the robots among
    them act on the command only when closer than p[P_REACH] (the largest R): the repulsion
    of a body is zero beyond its R anyway, and the governor leaves such robots out too, so a
    distributed robot needs exactly the robots its lock-step wait rule guarantees
    (docs/runtime.md); obstacles, known to every robot, count up to p[P_SENSE];
    na: the age [s] of what is known of each body (0 without faults: see governor_speed_limit);
    mem: this robot's memory (M_* layout), updated; p: parameters (P_* layout).
    Returns (v [m/s], w [rad/s]).
    """
    gx = 0.0
    gy = 0.0
    inside = False
    for k in range(n):
        dx = x - nx[k]
        dy = y - ny[k]
        if nk[k] == KIND_ROBOT and dx * dx + dy * dy < nR[k] * nR[k]:
            inside = True
        ax, ay = repulsion_gradient(x, y, nx[k], ny[k], nr[k], nR[k])
        gx += ax
        gy += ay
    frozen = freeze_update(mem, inside, t, xl, yl, thl, p[P_TU])
    if frozen:
        v, w, ex, ey, eth = tracking_command(
            x, y, th, mem[M_SNAP_X] + ox, mem[M_SNAP_Y] + oy, mem[M_SNAP_TH], 0.0, 0.0, gx, gy,
            p[P_K1], p[P_K2], p[P_K3],
        )
    else:
        v, w, ex, ey, eth = tracking_command(
            x, y, th, xl + ox, yl + oy, thl, vl, wl, gx, gy, p[P_K1], p[P_K2], p[P_K3]
        )
    v = apply_threshold(v, p[P_VT], int(p[P_THRESHOLD]), frozen)
    v, w, scale = bound_command(v, w, x, y, th, r_self, nx, ny, nr, nk, na, n, p)
    mem[M_EX] = ex
    mem[M_EY] = ey
    mem[M_ETH] = eth
    mem[M_SCALE] = scale
    return v, w


def hold_horizon(dt: float, brake_s: float = BRAKE_S) -> float:
    """How long one command may act [s] when the next may be missing: its period, the world's one-period
    hold, then the brake ramp (swarm.core.faultkernel.brake_factor), as whole periods' shares of dt."""
    steps, since = 1.0, 1
    while True:
        f = 1.0 if since <= 1 else max(0.0, 1.0 - (since - 1) * dt / brake_s)
        if f <= 0.0:
            return dt * steps
        steps += f
        since += 1

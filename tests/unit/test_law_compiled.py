"""The compiled law a robot runs (swarm/core/_law.c) gives the bits swarm.core.law gives, on every branch:
freeze and release, each threshold mode, the speed bound, the governor with fresh and stale bodies, bodies
inside each other, angles to wrap, and values no run should reach (huge, infinite, NaN)."""

from __future__ import annotations

import math
import os
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core import fastlaw, law

# skipped without the compiled law, except under .ci/run (SWARM_REQUIRE_COMPILED): there its absence fails
pytestmark = [pytest.mark.unit,
              pytest.mark.skipif(fastlaw._law is None and not os.environ.get("SWARM_REQUIRE_COMPILED"),
                                 reason="the compiled law is not built here (no C compiler)")]


def test_ci_builds_the_compiled_law():
    """.ci/run sets SWARM_REQUIRE_COMPILED: there a missing build (it is optional at install) is a failure."""
    if os.environ.get("SWARM_REQUIRE_COMPILED"):
        assert fastlaw.COMPILED and fastlaw.robot_command is fastlaw._law.robot_command


def bits(x: float) -> bytes:
    """A float's bits, the sign of zero included; every NaN the same (the sign a NaN gets differs between
    libm's and the CPU's ways of making one, and no check tells one NaN from another: a NaN is refused)."""
    return b"nan" if math.isnan(x) else struct.pack("<d", x)


coord = st.one_of(st.floats(-5.0, 5.0), st.sampled_from([0.0, -0.0, 1e-13, 0.3, 1.2, 1e6]))
angle = st.one_of(st.floats(-20.0, 20.0), st.sampled_from([math.pi, -math.pi, 3 * math.pi, 1e6, -0.0]))
odd = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324])


@st.composite
def cases(draw):
    n = draw(st.integers(0, 8))
    near = st.tuples(st.floats(-1.6, 1.6), st.floats(-1.6, 1.6))  # within the cell around the robot at the origin
    rows = []
    for _ in range(n):
        dx, dy = draw(st.one_of(near, st.tuples(st.sampled_from([0.0, 0.2, 1e-13]), st.sampled_from([0.0, 0.1]))))
        r = draw(st.sampled_from([0.3, 0.2, 0.5]))
        R = draw(st.sampled_from([1.2, 0.8, 1.0, r + 1e-3]))
        kind = draw(st.sampled_from([law.KIND_ROBOT, law.KIND_OBSTACLE]))
        age = draw(st.one_of(st.just(0.0), st.floats(0.0, 2.0)))
        rows.append((dx, dy, r, R, kind, age))
    x, y = draw(coord), draw(coord)
    nx = [x + dx for dx, _, _, _, _, _ in rows]
    ny = [y + dy for _, dy, _, _, _, _ in rows]
    nr = [r for _, _, r, _, _, _ in rows]
    nR = [R for _, _, _, R, _, _ in rows]
    nk = [k for _, _, _, _, k, _ in rows]
    na = [a for *_, a in rows]
    if n and draw(st.booleans()):  # a value no run should reach, anywhere
        which = draw(st.sampled_from(["nx", "ny", "na", "x", "th", "xl", "vl"]))
        v = draw(odd)
        if which in ("nx", "ny", "na"):
            {"nx": nx, "ny": ny, "na": na}[which][draw(st.integers(0, n - 1))] = v
        else:
            rows.append((which, v))
    p = [0.0] * law.P_SIZE
    p[law.P_K1], p[law.P_K2], p[law.P_K3] = 0.5, 0.5, 1.0
    p[law.P_TU], p[law.P_VT] = draw(st.sampled_from([1.0, 0.5])), draw(st.sampled_from([0.05, 0.0, 0.5]))
    p[law.P_THRESHOLD] = float(draw(st.sampled_from([law.THRESHOLD_OFF, law.THRESHOLD_FROZEN, law.THRESHOLD_ALWAYS])))
    p[law.P_GOVERNOR] = draw(st.sampled_from([1.0, 0.0]))
    p[law.P_DT] = draw(st.sampled_from([0.02, 0.01, 0.06]))
    p[law.P_SENSE], p[law.P_REACH], p[law.P_OBSTACLE_R] = 1.5, 1.2, draw(st.sampled_from([0.0, 0.3]))
    p[law.P_V_MAX], p[law.P_W_MAX] = draw(st.sampled_from([(0.0, 0.0), (0.22, 2.84), (1e-3, 1e-3)]))
    mem = [0.0] * law.M_SIZE
    mem[law.M_SCALE] = 1.0
    if draw(st.booleans()):  # frozen earlier, with a snapshot due or not
        mem[law.M_FROZEN], mem[law.M_SNAP_X], mem[law.M_SNAP_Y], mem[law.M_SNAP_TH] = 1.0, 0.4, -0.3, 0.2
        mem[law.M_T_SNAP] = draw(st.sampled_from([0.0, 4.5, 5.0 - 1e-10]))
    args = dict(x=x, y=y, th=draw(angle), ox=draw(coord), oy=draw(coord), r_self=0.3, t=5.0, xl=draw(coord),
                yl=draw(coord), thl=draw(angle), vl=draw(st.floats(-1.0, 1.0)), wl=draw(st.floats(-1.0, 1.0)))
    for which, v in [r for r in rows if isinstance(r[0], str)]:
        args[which] = v
    return args, (nx, ny, nr, nR, nk, na, n), mem, p


@settings(max_examples=1000, deadline=None)
@given(case=cases())
def test_compiled_law_gives_the_same_bits(case):
    args, (nx, ny, nr, nR, nk, na, n), mem, p = case
    a = list(args.values())
    mem_py, mem_c = list(mem), list(mem)

    def outcome(f, *more):
        try:
            return tuple(bits(u) for u in f(*a, *more))
        except (ValueError, OverflowError) as e:  # math.cos(inf) and the like: a pose is never infinite, but
            return f"{type(e).__name__}: {e}"  # the two still fail alike, with mem as far as it got

    py = outcome(law.robot_command, nx, ny, nr, nR, nk, na, n, mem_py, p)
    c = outcome(fastlaw._law.robot_command, list(nx), list(ny), list(nr), list(nR), list(nk), list(na), n, mem_c,
                list(p))
    assert c == py
    assert [bits(m) for m in mem_c] == [bits(m) for m in mem_py]


def test_compiled_law_refuses_what_the_agent_never_passes():
    mem, p = [0.0] * law.M_SIZE, [0.0] * law.P_SIZE
    with pytest.raises(TypeError):
        fastlaw._law.robot_command(0.0, 0.0)
    with pytest.raises(IndexError, match="nx"):
        fastlaw._law.robot_command(*[0.0] * 12, [], [], [], [], [], [], 1, mem, p)
    with pytest.raises(TypeError, match="mem"):
        fastlaw._law.robot_command(*[0.0] * 12, [], [], [], [], [], [], 0, (0.0,) * law.M_SIZE, p)
    p[law.P_THRESHOLD] = math.nan
    with pytest.raises(ValueError, match="P_THRESHOLD"):
        fastlaw._law.robot_command(*[0.0] * 12, [], [], [], [], [], [], 0, mem, p)

"""The control law of docs/design.md (swarm.core.law, plain Python form)."""

from __future__ import annotations

import decimal
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from swarm.core import jit, kinematics, law
from swarm.core import scenario_file as sf
from swarm.core.scenario import Control, Leader, Segment

pytestmark = pytest.mark.unit

K1, K2, K3 = 0.5, 0.5, 1.0
SENSE = 1.5  # m, the default cell side (R + margin)
REACH = 1.2  # m, the default largest R


def params(dt=0.01, threshold="off", governor=False, tu=1.0, vt=0.05, sense=SENSE, reach=REACH, obstacle_r=0.3):
    return Control(k1=K1, k2=K2, k3=K3, tu=tu, vt=vt, threshold=threshold,
                   governor=governor).vector(dt, sense, reach, obstacle_r)


def bodies(*rows):
    """rows of (x, y, r, R, kind) -> nx, ny, nr, nR, nk, na, n (arrays with one spare entry; na: ages, all 0)."""
    size = len(rows) + 1
    nx, ny, nr, nR = (np.zeros(size) for _ in range(4))
    nk = np.zeros(size, np.int64)
    for a, (x, y, r, R, kind) in enumerate(rows):
        nx[a], ny[a], nr[a], nR[a], nk[a] = x, y, r, R, kind
    return nx, ny, nr, nR, nk, np.zeros(size), len(rows)


def new_mem():
    mem = np.zeros(law.M_SIZE)
    mem[law.M_SCALE] = 1.0
    return mem


def command(pose, offset, t, ref, nb, mem, p, r_self=0.3):
    x, y, th = pose
    xl, yl, thl, vl, wl = ref
    return law.robot_command(x, y, th, offset[0], offset[1], r_self, t, xl, yl, thl, vl, wl, *nb, mem, p)


# --------------------------------------------------------------------------- potential


def _ulps(got: float, exact: decimal.Decimal) -> float:
    """|got - exact| in units of the last place of `exact`'s double."""
    e = float(exact)
    ulp = math.ulp(e) if e != 0.0 else math.ulp(0.0)
    return float(abs(decimal.Decimal(got) - exact)) / ulp


def test_exp_pair_gives_b_and_one_minus_b_within_an_ulp_everywhere():
    """B and 1 - B from one libm call (exp below -ln 2, expm1 above): each within an ulp of the exact value,
    next to u = 0 (a body at the robot's border, where 1 - exp(u) would lose every digit) and at -ln 2."""
    decimal.getcontext().prec = 400  # 1 - B of u = -1e-200 needs 217 digits
    rng = np.random.default_rng(7)
    us = [0.0, -1e-200, -1e-12, -1e-6, -law.LN2, math.nextafter(-law.LN2, 0.0), math.nextafter(-law.LN2, -1.0),
          -1.0, -37.0, -700.0, -745.0, *(-rng.exponential(3.0, 400)), *(-rng.uniform(0.0, 1e-3, 100))]
    worst_b = worst_1mb = 0.0
    for u in us:
        b, one_minus_b = law.exp_pair(u)
        exact_b = decimal.Decimal(u).exp()
        worst_b = max(worst_b, _ulps(b, exact_b))
        if u != 0.0:
            worst_1mb = max(worst_1mb, _ulps(one_minus_b, 1 - exact_b))
    assert worst_b <= 1.0
    assert worst_1mb <= 1.0
    # the plain 1 - exp(u) next to u = 0 is off by about 1e4 ulps: why the pair takes expm1 there
    assert _ulps(1.0 - math.exp(-1e-12), 1 - decimal.Decimal(-1e-12).exp()) > 1e3
    assert law.exp_pair(-800.0) == (0.0, 1.0)


def test_exp_pair_compiled_gives_the_same_bits():
    compiled = jit.compiled("swarm.core.law")
    rng = np.random.default_rng(8)
    for u in (0.0, -law.LN2, math.nextafter(-law.LN2, 0.0), -745.0, -800.0, *(-rng.exponential(3.0, 200))):
        assert compiled.exp_pair(u) == law.exp_pair(u)


@pytest.mark.parametrize("r, R", [(0.3, 1.2), (0.2, 0.5), (0.5, 3.0), (1.0, 1.1)])
def test_potential_slope_matches_central_differences(r, R):
    rng = np.random.default_rng(1)
    span = R - r
    ls = rng.uniform(r + law.COLLISION_EPS + 1e-3 * span, R - 2e-3 * span, 300)
    for l in ls:
        h = 1e-6 * min(l - r - law.COLLISION_EPS, R - l)
        fd = (law.potential(l + h, r, R) - law.potential(l - h, r, R)) / (2 * h)
        slope = law.potential_slope(l, r, R)
        assert slope <= 0.0
        assert_allclose(slope, fd, rtol=1e-6, atol=1e-300, err_msg=f"l = {l!r}")


@pytest.mark.parametrize("r, R", [(0.3, 1.2), (0.2, 0.5)])
def test_repulsion_gradient_matches_central_differences_in_the_plane(r, R):
    rng = np.random.default_rng(2)
    for _ in range(300):
        xj, yj = rng.uniform(-5.0, 5.0, 2)
        l = rng.uniform(r + 2e-3 * (R - r), R - 2e-2 * (R - r))
        a = rng.uniform(-math.pi, math.pi)
        xi, yi = xj + l * math.cos(a), yj + l * math.sin(a)
        h = 1e-6 * min(l - r - law.COLLISION_EPS, R - l)

        def v(x, y):
            return law.potential(math.hypot(x - xj, y - yj), r, R)

        fx = (v(xi + h, yi) - v(xi - h, yi)) / (2 * h)
        fy = (v(xi, yi + h) - v(xi, yi - h)) / (2 * h)
        gx, gy = law.repulsion_gradient(xi, yi, xj, yj, r, R)
        scale = math.hypot(fx, fy)
        assert_allclose([gx, gy], [fx, fy], rtol=1e-6, atol=1e-6 * scale, err_msg=f"l = {l!r}, a = {a!r}")


def test_potential_grows_without_bound_towards_r():
    r, R = 0.3, 1.2
    deltas = np.array([0.5, 0.1, 1e-2, 1e-3, 3e-4, 1.5e-4])  # all above the clamp (1e-4)
    v = np.array([law.potential(r + d, r, R) for d in deltas])
    assert np.all(np.diff(v) > 0)
    assert v[-1] > 5e3
    # V ~ (R - r) / (l - r) next to r
    assert_allclose(v[-3:] * deltas[-3:], R - r, rtol=2e-3)


def test_potential_is_decreasing_on_the_whole_region():
    r, R = 0.3, 1.2
    ls = np.linspace(r + law.COLLISION_EPS, R, 5001)
    v = np.array([law.potential(l, r, R) for l in ls])
    s = np.array([law.potential_slope(l, r, R) for l in ls])
    positive = v > 0
    assert np.all(np.diff(v) <= 0)
    assert np.all(np.diff(v[positive]) < 0)
    assert np.all(s <= 0)
    assert np.all(s[:-1][positive[:-1]] < 0)


@pytest.mark.parametrize("l", [1.2, 1.2 + 1e-15, 1.5, 3.0, 1e6])
def test_potential_and_gradient_vanish_beyond_R(l):
    r, R = 0.3, 1.2
    assert law.potential(l, r, R) == 0.0
    assert law.potential_slope(l, r, R) == 0.0
    assert law.repulsion_gradient(2.0 + l, -1.0, 2.0, -1.0, r, R) == (0.0, 0.0)
    assert law.repulsion_gradient(2.0, -1.0 - l, 2.0, -1.0, r, R) == (0.0, 0.0)


def test_potential_and_slope_are_continuous_at_R():
    r, R = 0.3, 1.2
    deltas = [0.2, 0.1, 0.05, 0.02, 0.01, 1e-3, 1e-9]
    v = [law.potential(R - d, r, R) for d in deltas]
    s = [abs(law.potential_slope(R - d, r, R)) for d in deltas]
    assert all(a > b for a, b in zip(v[:5], v[1:5]))
    assert v[4] < 1e-30 and v[-1] == 0.0
    assert s[4] < 1e-25 and s[-1] == 0.0


@pytest.mark.parametrize("l", [0.3, 0.2999, 0.25, 0.1, 1e-3, 0.0])
def test_collision_clamp_keeps_the_repulsion_at_its_border_value(l):
    r, R = 0.3, 1.2
    edge = r + law.COLLISION_EPS
    assert law.potential(l, r, R) == law.potential(edge, r, R)
    assert law.potential(l, r, R) > 1e3
    assert law.potential_slope(l, r, R) == law.potential_slope(edge, r, R)
    assert law.potential_slope(l, r, R) < -1e6
    if l > 0.0:
        rng = np.random.default_rng(3)
        for a in rng.uniform(-math.pi, math.pi, 8):
            xj, yj = 4.0, -7.0
            xi, yi = xj + l * math.cos(a), yj + l * math.sin(a)
            gx, gy = law.repulsion_gradient(xi, yi, xj, yj, r, R)
            ex, ey = law.repulsion_gradient(xj + edge * math.cos(a), yj + edge * math.sin(a), xj, yj, r, R)
            assert_allclose([gx, gy], [ex, ey], rtol=1e-9)
            # the correction -grad V pushes robot i away from body j
            assert -(gx * (xi - xj) + gy * (yi - yj)) > 0.0
    else:
        gx, gy = law.repulsion_gradient(1.0, 2.0, 1.0, 2.0, r, R)
        assert math.hypot(gx, gy) == pytest.approx(abs(law.potential_slope(edge, r, R)))


def test_coincident_centres_push_along_plus_x_as_documented():
    gx, gy = law.repulsion_gradient(1.0, 2.0, 1.0, 2.0, 0.3, 1.2)
    assert gy == 0.0
    assert gx < 0.0  # the gradient points along -x ...
    assert -gx > 0.0  # ... so the correction P = p - grad V pushes along +x


# --------------------------------------------------------------------------- wrap


@pytest.mark.parametrize(
    "a, expected",
    [
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3 * math.pi, math.pi),
        (-3 * math.pi, math.pi),
        (2 * math.pi, 0.0),
        (-2 * math.pi, 0.0),
        (1.5 * math.pi, -0.5 * math.pi),
        (-1.5 * math.pi, 0.5 * math.pi),
        (7.0, 7.0 - 2 * math.pi),
        (-7.0, -7.0 + 2 * math.pi),
        (np.nextafter(math.pi, 4.0), -math.pi + 4.5e-16),
    ],
)
def test_wrap_angle_table(a, expected):
    w = law.wrap_angle(float(a))
    assert -math.pi < w <= math.pi
    assert_allclose(w, expected, atol=1e-14)


def test_wrap_angle_returns_values_in_range_bit_for_bit():
    rng = np.random.default_rng(4)
    values = list(rng.uniform(-math.pi, math.pi, 1000)) + [0.0, -0.0, 1e-300, -1e-300, math.pi,
                                                           np.nextafter(-math.pi, 0.0), 1.0, -1.0]
    for a in values:
        w = law.wrap_angle(float(a))
        assert w == a and math.copysign(1.0, w) == math.copysign(1.0, a)


@pytest.mark.parametrize("scale", [10.0, 1e3, 1e6, 1e9, 1e12, 1e15])
def test_wrap_angle_of_large_values_is_in_range_and_congruent(scale):
    rng = np.random.default_rng(5)
    for a in rng.uniform(-scale, scale, 500):
        w = law.wrap_angle(float(a))
        assert -math.pi < w <= math.pi
        d = abs(math.remainder(a, 2 * math.pi) - w)
        d = min(d, 2 * math.pi - d)
        assert d <= np.spacing(abs(a)) + 1e-15


def test_wrap_angle_without_fmod_gives_the_modulo_s_bits():
    """Below 2 TWO_PI in size wrap_angle subtracts instead of calling fmod: the same bits as Python's %."""
    def by_modulo(a: float) -> float:
        if -law.PI < a <= law.PI:
            return a
        w = a % law.TWO_PI
        return w - law.TWO_PI if w > law.PI else w

    rng = np.random.default_rng(7)
    edges = [law.PI, law.TWO_PI, 2 * law.TWO_PI, 3 * law.PI]
    values = list(rng.uniform(-2.5 * law.TWO_PI, 2.5 * law.TWO_PI, 20000))
    for e in edges:
        for x in (e, -e):
            values += [x, np.nextafter(x, 0.0), np.nextafter(x, 2 * x), x + 1e-9, x - 1e-9]
    values += [math.nan, math.inf, -math.inf, 0.0, -0.0]
    compiled = jit.compiled("swarm.core.law").wrap_angle  # numba's float ops, the simulator's copy
    for a in map(float, values):
        m = by_modulo(a) if math.isfinite(a) else math.nan
        for w in (law.wrap_angle(a), compiled(a)):
            assert (w == m and math.copysign(1.0, w) == math.copysign(1.0, m)) or (w != w and m != m), \
                f"wrap_angle({a!r}) = {w!r}, % gives {m!r}"


@pytest.mark.parametrize("a", [1e18, -1e18])
def test_wrap_angle_of_huge_values_is_in_range(a):
    rng = np.random.default_rng(6)
    for x in [a] + list(rng.uniform(0.5, 1.0, 50) * a):
        w = law.wrap_angle(float(x))
        assert -math.pi < w <= math.pi, f"wrap_angle({x!r}) = {w!r}"


# --------------------------------------------------------------------------- sgn and threshold


@pytest.mark.parametrize("vl, sgn", [(0.5, 1.0), (1e-300, 1.0), (-0.5, -1.0), (-1e-300, -1.0), (0.0, 1.0),
                                     (-0.0, 1.0)])
def test_omega_uses_k2_sgn_vl_ey_and_plain_k2_ey_when_vl_is_zero(vl, sgn):
    rng = np.random.default_rng(7)
    assert law.sgn_gain(vl) == sgn
    for _ in range(50):
        x, y, xd, yd, gx, gy = rng.uniform(-5, 5, 6)
        th, thd = rng.uniform(-3, 3, 2)
        wl = rng.uniform(-1, 1)
        v, w, ex, ey, eth = law.tracking_command(x, y, th, xd, yd, thd, vl, wl, gx, gy, K1, K2, K3)
        px, py = xd - x - gx, yd - y - gy
        ey_hand = -math.sin(th) * px + math.cos(th) * py
        ex_hand = math.cos(th) * px + math.sin(th) * py
        eth_hand = law.wrap_angle(thd - th)
        assert_allclose([ex, ey, eth], [ex_hand, ey_hand, eth_hand], rtol=1e-12, atol=1e-12)
        assert_allclose(w, wl + K2 * sgn * ey_hand + K3 * eth_hand, rtol=1e-12, atol=1e-12)
        assert_allclose(v, vl * math.cos(eth_hand) + K1 * ex_hand, rtol=1e-12, atol=1e-12)


def test_v_without_the_cos_at_a_zero_vl_has_the_bits_of_the_plain_formula():
    """v_l = +-0 (frozen) skips cos(e_theta): v = k1 E_x has the bits of v_l cos(e_theta) + k1 E_x, signed zeros
    (E_x = 0, k1 = 0) and a NaN e_theta included."""
    def plain(x, y, th, xd, yd, thd, vl, gx, gy, k1):
        cx, cy = xd - x - gx, yd - y - gy
        ex = math.cos(th) * cx + math.sin(th) * cy
        return vl * math.cos(law.wrap_angle(thd - th)) + k1 * ex

    rng = np.random.default_rng(8)
    cases = [(0.0, 0.0, 0.0, 0.0, 0.0, thd, vl, 0.0, 0.0, k1)  # E_x = +-0: the sign of v is the zeros'
             for thd in (0.3, -0.3, 2.0, -2.0, math.pi, math.nan) for vl in (0.0, -0.0) for k1 in (K1, 0.0, -K1)]
    for _ in range(300):
        x, y, xd, yd, gx, gy = rng.uniform(-5, 5, 6)
        th, thd = rng.uniform(-7, 7, 2)
        vl = float(rng.choice([0.0, -0.0, 0.5]))
        cases += [(x, y, th, xd, yd, thd, vl, gx, gy, K1), (x, y, th, xd, yd, math.nan, vl, gx, gy, K1)]
    compiled = jit.compiled("swarm.core.law").tracking_command
    for x, y, th, xd, yd, thd, vl, gx, gy, k1 in cases:
        want = plain(x, y, th, xd, yd, thd, vl, gx, gy, k1)
        for f in (law.tracking_command, compiled):
            v = f(x, y, th, xd, yd, thd, vl, 0.1, gx, gy, k1, K2, K3)[0]
            assert (v == want and math.copysign(1.0, v) == math.copysign(1.0, want)) or (v != v and want != want), \
                (f, x, y, th, xd, yd, thd, vl, k1, v, want)


def test_frozen_robot_steers_with_plain_k2_ey_even_when_the_leader_reverses():
    """Frozen: v_l = w_l = 0 in the law, so omega = k2 E_y + k3 e_theta (no sgn of the live v_l)."""
    p = params(threshold="off")
    mem = new_mem()
    nb = bodies((1.0, 0.5, 0.3, 1.2, law.KIND_ROBOT))
    pose = (0.0, 0.0, 0.3)
    ref = (2.0, -1.0, 0.1, -0.5, 0.2)  # leader drives backwards
    v, w = command(pose, (0.0, 0.0), 0.0, ref, nb, mem, p)
    assert mem[law.M_FROZEN] == 1.0
    ey, eth = mem[law.M_EY], mem[law.M_ETH]
    assert abs(ey) > 0.1
    assert_allclose(w, K2 * ey + K3 * eth, rtol=1e-12)
    assert abs(w - (-K2 * ey + K3 * eth)) > 0.1


@pytest.mark.parametrize(
    "mode, frozen, v, expected",
    [
        (law.THRESHOLD_OFF, True, 0.01, 0.01),
        (law.THRESHOLD_OFF, False, 0.0, 0.0),
        (law.THRESHOLD_OFF, True, -0.01, -0.01),
        (law.THRESHOLD_FROZEN, False, 0.01, 0.01),
        (law.THRESHOLD_FROZEN, False, 0.0, 0.0),
        (law.THRESHOLD_FROZEN, True, 0.01, 0.05),
        (law.THRESHOLD_FROZEN, True, -0.01, -0.05),
        (law.THRESHOLD_FROZEN, True, 0.0, 0.05),
        (law.THRESHOLD_FROZEN, True, -0.0, 0.05),
        (law.THRESHOLD_FROZEN, True, 0.05, 0.05),
        (law.THRESHOLD_FROZEN, True, 0.3, 0.3),
        (law.THRESHOLD_FROZEN, True, -0.3, -0.3),
        (law.THRESHOLD_ALWAYS, False, 0.01, 0.05),
        (law.THRESHOLD_ALWAYS, False, -0.049, -0.05),
        (law.THRESHOLD_ALWAYS, False, 0.0, 0.05),
        (law.THRESHOLD_ALWAYS, True, 0.0, 0.05),
        (law.THRESHOLD_ALWAYS, False, -0.2, -0.2),
        (law.THRESHOLD_ALWAYS, True, 7.0, 7.0),
    ],
)
def test_threshold_rule(mode, frozen, v, expected):
    assert law.apply_threshold(v, 0.05, mode, frozen) == expected


@pytest.mark.parametrize("threshold, frozen_applies, free_applies",
                         [("off", False, False), ("frozen", True, False), ("always", True, True)])
def test_robot_command_applies_the_threshold_by_mode(threshold, frozen_applies, free_applies):
    p = params(threshold=threshold, vt=0.05)
    # at the slot with the leader standing: the law gives v = 0 exactly
    ref = (1.0, 2.0, 0.4, 0.0, 0.0)
    pose = (1.0, 2.0, 0.4)
    v_free, _ = command(pose, (0.0, 0.0), 0.0, ref, bodies(), new_mem(), p)
    assert v_free == (0.05 if free_applies else 0.0)
    # frozen next to a robot straight to the left: the repulsion is along y, so E_x = 0 again
    nb = bodies((1.0 - 0.4 * math.sin(0.4), 2.0 + 0.4 * math.cos(0.4), 0.3, 1.2, law.KIND_ROBOT))
    mem = new_mem()
    v_frozen, _ = command(pose, (0.0, 0.0), 0.0, ref, nb, mem, p)
    assert mem[law.M_FROZEN] == 1.0
    assert abs(mem[law.M_EX]) < 1e-12 and abs(mem[law.M_EY]) > 1.0
    if frozen_applies:
        assert abs(v_frozen) == 0.05
    else:
        assert abs(v_frozen) < 1e-10


# --------------------------------------------------------------------------- freeze


def test_freeze_state_machine_snapshots_refreshes_every_tu_and_releases_at_once():
    dt, tu = 0.01, 1.0
    mem = new_mem()

    def live(t):
        return 0.5 * t, 0.1 * t * t, 0.2 * t

    enter, leave, reenter = 123, 468, 520  # steps: inside on [enter, leave) and from reenter on
    refreshes = []
    for k in range(700):
        t = k * dt
        inside = enter <= k < leave or k >= reenter
        before = mem[law.M_T_SNAP]
        frozen = law.freeze_update(mem, inside, t, *live(t), tu)
        assert frozen == inside
        assert mem[law.M_FROZEN] == (1.0 if inside else 0.0)
        if inside:
            if mem[law.M_T_SNAP] != before or k in (enter, reenter):
                refreshes.append(k)
                assert mem[law.M_T_SNAP] == t
                assert tuple(mem[law.M_SNAP_X:law.M_SNAP_TH + 1]) == live(t)
            else:
                assert tuple(mem[law.M_SNAP_X:law.M_SNAP_TH + 1]) == live(mem[law.M_T_SNAP])
    assert refreshes == [123, 223, 323, 423, 520, 620]


@pytest.mark.parametrize("dt, tu", [(0.001, 1.0), (0.02, 1.0), (0.05, 0.5), (0.1, 2.0)])
def test_freeze_refresh_instants_fall_on_every_tu(dt, tu):
    mem = new_mem()
    steps = int(round(5 * tu / dt))
    taken = []
    for k in range(steps + 1):
        t = k * dt
        before = (mem[law.M_FROZEN], mem[law.M_T_SNAP])
        law.freeze_update(mem, True, t, t, -t, 0.0, tu)
        if before != (1.0, mem[law.M_T_SNAP]) or k == 0:
            taken.append(k)
    per = int(round(tu / dt))
    assert taken == list(range(0, steps + 1, per))


def test_frozen_robot_command_tracks_the_snapshot_with_zero_leader_velocity():
    p = params(threshold="off", governor=False, dt=0.01)
    mem = new_mem()
    offset = (1.5, -0.75)
    r_nb = (0.9, 0.4, 0.3, 1.2, law.KIND_ROBOT)
    pose0 = (0.2, 0.1, 0.7)
    ref0 = (-1.0, 0.5, 0.3, 0.5, 0.1)
    command(pose0, offset, 2.0, ref0, bodies(r_nb), mem, p)
    assert mem[law.M_FROZEN] == 1.0
    assert (mem[law.M_SNAP_X], mem[law.M_SNAP_Y], mem[law.M_SNAP_TH], mem[law.M_T_SNAP]) == (-1.0, 0.5, 0.3, 2.0)

    # 0.5 s later, still inside: the live reference moved on, the law must use the snapshot
    pose = (0.25, 0.05, 0.8)
    ref = (-0.7, 0.6, 0.35, 0.5, 0.1)
    v, w = command(pose, offset, 2.5, ref, bodies(r_nb), mem, p)
    gx, gy = law.repulsion_gradient(pose[0], pose[1], r_nb[0], r_nb[1], r_nb[2], r_nb[3])
    ve, we, *_ = law.tracking_command(pose[0], pose[1], pose[2], -1.0 + offset[0], 0.5 + offset[1], 0.3,
                                      0.0, 0.0, gx, gy, K1, K2, K3)
    assert (v, w) == (ve, we)
    live, *_ = law.tracking_command(pose[0], pose[1], pose[2], ref[0] + offset[0], ref[1] + offset[1], ref[2],
                                    ref[3], ref[4], gx, gy, K1, K2, K3)
    assert abs(live - v) > 0.1

    # out of the region: the live reference at once
    far = (5.0, 5.0, 0.3, 1.2, law.KIND_ROBOT)
    v, w = command(pose, offset, 2.51, ref, bodies(far), mem, p)
    assert mem[law.M_FROZEN] == 0.0
    gx, gy = law.repulsion_gradient(pose[0], pose[1], 5.0, 5.0, 0.3, 1.2)
    assert (v, w) == law.tracking_command(pose[0], pose[1], pose[2], ref[0] + offset[0], ref[1] + offset[1],
                                          ref[2], ref[3], ref[4], gx, gy, K1, K2, K3)[:2]


def test_an_obstacle_repels_but_does_not_freeze():
    p = params(threshold="off")
    mem = new_mem()
    nb = bodies((0.8, 0.0, 0.3, 1.2, law.KIND_OBSTACLE))
    ref = (3.0, 0.0, 0.0, 0.5, 0.0)
    v, w = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, ref, nb, mem, p)
    assert mem[law.M_FROZEN] == 0.0
    gx, gy = law.repulsion_gradient(0.0, 0.0, 0.8, 0.0, 0.3, 1.2)
    assert gx > 0 and gy == 0.0  # grad V points at the body: the correction -grad V points away
    assert (v, w) == law.tracking_command(0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.5, 0.0, gx, gy, K1, K2, K3)[:2]


def test_robot_neighbours_sum_their_gradients_in_the_given_order():
    p = params(threshold="off")
    rows = [(0.9, 0.3, 0.3, 1.2, law.KIND_ROBOT), (-0.4, 1.0, 0.3, 1.2, law.KIND_ROBOT),
            (0.2, -1.1, 0.25, 1.0, law.KIND_OBSTACLE)]
    gx = gy = 0.0
    for x, y, r, R, _ in rows:
        ax, ay = law.repulsion_gradient(0.0, 0.0, x, y, r, R)
        gx += ax
        gy += ay
    mem = new_mem()
    v, w = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, (0.0, 0.0, 0.0, 0.0, 0.0), bodies(*rows), mem, p)
    assert (v, w) == law.tracking_command(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, gx, gy, K1, K2, K3)[:2]


# --------------------------------------------------------------------------- governor


def test_governor_changes_nothing_far_from_every_body():
    rng = np.random.default_rng(8)
    for dt in (0.001, 0.02, 0.05):
        for _ in range(100):
            pose = tuple(rng.uniform(-3, 3, 3))
            ref = tuple(rng.uniform(-3, 3, 3)) + tuple(rng.uniform(-1, 1, 2))
            off = tuple(rng.uniform(-2, 2, 2))
            t = rng.uniform(0, 100)
            on_mem, off_mem = new_mem(), new_mem()
            on = command(pose, off, t, ref, bodies(), on_mem, params(dt=dt, governor=True, threshold="frozen"))
            free = command(pose, off, t, ref, bodies(), off_mem, params(dt=dt, governor=False, threshold="frozen"))
            assert on == free
            assert on_mem[law.M_SCALE] == 1.0


@pytest.mark.parametrize(
    "kind, r_body, l, fraction",
    [
        (law.KIND_OBSTACLE, 0.3, 0.5, law.GOVERNOR_FRACTION),
        (law.KIND_OBSTACLE, 0.6, 0.75, law.GOVERNOR_FRACTION),
        (law.KIND_ROBOT, 0.3, 0.6, 0.5 * law.GOVERNOR_FRACTION),
        (law.KIND_ROBOT, 0.4, 0.6, 0.5 * law.GOVERNOR_FRACTION),  # the larger r counts
    ],
)
def test_governor_step_closes_at_most_its_share_of_the_clearance(kind, r_body, l, fraction):
    dt = 0.1
    p = params(dt=dt, governor=True, threshold="frozen")
    p_off = params(dt=dt, governor=False, threshold="frozen")
    rng = np.random.default_rng(9)
    for a in rng.uniform(-math.pi, math.pi, 20):
        nb = bodies((l * math.cos(a), l * math.sin(a), r_body, 1.2, kind))
        clearance = l - max(0.3, r_body) if kind == law.KIND_ROBOT else l - r_body
        ref = (60 * math.cos(a), 60 * math.sin(a), a, 0.5, 0.0)  # the slot lies far beyond the body
        pose = (0.0, 0.0, a)
        mem = new_mem()
        v, w = command(pose, (0.0, 0.0), 0.0, ref, nb, mem, p)
        v0, w0 = command(pose, (0.0, 0.0), 0.0, ref, nb, new_mem(), p_off)
        assert abs(v0) * dt > fraction * clearance  # the governor has work to do
        assert abs(v) * dt <= fraction * clearance * (1 + 1e-12)
        assert_allclose(abs(v) * dt, fraction * clearance, rtol=1e-12)
        assert mem[law.M_SCALE] < 1.0
        assert_allclose([v, w], [v0 * mem[law.M_SCALE], w0 * mem[law.M_SCALE]], rtol=1e-12)


def test_governor_limit_of_bodies_out_of_reach_is_a_share_of_the_reach():
    dt, r_self = 0.02, 0.3
    nx, ny, nr, nR, nk, na, n = bodies()
    limit = law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, REACH, SENSE, 0.3, 0.0, 1.0, 0.0)[0]
    assert_allclose(limit * dt, 0.5 * law.GOVERNOR_FRACTION * (REACH - r_self), rtol=1e-15)
    # a robot at the reach or farther, an obstacle at the cell side or farther, set no limit of their own
    nx, ny, nr, nR, nk, na, n = bodies((REACH, 0.0, 0.3, 1.2, law.KIND_ROBOT), (0.0, SENSE, 1.1, 1.2, law.KIND_OBSTACLE))
    assert law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, REACH, SENSE, 0.3, 0.0, 1.0, 0.0)[0] == limit


def test_the_bound_for_unseen_obstacles_follows_the_largest_obstacle():
    """An obstacle of r = 2.4 beyond the cell side (2.8 m) has only 0.4 m of clearance there: a step may
    take GOVERNOR_FRACTION of that, less than the share of reach - r_self a step toward unseen robots may
    take (a review found 5-15 collisions with big obstacles when only that bound held)."""
    dt, r_self, reach, sense = 0.1, 0.3, 2.5, 2.8
    nx, ny, nr, nR, nk, na, n = bodies()
    limit = law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, reach, sense, 2.4, 0.0, 1.0, 0.0)[0]
    assert_allclose(limit * dt, law.GOVERNOR_FRACTION * (sense - 2.4), rtol=1e-15)
    assert law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, reach, sense, 0.3, 0.0, 1.0, 0.0)[0] * dt == \
        pytest.approx(0.5 * law.GOVERNOR_FRACTION * (reach - r_self))


def test_a_big_obstacle_beyond_the_reach_still_caps_the_speed():
    """Obstacles count up to the cell side (every robot knows them all): one of r = 1 at 1.3 m has 0.3 m
    of clearance, which the bound for unseen robots (a share of reach - r) would let a robot cross."""
    dt = 0.25
    ref = (8.0, 0.0, 0.0, 0.5, 0.0)
    v, _ = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, ref, bodies((0.0, -1.3, 1.0, 1.2, law.KIND_OBSTACLE)),
                   new_mem(), params(dt=dt, governor=True, threshold="off", obstacle_r=1.0))
    assert_allclose(abs(v), law.GOVERNOR_FRACTION * (1.3 - 1.0) / dt, rtol=1e-12)


@pytest.mark.parametrize("far", [REACH, 1.3, SENSE - 1e-9])
def test_known_robots_beyond_the_reach_do_not_act_on_the_command(far):
    """Lock-step waits only for the robots that can come within the reach (docs/runtime.md): those
    between the reach and the cell side must not change the command, even where the governor acts.
    (When the governor's bound for unseen bodies used the cell side, a robot 1.3 m away capped |v|.)"""
    kind = law.KIND_ROBOT
    dt, r_self = 0.25, 0.3
    p = params(dt=dt, governor=True, threshold="off")
    ref = (8.0, 0.0, 0.0, 0.5, 0.0)  # the slot is far ahead: the law asks for more than the governor allows
    alone = bodies()
    with_far = bodies((-far, 0.0, 0.3, 1.2, kind))
    mem0, mem1 = new_mem(), new_mem()
    v0, w0 = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, ref, alone, mem0, p)
    v1, w1 = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, ref, with_far, mem1, p)
    assert (v1, w1) == (v0, w0) and list(mem1) == list(mem0)
    assert_allclose(abs(v0), 0.5 * law.GOVERNOR_FRACTION * (REACH - r_self) / dt, rtol=1e-15)  # the governor acted


@pytest.mark.parametrize("kind", [law.KIND_OBSTACLE, law.KIND_ROBOT])
@pytest.mark.parametrize("l", [0.3, 0.2, 0.0])
def test_body_already_inside_sets_no_speed_limit(kind, l):
    dt, r_self = 0.02, 0.3
    nx, ny, nr, nR, nk, na, n = bodies()
    free = law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, REACH, SENSE, 0.3, 0.0, 1.0, 0.0)[0]
    nx, ny, nr, nR, nk, na, n = bodies((l, 0.0, 0.3, 1.2, kind))
    assert law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, REACH, SENSE, 0.3, 0.0, 1.0, 0.0)[0] == free
    # with another body outside, that one sets the limit
    nx, ny, nr, nR, nk, na, n = bodies((l, 0.0, 0.3, 1.2, kind), (0.0, 0.5, 0.3, 1.2, law.KIND_OBSTACLE))
    got = law.governor_speed_limit(0.0, 0.0, r_self, nx, ny, nr, nk, na, n, dt, REACH, SENSE, 0.3, 0.0, 1.0, 0.0)[0]
    assert_allclose(got, law.GOVERNOR_FRACTION * 0.2 / dt, rtol=1e-12)
    # and through robot_command: inside a body the robot is pushed out at up to the free limit
    p = params(dt=dt, governor=True, threshold="off")
    nb = bodies((0.1, 0.0, 0.3, 1.2, kind))
    v, _ = command((0.0, 0.0, 0.0), (0.0, 0.0), 0.0, (0.0, 0.0, 0.0, 0.0, 0.0), nb, new_mem(), p)
    assert v < 0.0
    assert_allclose(abs(v), free, rtol=1e-12)


# --------------------------------------------------------------------------- closed loop


def _run_one_robot(segments, slot_offset, start_error, dt=0.01, duration=60.0):
    leader = Leader((1.0, -2.0, 0.2), tuple(Segment(*s) for s in segments))
    table = leader.table()
    xl, yl, thl, _, _ = kinematics.leader_state(table, 0.0)
    q = np.array([xl + slot_offset[0] + start_error[0], yl + slot_offset[1] + start_error[1],
                  thl + start_error[2]])
    c = np.zeros(3)
    mem = new_mem()
    p = params(dt=dt, threshold="frozen", governor=True)
    nb = bodies()
    steps = int(round(duration / dt))
    for k in range(steps + 1):
        t = k * dt
        ref = kinematics.leader_state(table, t)
        if k == steps:
            break
        v, w = command(q, slot_offset, t, ref, nb, mem, p)
        kinematics.step_pose(q, c, v, w, dt)
    return math.hypot(ref[0] + slot_offset[0] - q[0], ref[1] + slot_offset[1] - q[1]), law.wrap_angle(ref[2] - q[2])


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    "segments",
    [
        [(60.0, 0.5, 0.0)],  # straight
        [(60.0, 0.5, 0.1)],  # a constant left arc
        [(60.0, 0.4, -0.15)],  # a constant right arc
        [(10.0, 0.5, 0.0), (20.0, 0.5, 0.0982), (30.0, 0.5, 0.0)],  # switches on the step grid
    ],
)
@pytest.mark.parametrize("start_error", [(-1.0, 0.8, 0.5), (0.7, -0.4, -2.5)])
def test_single_robot_converges_to_its_slot(segments, start_error):
    pe, ee = _run_one_robot(segments, (1.5, -0.75), start_error)
    assert pe < 1e-9  # ~1e-11 expected: the slowest mode decays as t exp(-t / 2)
    assert abs(ee) < 1e-9


@pytest.mark.timeout(60)
@pytest.mark.parametrize("w", [0.0, 0.1, -0.2])
def test_single_robot_converges_tightly_in_the_compiled_simulator(w):
    doc = {
        "run": {"duration": 100.0, "dt": 0.01},
        "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.0, "v": 0.5, "w": w}]},
        "formation": {"offsets": [[1.5, -0.75]]},
        "robots": {"poses": [[0.5, 0.2, 0.9]]},
    }
    from swarm.core.sim import Simulation

    m = Simulation(sf.resolve(sf.parse(doc, "test", "one-robot"))).run().metrics
    assert m["final_position_error_max_m"] < 1e-9
    assert m["final_orientation_error_max_rad"] < 1e-9
    assert m["converged_at_s"] is not None and m["converged_at_s"] < 60.0
    assert m["min_robot_distance_m"] is None and m["collisions"] == 0

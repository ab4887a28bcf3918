"""Real time's safety rule (swarm.core.safety; docs/runtime.md, "The safety invariant"): its bounds hold for every
motion a drive can make, and robots that follow it never meet, whatever the latency, the losses or the deaths."""

from __future__ import annotations

import math
import random

import pytest

from swarm.core import kinematics, safety

pytestmark = pytest.mark.unit

RAMP, EPS, DT = safety.RAMP_S, safety.CLOCK_SKEW_S, 0.02
H = min(DT, RAMP / 2.0)  # the simulated world's ramp step


def factor(t: float, until: float) -> float:
    """The simulated world's speed factor of a command valid until `until`, at time t (world.realtime_loop: full until
    then, then 1 - k h / RAMP from until + (k - 1) h, never faster than a linear ramp to a stop over RAMP)."""
    if t < until:
        return 1.0
    k = int((t - until) / H) + 1
    return max(0.0, 1.0 - k * H / RAMP)


def drive(x: float, y: float, th: float, t0: float, t1: float, cmds: list[tuple[float, float, float, float]],
          step: float = 0.002) -> list[tuple[float, float, float]]:
    """The positions a simulated drive takes from (x, y, th) at t0 to t1: cmds are (arrival, v, w, until), each
    executed from its arrival (one that arrives after its until never is) until the next arrives."""
    out = [(t0, x, y)]
    q, comp = [x, y, th], [0.0, 0.0, 0.0]
    t = t0
    live = sorted((a, v, w, u) for a, v, w, u in cmds if a <= u)
    while t < t1 - 1e-12:
        dt = min(step, t1 - t)
        now = [c for c in live if c[0] <= t + 1e-12]
        if now:
            _a, v, w, u = now[-1]
            f = factor(t, u)
            kinematics.step_pose(q, comp, v * f, w * f, dt)
        t += dt
        out.append((t, q[0], q[1]))
    return out


def random_plan(rng: random.Random, t: float):
    """A pose's time s <= t, pending commands (speed, turn, until) sent before, and a new command's until."""
    s = t - rng.uniform(0.0, 0.1)
    pending = [(rng.uniform(0.0, 1.0), rng.uniform(-1.0, 1.0), s + rng.uniform(-0.05, 0.12))
               for _ in range(rng.randint(0, 3))]
    until = t + rng.uniform(0.04, 0.3)
    return s, pending, until


def plan_of(s, t, pending, until, switch=0.0) -> safety.Plan:
    vp = max((abs(v) for v, _w, u in pending if u + EPS + RAMP / 2 > s), default=0.0)
    wp = max((abs(w) for _v, w, u in pending if u + EPS + RAMP / 2 > s), default=0.0)
    ep = max([u + EPS + RAMP / 2 for _v, _w, u in pending] + [-math.inf])
    return safety.Plan(s, t, until, vp, max(ep, s), wp, RAMP, switch, EPS)


@pytest.mark.parametrize("seed", range(40))
def test_the_reach_bounds_every_motion_the_drive_can_make(seed):
    """From its pose of time s, whatever command is acting then (a pending one, sent earlier, possibly late) and
    whenever the new one arrives (or never), a robot moves at most Plan.reach(|v|) and stands by Plan.end."""
    rng = random.Random(seed)
    t = 10.0
    s, pending, until = random_plan(rng, t)
    v, w = rng.uniform(-1.0, 1.0), rng.uniform(-2.0, 2.0)
    plan = plan_of(s, t, pending, until)
    for _ in range(5):
        # the pending ones arrived in order before s (the newest acts at s), the new one at a random time
        cmds = [(s - 0.01 * (len(pending) - k), pv, pw, pu) for k, (pv, pw, pu) in enumerate(pending)]
        arrival = rng.choice([t, until + EPS, rng.uniform(t, until + EPS), math.inf])
        if arrival < math.inf:
            cmds.append((arrival, v, w, until + EPS))  # the drive's clock may be EPS behind
        path = drive(0.0, 0.0, rng.uniform(-3, 3), s, plan.end + 0.2, cmds)
        far = max(math.hypot(x, y) for _t, x, y in path)
        assert far <= plan.reach(abs(v)) + 1e-9, (far, plan.reach(abs(v)))
        assert math.hypot(path[-1][1] - path[-20][1], path[-1][2] - path[-20][2]) == 0.0  # standing by the end


@pytest.mark.parametrize("seed", range(60))
def test_a_limited_command_keeps_clear_of_everywhere_a_body_can_be_or_moves_away_from_it(seed):
    """For bodies placed at random (a position, a contact distance, how far they may be from it), the speed the
    rule allows keeps every position the robot can reach farther than the contact distance from every point the
    body can be at, or moves the robot away from all of them (its distance to each only grows). (No pending
    command here: an earlier check covers a pending one's motion; the test above bounds it.)"""
    rng = random.Random(1000 + seed)
    t = 5.0
    s, _pending, until = random_plan(rng, t)
    pending: list = []
    plan = plan_of(s, t, pending, until)
    th = rng.uniform(-math.pi, math.pi)
    v, w = rng.choice([-1, 1]) * rng.uniform(0.1, 1.0), rng.uniform(-1.0, 1.0)
    bodies = []
    for _ in range(rng.randint(1, 4)):
        ang, l = rng.uniform(-math.pi, math.pi), rng.uniform(0.4, 1.6)
        bodies.append((l * math.cos(ang), l * math.sin(ang), 0.3, rng.uniform(0.0, 0.5)))
    sv = 1.0 if v >= 0 else -1.0
    limit, _why = plan.limit(0.0, 0.0, sv * math.cos(th), sv * math.sin(th), w, bodies, 1.0)
    f = min(1.0, limit / abs(v))
    vv, ww = v * f, (w * f if f > 0 else w)
    cmds = [(s - 0.01 * (len(pending) - k), pv, pw, pu) for k, (pv, pw, pu) in enumerate(pending)]
    cmds.append((rng.uniform(t, until + EPS), vv, ww, until + EPS))
    path = drive(0.0, 0.0, th, s, plan.end, cmds)
    for bx, by, contact, m in bodies:
        clear = min(math.hypot(x - bx, y - by) for _t, x, y in path) - m > contact
        # away: the distance to each point the body can be at never shrinks along the path
        ring = [(bx + m * math.cos(a), by + m * math.sin(a)) for a in [k * math.pi / 8 for k in range(16)]] + [(bx, by)]
        away = all(math.hypot(x1 - qx, y1 - qy) >= math.hypot(x0 - qx, y0 - qy) - 1e-9
                   for (_t0, x0, y0), (_t1, x1, y1) in zip(path, path[1:]) for qx, qy in ring)
        assert clear or away, (bodies, limit)


def test_standing_is_always_allowed_and_a_body_far_away_sets_no_limit():
    plan = safety.Plan(1.0, 1.0, 1.1, 0.0, 1.0)
    assert plan.reach(0.0) == 0.0
    assert plan.limit(0.0, 0.0, 1.0, 0.0, 0.0, [(50.0, 0.0, 0.3, 1.0)], 1.0) == (math.inf, safety.FREE)
    limit, why = plan.limit(0.0, 0.0, 1.0, 0.0, 0.0, [(0.5, 0.0, 0.3, 0.3)], 1.0)  # right ahead, may be touching
    assert limit == 0.0 and why == safety.AWAY_ONLY
    assert plan.limit(0.0, 0.0, -1.0, 0.0, 0.0, [(0.5, 0.0, 0.3, 0.3)], 1.0)[0] == math.inf  # backing away: free
    limit, why = plan.limit(0.0, 0.0, 1.0, 0.0, 0.0, [], 1.0, unknown=0.4)
    assert limit == 0.4 and why == safety.UNKNOWN
    assert safety.unheard_speed(1.5, 0.3, 0.1, 0.2) == pytest.approx(2.0)
    assert 0.0 < safety.unheard_speed(1.5, 0.3, 10.0, 0.5) < 0.1  # slowed, never frozen


def test_a_neighbours_bound_grows_with_its_age_and_holds_still_while_it_promised():
    V = 1.0
    assert safety.motion_bound(2.0, 0.5, 1.8, V, eps=0.0) == pytest.approx(0.7)
    # promised to stand for 0.4 s after its state (of time 1.3 = 1.8 - 0.5): static until 1.7, then V
    assert safety.motion_bound(1.8, 0.5, 1.8, V, stop=0.05, still_left=0.4, eps=0.0) == pytest.approx(0.15)
    assert safety.motion_bound(1.6, 0.1, 1.6, V, stop=0.05, still_left=0.4, eps=0.0) == pytest.approx(0.05)
    # a promise is taken for at most PROMISE_MAX_S
    far = safety.motion_bound(3.0, 0.0, 1.0, V, stop=0.0, still_left=1e6, eps=0.0)
    assert far == pytest.approx(V * (2.0 - safety.PROMISE_MAX_S))


def test_validity_follows_the_lag_and_the_time_commands_take_to_act_up_to_a_cap():
    assert safety.validity(0.02, 0.0) == pytest.approx(0.06)
    assert safety.validity(0.02, 0.05) == pytest.approx(0.16)
    assert safety.validity(0.02, 0.0, 0.2) == pytest.approx(0.24)
    assert safety.validity(0.02, 2.0) == safety.VALIDITY_MAX_S
    assert safety.speed_bound(0.0, 0.5) == 1.0 and safety.speed_bound(0.0, 2.0) == 4.0 and safety.speed_bound(0.3, 2.0) == 0.3


@pytest.mark.parametrize("seed", range(6))
def test_robots_that_follow_the_rule_never_meet_whatever_the_latency(seed):
    """Eight robots in a 4 m box, each driven toward random goals at up to V by a law that knows nothing of
    safety, steered only by the rule: each command is computed from neighbours' states up to 0.4 s old (a random
    delay each time), reaches the drive after up to 0.25 s (or never: 15 % lost, or refused past its validity),
    and two robots die mid-run (the world stops them at once). No two robots ever come within the contact
    distance; and they do move (the rule is not a wall)."""
    rng = random.Random(seed)
    n, V, contact, T, fine = 8, 1.0, 0.3, 12.0, 0.002
    pos: list[tuple[float, float]] = []
    while len(pos) < n:
        p = (rng.uniform(0, 4), rng.uniform(0, 4))
        if all(math.hypot(p[0] - o[0], p[1] - o[1]) > 0.8 for o in pos):
            pos.append(p)
    q = [[x, y, rng.uniform(-math.pi, math.pi)] for x, y in pos]
    comp = [[0.0, 0.0, 0.0] for _ in range(n)]
    goals = [(rng.uniform(0, 4), rng.uniform(0, 4)) for _ in range(n)]
    dies = {i: rng.uniform(2, 8) for i in rng.sample(range(n), 2)}
    history: list[list[tuple]] = [[] for _ in range(n)]  # the states each published: (t, x, y, stop, still)
    inflight: list[list[tuple]] = [[] for _ in range(n)]  # commands on their way: (arrival, v, w, until)
    pending: list[list[tuple]] = [[] for _ in range(n)]  # commands sent: (|v|, |w|, until)
    acting: list[tuple | None] = [None] * n  # the command each drive executes: (v, w, until)
    still = [-math.inf] * n
    travelled = [0.0] * n
    closest = math.inf
    every = int(round(DT / fine))
    for k in range(int(T / fine)):
        t = k * fine
        dead = [i in dies and t >= dies[i] for i in range(n)]
        if k % every == 0:
            for i in range(n):
                if dead[i]:
                    continue
                x, y, th = q[i]
                s = t - rng.uniform(0.0, 0.05)  # the pose read late: the rule bounds its motion from s
                gx, gy = goals[i]
                if math.hypot(gx - x, gy - y) < 0.2:
                    goals[i] = gx, gy = rng.uniform(0, 4), rng.uniform(0, 4)
                err = (math.atan2(gy - y, gx - x) - th + math.pi) % (2 * math.pi) - math.pi
                v, w = V * max(0.0, math.cos(err)), 2.0 * err
                until = t + safety.validity(DT, rng.uniform(0.0, 0.1))
                pend = [c for c in pending[i] if c[2] + EPS + RAMP / 2 > s]
                plan = safety.Plan(s, t, until, max((c[0] for c in pend), default=0.0),
                                   max([c[2] + EPS + RAMP / 2 for c in pend] + [s]),
                                   max((c[1] for c in pend), default=0.0), RAMP, 0.0, EPS)
                bodies = []
                for j in range(n):
                    if j == i or not history[j]:
                        continue
                    delay = rng.uniform(0.0, 0.4)
                    known = [h for h in history[j] if h[0] <= t - delay] or history[j][:1]
                    tj, xj, yj, stopj, stillj = known[-1]
                    if dead[j] and known[-1] is history[j][-1]:  # its last state, and its token is gone
                        m = stopj + V * EPS
                    else:
                        m = safety.motion_bound(plan.end, t - tj, t, V, stopj, stillj - tj)
                    bodies.append((xj, yj, contact, m))
                if t < still[i]:
                    v = 0.0
                else:
                    sv = 1.0 if v >= 0 else -1.0
                    limit, _ = plan.limit(x, y, sv * math.cos(th), sv * math.sin(th), w, bodies, V)
                    if abs(v) > limit:
                        if limit < 1e-3:
                            v = 0.0
                            still[i] = t + (plan.end - t) * (1.0 + 0.5 * rng.random())
                        else:
                            v, w = v * limit / abs(v), w * limit / abs(v)
                history[i].append((s, x, y, plan.reach(abs(v)), still[i] if still[i] > t else 0.0))
                pending[i] = pend + [(abs(v), abs(w), until)]
                if rng.random() > 0.15:
                    inflight[i].append((t + rng.uniform(0.0, 0.25), v, w, until))
        for i in range(n):
            if dead[i]:
                acting[i] = None  # the world stops a dead robot at once
                continue
            for c in sorted(c for c in inflight[i] if c[0] <= t):
                if c[0] <= c[3]:  # one that comes after its validity is refused
                    acting[i] = c[1:]
            inflight[i] = [c for c in inflight[i] if c[0] > t]
            if acting[i] is not None:
                v, w, until = acting[i]
                f = factor(t, until)
                x0, y0 = q[i][0], q[i][1]
                kinematics.step_pose(q[i], comp[i], v * f, w * f, fine)
                travelled[i] += math.hypot(q[i][0] - x0, q[i][1] - y0)
        for i in range(n):
            for j in range(i):
                closest = min(closest, math.hypot(q[i][0] - q[j][0], q[i][1] - q[j][1]))
    assert closest > contact, closest
    assert sum(travelled) > 2.0, travelled  # they did move (not much, with news this old: the rule is not a wall)

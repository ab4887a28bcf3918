"""Rendezvous: every robot heads for the centre of the robots it hears, and keeps `gap` from each.

A consensus law for `[control] law = "laws/rendezvous.py:rendezvous"`: the leader and the slots play no
part (the reference is ignored), so the swarm is judged by `final_spread_m`, the largest distance between
two robots at the end (docs/metrics.md), not by convergence to slots. Each robot averages the positions of
itself and of the robots closer than reach (the largest R: its neighbours in the scenario), steers toward that
point, and is pushed off any body (robot, obstacle or dead robot) closer than `gap`. params = [k_v, k_w, gap]:
the gain on the distance to the centre [1/s], the turning gain [1/s], the distance [m] it keeps from a body's
centre.

Written to numba's subset (math, one element at a time, loops in order): `swarm scenario check` holds the
compiled law equal to the Python one.
"""

import math


def rendezvous(me, ref, bodies, params, *, kinds):
    k_v, k_w, gap = params[0], params[1], params[2]
    x, y, th = me[0], me[1], me[2]
    cx = x
    cy = y
    count = 1
    for i in range(bodies.shape[0]):
        if kinds[i] == 0:  # a live robot
            cx += bodies[i, 0]
            cy += bodies[i, 1]
            count += 1
    tx = cx / count - x
    ty = cy / count - y
    for i in range(bodies.shape[0]):
        dx = x - bodies[i, 0]
        dy = y - bodies[i, 1]
        d = math.sqrt(dx * dx + dy * dy)
        if 1e-9 < d < gap:
            f = (gap - d) / d
            tx += 2.0 * f * dx
            ty += 2.0 * f * dy
    dist = math.sqrt(tx * tx + ty * ty)
    if dist < 0.02:  # there: hold still
        return 0.0, 0.0
    heading = math.atan2(ty, tx) - th
    heading = math.atan2(math.sin(heading), math.cos(heading))
    v = k_v * dist * math.cos(heading)
    w = k_w * math.sin(heading)
    return v, w

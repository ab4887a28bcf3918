"""Go to your slot, keep clear of what is near: a law for `[control] law = "laws/goto_slot.py:goto_slot"`.

A tracking law drives the robot to its slot (the reference `ref`: the slot's pose and speeds); each body
closer than `gap` pushes the target away from it, harder the closer it is. The governor (control.governor)
then keeps every step safe. params = [k1, k2, k3, gap, push]: the gains on the along-track, cross-track and
heading errors, the distance [m] at which a body starts to push, and how hard it pushes.

Written to numba's subset of Python (math, float arrays indexed one element at a time, loops in order), so
`swarm sim` compiles it and the compiled law equals the Python one bit for bit (`swarm scenario check`).
"""

import math


def goto_slot(me, ref, bodies, params):
    k1, k2, k3, gap, push = params[0], params[1], params[2], params[3], params[4]
    x, y, th = me[0], me[1], me[2]
    tx = ref[0] - x
    ty = ref[1] - y
    for i in range(bodies.shape[0]):
        dx = x - bodies[i, 0]
        dy = y - bodies[i, 1]
        d = math.sqrt(dx * dx + dy * dy)
        clear = d - bodies[i, 2]  # distance to the body's edge
        if d > 1e-9 and clear < gap:
            f = push * (gap - clear) / max(clear, 0.05)
            tx += f * dx / d
            ty += f * dy / d
    c = math.cos(th)
    s = math.sin(th)
    ex = c * tx + s * ty  # the target in the robot's frame
    ey = -s * tx + c * ty
    eth = ref[2] - th
    eth = math.atan2(math.sin(eth), math.cos(eth))
    v = ref[3] * math.cos(eth) + k1 * ex
    w = ref[4] + k2 * ey + k3 * math.sin(eth)
    return v, w

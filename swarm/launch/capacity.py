"""Whether this machine can hold a real-time swarm's control period, measured before `swarm up --mode realtime`.

    need = demand(robots, dt, speed, step_us())   # cores the swarm needs
    note = verdict(robots, dt, speed)              # None, or a warning naming what this machine can hold

A real-time robot does its control step every period whatever the machine: when the machine cannot keep up, its
commands come late, their validity runs out and its safety rule holds it back (docs/runtime.md, "The safety
invariant"): safe, but slower. This measures the Python part of one robot's step here (decode its neighbours'
states, the law, the safety rule, encode its state and command), then scales it by what a whole robot process
costs beside it: zenoh's threads, the wake-ups and the cold caches of 40 processes on a few cores (PROCESS_FACTOR,
measured on the 2-core development machine), plus the world and the router (a share per robot). It warns when the
swarm would need more than HEADROOM of the cores.
"""

from __future__ import annotations

import math
import os
import time

# What a whole real-time swarm costs a robot-period, over the step measured here. On the 2-core development machine
# (a step of 32 us) `swarm up --robots 19 --mode realtime --duration 30` took 1.0-1.6 ms of CPU a robot-period at
# speed 1 (all its processes: the robot's own, zenoh's threads and wake-ups in it, the world, the router, the
# leader) and less at speed 2 (more work a wake-up); 1 850-1 900 robot-periods a second (37 robots at speed 1, 19
# at speed 2) held the period in bench/realtime_stress.py (round trip p99 13-49 ms), 3 700 (37 at speed 2) did not
PROCESS_FACTOR = 20.0  # a robot process's CPU a period over the step
SHARED_FACTOR = 5.0  # the world's, the router's and the leader's CPU a robot-period, over the step
HEADROOM = 0.8  # the share of the cores a real-time swarm may take and still hold its period
BODIES = 8  # neighbours and obstacles a robot has near in a formation


def step_us(rounds: int = 5, steps: int = 400) -> float:
    """The CPU [us] of the Python part of one robot's real-time step on this machine (the median of rounds)."""
    from swarm.core import fastlaw, law, safety
    from swarm.proto import protocol

    dec = protocol.decoder("state", protocol.Limits.of(64, 1.2))
    enc_state, enc_cmd = protocol.encoder("state"), protocol.encoder("cmd")
    states = [enc_state(j, 1.0, 50, 1.5 * math.cos(j), 1.5 * math.sin(j), 0.1 * j, 0.3, 1.2, False, 0.05, 0.0)
              for j in range(1, BODIES + 1)]
    p = [0.0] * law.P_SIZE
    p[law.P_K1], p[law.P_K2], p[law.P_K3], p[law.P_TU], p[law.P_VT] = 0.5, 0.5, 1.0, 1.0, 0.05
    p[law.P_THRESHOLD], p[law.P_GOVERNOR], p[law.P_DT], p[law.P_SENSE], p[law.P_REACH] = 1.0, 1.0, 0.02, 1.5, 1.2
    mem = [0.0] * law.M_SIZE
    times = []
    for _ in range(rounds):
        c0 = time.thread_time()
        for k in range(steps):
            got = [dec(s, j + 1) for j, s in enumerate(states)]
            nx = [s.x for s in got]
            ny = [s.y for s in got]
            n = len(got)
            v, w = fastlaw.robot_command(0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 1.0, 0.1, 0.0, 0.0, 0.5, 0.0, nx, ny,
                                         [0.3] * n, [1.2] * n, [law.KIND_ROBOT] * n, [0.0] * n, n, mem, p)
            plan = safety.Plan(1.0, 1.0, 1.08, 0.5, 1.1, 0.1)
            plan.limit(0.0, 0.0, 1.0, 0.0, w, [(a, b, 0.3, 0.2) for a, b in zip(nx, ny)], 1.0, 0.9)
            enc_state(0, 1.0, k, 0.0, 0.0, 0.0, 0.3, 1.2, False, plan.reach(abs(v)), 0.0)
            enc_cmd(1.0, k, v, w, 1.08)
        times.append((time.thread_time() - c0) / steps * 1e6)
    times.sort()
    return times[len(times) // 2]


def demand(robots: int, dt: float, speed: float, step: float) -> float:
    """Cores a real-time swarm of `robots` needs at control period dt [s] and `speed`, a step costing `step` us."""
    rate = speed / dt  # control periods a wall second
    return robots * rate * step * 1e-6 * (PROCESS_FACTOR + SHARED_FACTOR)


def verdict(robots: int, dt: float, speed: float, cores: int | None = None, step: float | None = None) -> str | None:
    """None when this machine holds the control period for `robots` at `speed`; else a warning that says how many
    it holds and what happens past that."""
    cores = cores or os.cpu_count() or 1
    step = step_us() if step is None else step
    need = demand(robots, dt, speed, step)
    if need <= HEADROOM * cores:
        return None
    per_robot = need / robots
    holds = max(0, int(HEADROOM * cores / per_robot))
    return (f"this machine ({cores} cores; a robot's step here {step:.0f} us of Python) holds the {dt:g} s control "
            f"period for about {holds} robots at --speed {speed:g}, not {robots}: commands will come late and the "
            f"robots' safety rule will hold them back (slower convergence, never a collision; docs/runtime.md). "
            f"Try fewer robots, a lower --speed, or lock-step")

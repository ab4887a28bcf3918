"""Whether this machine can hold a swarm: its memory and cores before `swarm up` starts N processes, and a
real-time swarm's control period (measured before `swarm up --mode realtime`).

    r = Resources(robots, router=True, viewer=True)  # memory the processes take, against what is available
    r.refusal()  /  r.warning()                      # None, or what to say before anything starts
    waves = Waves(sup.start, plan.robots, timeout_s) # robots started a few cores' worth at a time

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
LAUNCH_WAVE_PER_CORE = 8  # robot processes starting at once a core (swarm up starts the others as these come up)
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
    cores = cores or usable_cores()
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


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS says, else every core)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def launch_wave(cores: int | None = None) -> int:
    """How many robot processes `swarm up` lets start at once: a Python process takes about half a second of CPU
    to start, and 300 started together on 2 cores starved zenoh's threads until the handshakes timed out and the
    leases lapsed. LAUNCH_WAVE_PER_CORE a core (at least 8) keeps start-up as fast and never so."""
    return max(8, LAUNCH_WAVE_PER_CORE * (cores or usable_cores()))


# What one process of `swarm up` takes (`python bench/launch_scale.py --robots 7,100,200` on the 2-core development
# VM, docs/runtime.md): a robot process 13.5-15.7 MiB of its own whatever N, 14.5-15.8 MiB of available memory a
# process all told (17 here: a margin); the router 14 MiB plus 0.25 MiB a robot (its routes), the world 22 plus 0.07
# a robot, the leader and the launcher about 23 each, the viewer (its process and the meshcat server) about 120.
ROBOT_MIB = 17.0
ROUTER_MIB, ROUTER_MIB_PER_ROBOT = 14.0, 0.25
WORLD_MIB, WORLD_MIB_PER_ROBOT = 22.0, 0.07
LEADER_MIB = LAUNCHER_MIB = 23.0
VIEWER_MIB = 120.0
MEMORY_SHARE = 0.8  # of the available memory a swarm may take before a warning (the rest: the OS, its caches)
# Robot processes a core: 100 robots on 2 cores ran lock-step at 0.2x real time, 200 missed commands and overran
# (10 simulated s in 235 s), 300 lost every zenoh session at start (each must answer its 1 s lease)
ROBOTS_PER_CORE = 50


def available_mib() -> float | None:
    """MemAvailable of /proc/meminfo [MiB] (memory a new process can take without swapping); None off Linux."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


class Resources:
    """The memory and cores `robots` robot processes (and the router, world, leader, launcher, viewer where
    started here) take, against what this machine has."""

    def __init__(self, robots: int, router: bool = True, viewer: bool = True, available: float | None = None,
                 cores: int | None = None):
        self.robots = robots
        self.per_robot_mib = ROBOT_MIB + WORLD_MIB_PER_ROBOT + (ROUTER_MIB_PER_ROBOT if router else 0.0)
        self.fixed_mib = WORLD_MIB + LEADER_MIB + LAUNCHER_MIB + (ROUTER_MIB if router else 0.0) + \
            (VIEWER_MIB if viewer else 0.0)
        self.need_mib = self.fixed_mib + robots * self.per_robot_mib
        self.available_mib = available_mib() if available is None else available
        self.cores = cores or usable_cores()

    def text(self) -> str:
        """One line for the dry run."""
        have = "" if self.available_mib is None else f" of {_gib(self.available_mib)} available"
        return (f"resources: {self.robots} robot processes, about {_gib(self.need_mib)} of memory{have}, "
                f"{self.cores} cores ({ROBOTS_PER_CORE} robots a core run well)")

    def refusal(self) -> str | None:
        """Why the swarm cannot start here (more memory than is available: the kernel would kill processes at
        random, each a robot that stops where it is), or None."""
        if self.available_mib is None or self.need_mib <= self.available_mib:
            return None
        fits = int((self.available_mib - self.fixed_mib) / self.per_robot_mib)
        return (f"{self.robots} robot processes need about {_gib(self.need_mib)} of memory ({ROBOT_MIB:g} MiB a robot "
                f"process), and this machine has {_gib(self.available_mib)} available: about {max(fits, 0)} robots "
                f"fit here. Spread the robots over machines (swarm robot --connect, docs/deploy.md) or run the law "
                f"alone with swarm sim, which takes {self.robots} robots in one process")

    def warning(self) -> str | None:
        """What will be slow or tight here (a swarm that still starts), or None."""
        notes = []
        if self.available_mib is not None and MEMORY_SHARE * self.available_mib < self.need_mib <= self.available_mib:
            notes.append(f"it takes about {_gib(self.need_mib)} of the {_gib(self.available_mib)} of memory available")
        if self.robots > ROBOTS_PER_CORE * self.cores:
            notes.append(f"{self.robots} robot processes on {self.cores} cores is more than {ROBOTS_PER_CORE} a core: "
                         "lock-step runs far slower than real time and may miss commands, real time cannot hold its "
                         "period, and past about 150 a core the processes cannot even answer zenoh's lease at start; "
                         "spread the robots over machines or use swarm sim")
        return "; ".join(notes) or None


def _gib(mib: float) -> str:
    return f"{mib / 1024:.1f} GiB" if mib >= 1024 else f"{mib:.0f} MiB"


class Waves:
    """`swarm up`'s start: robot processes started in waves of launch_wave() (the next as earlier ones come
    alive), and a wait that ends timeout_s after the last process came alive, not after the first was started
    (a big swarm takes longer than a minute to start, and a stuck one is still found in timeout_s).

        waves = Waves(sup.start, plan.robots, args.start_timeout)
        while not want <= alive:
            if waves.step(len(alive & want), len(alive & robot_keys)): ...  # True: timed out
    """

    def __init__(self, start, specs, timeout_s: float, wave: int | None = None, clock=time.monotonic):
        self.start, self.waiting, self.timeout_s, self.clock = start, list(specs), timeout_s, clock
        self.total, self.wave = len(self.waiting), launch_wave() if wave is None else wave
        self.seen, self.end = -1, clock() + timeout_s

    def step(self, up: int, robots_up: int) -> bool:
        """Start what the wave allows, given `up` processes and `robots_up` robots alive now; True once timeout_s
        has passed without a new process alive."""
        while self.waiting and self.total - len(self.waiting) - robots_up < self.wave:
            self.start(self.waiting.pop(0))
        if up > self.seen:
            self.seen, self.end = up, self.clock() + self.timeout_s
        return self.clock() > self.end

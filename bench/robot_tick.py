"""One robot's real-time control period, alone: its CPU, and where it goes.

    python bench/robot_tick.py [--robots 37] [--ticks 3000] [--mode realtime|lockstep] [--bus memory|zenoh]
                               [--idle 0.02] [--profile]

The agent of the robot with the most neighbours in the built-in paper-50hz formation (N robots near
their slots around the leader, the formation squeezed by a fifth so that neighbours are within reach)
runs the real-time loop's step on a bus while this script feeds it, every control period, what `swarm up` would: the states of every
robot in its 3x3 cells, the leader's reference and its own pose. The agent's part of each period
(drain and decode its inboxes, the law, encode and publish its state, command and status) is timed
with the thread's CPU clock, as the robot process logs it ("loop CPU ... us a tick", which
bench/up_speed.py reads). --bus zenoh: a router and two client sessions in this process (the feeder's
sends are not timed; zenoh's own threads are not counted, as in a robot process); --bus memory: the
Python part alone. --idle 0.02: sleep between periods as a robot does (its CPU per period then triples:
cold caches). --mode lockstep: a lock-step tick instead, on a memory bus, its messages handed to
the agent's bus callbacks (zenoh's thread runs those in a robot process) and its loop's step, all timed
together. --profile: the same periods under cProfile, the functions by own time.

Prints the mean, median and p90 CPU per period [us] and what the agent heard.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import math
import pstats
import socket
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from agents import robot  # noqa: E402
from swarm.core import fastlaw  # noqa: E402
from swarm.core.clock import FakeClock  # noqa: E402
from swarm.core.runid import robot_config  # noqa: E402
from swarm.core.scenario_file import Overrides, load  # noqa: E402
from swarm.net.bus import MemoryBus, MemoryNet, ZenohBus, zenoh_config  # noqa: E402
from swarm.proto import keys, protocol  # noqa: E402

FLEET = "tick"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


SQUEEZE = 0.8  # the formation's offsets shrunk by this: in its slots (1.5 m apart) no robot is within reach


def formation(scn, t: float):
    """Every robot near its slot at time t, the formation squeezed by SQUEEZE (so each hears its
    neighbours closer than the cell side, as on the way in): (x, y, theta) rows, and the leader's state."""
    xl, yl, thl, vl, wl = scn.leader.state(t)
    return [(xl + SQUEEZE * float(dx), yl + SQUEEZE * float(dy), thl) for dx, dy in scn.offsets], (xl, yl, thl, vl, wl)


def busiest(scn) -> int:
    """The robot with the most others in its 3x3 cells at t = 0 in formation."""
    slots, _ = formation(scn, 0.0)
    cells = [keys.cell_of(x, y, scn.cell_side) for x, y, _ in slots]

    def near(i: int) -> int:
        ci = cells[i]
        return sum(1 for j, c in enumerate(cells) if j != i and abs(c[0] - ci[0]) <= 1 and abs(c[1] - ci[1]) <= 1)

    return max(range(scn.n), key=near)


def lockstep(agent, scn, me: int, others: list[int], ticks: int, prof) -> tuple[list[float], int]:
    """Lock-step ticks: the messages of each tick handed to the agent's bus callbacks as zenoh's thread
    would (its pose, every state in its 3x3 cells, the reference), and its loop's tick_lockstep(); the
    CPU of both (the thread's: this one runs them all), the payloads encoded beforehand."""
    f = FLEET
    agent._on_clock_msg(keys.world_clock(f), protocol.encode(protocol.Clock(t=0.0, seq=0, epoch=0.0, speed=1.0)))
    pose_key, ref_key = keys.robot_pose(f, me), keys.leader_ref(f)
    cpu, heard = [], 0
    for k in range(ticks + 20):
        t = k * scn.dt
        slots, lead = formation(scn, t)
        x, y, th = slots[me]
        states, far = [], []  # in its 3x3 cells; elsewhere (heard only at tick 0, on every cell's key)
        for j in others:
            sx, sy, sth = slots[j]
            near = abs(sx - x) < 1.5 * scn.cell_side and abs(sy - y) < 1.5 * scn.cell_side
            if near or k == 0:
                c = keys.cell_of(sx, sy, scn.cell_side)
                (states if near else far).append((keys.cell(f, c[0], c[1], j), protocol.encode(protocol.State(
                    id=j, t=t, seq=k, x=sx, y=sy, theta=sth, r=scn.r, R=scn.R, frozen=False, stop=0.05, still=0.0))))
        ref = protocol.encode(protocol.Ref(t, k, *lead))
        pose = protocol.encode(protocol.Pose(t=t, seq=k, x=x, y=y, theta=th, cmd=-1.0))
        if prof is not None and k >= 20:
            prof.enable()
        c0 = time.thread_time()
        agent._on_pose_msg(pose_key, pose)
        while agent.tick_lockstep():  # starts tick k: its state goes out
            pass
        agent._on_ref_msg(ref_key, ref)
        for key, data in states:
            agent._on_state_msg(key, data)
        for key, data in far:  # tick 0 waits for every robot's state_0 (agents.lockstep)
            agent._on_any_state_msg(key, data)
        done = agent.k_done
        while agent.tick_lockstep():  # inputs complete: the command goes out
            pass
        c1 = time.thread_time()
        if prof is not None:
            prof.disable()
        if agent.k_done != k or done == k:
            sys.exit(f"tick {k} was not computed once its inputs came (k_done {agent.k_done})")
        if k >= 20:
            cpu.append(1e6 * (c1 - c0))
            heard += agent.neighbours
    return cpu, heard


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--ticks", type=int, default=3000, help="control periods to time (default 3000)")
    ap.add_argument("--mode", choices=("realtime", "lockstep"), default="realtime")
    ap.add_argument("--bus", choices=("memory", "zenoh"), default="zenoh", help="real time (lock-step: memory)")
    ap.add_argument("--idle", type=float, default=0.0, help="real time: wall seconds to sleep before each period, as a robot waits for its next pose (0.02 at "
                         "50 Hz); the default 0 times a hot loop")
    ap.add_argument("--profile", action="store_true", help="cProfile the agent's part, functions by own time")
    a = ap.parse_args()
    if a.robots < 2 or a.ticks < 10:
        ap.error("--robots must be at least 2 and --ticks at least 10")

    scn = load("paper-50hz", Overrides(robots=a.robots))
    me = busiest(scn)
    cfg = robot_config(scn, me, lockstep=a.mode == "lockstep")
    clock = FakeClock()
    router = None
    if a.bus == "memory" or a.mode == "lockstep":
        net = MemoryNet()
        bus, feed = MemoryBus(net), MemoryBus(net)
    else:
        ep = f"tcp/127.0.0.1:{free_port()}"
        router = ZenohBus(zenoh_config("router", listen=[ep]))
        bus = ZenohBus(zenoh_config("client", connect=[ep]))
        feed = ZenohBus(zenoh_config("client", connect=[ep]))
    agent = robot.Agent(bus, cfg, FLEET, clock=clock)
    agent.start([protocol.Obstacle(*map(float, o)) for o in scn.obstacles])
    epoch = clock.time()
    clock_msg = protocol.encode(protocol.Clock(t=0.0, seq=0, epoch=epoch, speed=1.0))
    # the feeder's keys, declared up front (a put on a new key costs a declaration)
    others = [j for j in range(scn.n) if j != me]
    pose_key, ref_key = keys.robot_pose(FLEET, me), keys.leader_ref(FLEET)
    deadline = time.monotonic() + 5.0
    while agent.epoch is None:  # the clock arrives on zenoh's thread (once the subscription reached the router)
        if time.monotonic() > deadline:
            sys.exit("the agent never heard the clock")
        feed.put(keys.world_clock(FLEET), clock_msg)
        time.sleep(0.05)

    cpu: list[float] = []
    heard = 0
    prof = cProfile.Profile() if a.profile else None
    dt = scn.dt
    if a.mode == "lockstep":
        cpu, heard = lockstep(agent, scn, me, others, a.ticks, prof)
    for k in range(a.ticks + 20 if a.mode == "realtime" else 0):
        t = k * dt
        clock.advance(dt)
        slots, lead = formation(scn, t)
        x, y, th = slots[me]
        for j in others:
            sx, sy, sth = slots[j]
            if abs(sx - x) < 1.5 * scn.cell_side and abs(sy - y) < 1.5 * scn.cell_side:
                c = keys.cell_of(sx, sy, scn.cell_side)
                feed.put(keys.cell(FLEET, c[0], c[1], j), protocol.encode(protocol.State(
                    id=j, t=t, seq=k, x=sx, y=sy, theta=sth, r=scn.r, R=scn.R, frozen=False, stop=0.05, still=0.0)))
        feed.put(ref_key, protocol.encode(protocol.Ref(t, k, *lead)))
        feed.put(pose_key, protocol.encode(protocol.Pose(t=t, seq=k, x=x, y=y, theta=th, cmd=-1.0)))
        if a.idle > 0:
            time.sleep(a.idle)  # a robot between poses: its caches go cold (the same work costs 2-3x: docs/performance.md)
        got = agent.drive.wait()  # the pose goes last on the feeder's one link: the rest is in
        if prof is not None and k >= 20:
            prof.enable()
        c0 = time.thread_time()
        agent.take_poses(got)
        agent.drop_clock()
        agent.tick_realtime((clock.time() - epoch))
        c1 = time.thread_time()
        if prof is not None:
            prof.disable()
        if k >= 20:  # the first periods: subscriptions settle, codecs are generated
            cpu.append(1e6 * (c1 - c0))
            heard += agent.neighbours
    agent.close()
    for b in (bus, feed, router):
        if b is not None:
            b.close()
    cpu.sort()
    print(f"robot {me} of {scn.n} (paper-50hz formation), {a.mode}, bus {'memory' if router is None else 'zenoh'}, "
          f"{len(cpu)} periods: "
          f"{heard / len(cpu):.1f} neighbours a period, {agent.bad.count} bad messages; law "
          f"{'compiled' if fastlaw.COMPILED else 'Python'}, message loops {'compiled' if protocol._wire else 'Python'}"
          " (SWARM_PURE_PYTHON=1: both Python)")
    print(f"CPU per period: mean {statistics.fmean(cpu):.0f} us, median {cpu[len(cpu) // 2]:.0f} us, "
          f"p90 {cpu[math.floor(0.9 * len(cpu))]:.0f} us")
    if prof is not None:
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(25)
        print(s.getvalue())


if __name__ == "__main__":
    main()

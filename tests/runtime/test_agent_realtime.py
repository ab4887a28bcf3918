"""The robot agent in real time on the in-memory bus: a tick uses the newest data and advances the reference
(after its listening start), within the speed bound, with a command valid for a while; a base that keeps a
command longer makes the robot's reach longer; the safety rule holds a blocked robot (it stands, turns in
place and promises to stand); the knowledge rule keeps a neighbour it has not heard and bounds one heard in
order; a robot that moves to another cell puts its states in the one it left for a while; and the still
robots the world lists are static bodies. Lock-step: test_agent_lockstep.py."""

from __future__ import annotations

import pytest

from agents import robot
from swarm.proto import keys, protocol
from swarm.core import law, safety
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Pose, Ref, State
from tests.runtime.agent_helpers import CFG, F, Wire, law_command


def _capped(v, om, V):
    """(v, w) scaled together to the speed bound V (the real-time rule keeps the law's path)."""
    f = min(1.0, V / abs(v)) if v else 1.0
    return v * f, om * f


@pytest.mark.unit
def test_real_time_tick_uses_the_newest_data_and_advances_the_reference():
    cfg = protocol.replace(CFG, lockstep=False)
    w = Wire(cfg)
    w.put(keys.leader_ref(F), Ref(t=1.0, seq=50, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    # just started: it listens for LISTEN_PERIODS control periods, commanding 0 (states still on their way)
    for k in range(robot.LISTEN_PERIODS):
        w.put(keys.robot_pose(F, cfg.id), Pose(t=0.94 + 0.02 * k, seq=47 + k, x=-1.0, y=0.0, theta=0.0))
        assert w.agent.tick_realtime(0.94 + 0.02 * k)
        assert (w.cmds[-1].v, w.cmds[-1].w) == (0.0, 0.0)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=1.0, seq=50, x=-1.0, y=0.0, theta=0.0))
    assert w.agent.tick_realtime(1.1)
    # the leader moved 0.05 m along its heading since its last message; the law runs as in lock-step (its
    # governor's horizon the period), then within the speed bound (nothing near holds it back)
    v, om = _capped(*law_command((-1.0, 0.0, 0.0), (0.05, 0.0, 0.0, 0.5, 0.0), 1.1, [], cfg=cfg), cfg.v_bound)
    assert w.cmds[-1].v == pytest.approx(v, abs=1e-15) and w.cmds[-1].w == pytest.approx(om, abs=1e-15)
    assert w.agent.horizon_s == cfg.dt
    # the command is valid from now for at least three periods, and the state says how far it can take the robot
    assert 1.1 + 3 * cfg.dt <= w.cmds[-1].until <= 1.1 + safety.VALIDITY_MAX_S
    plan = safety.Plan(1.0, 1.1, w.cmds[-1].until, 0.0, 1.0)
    assert w.states[-1].stop == pytest.approx(plan.reach(abs(v))) and w.states[-1].still == 0.0
    assert w.cmds[-1].t == 1.0  # the time of the pose it answers


@pytest.mark.unit
def test_a_base_that_keeps_a_command_longer_than_its_validity_makes_the_robot_s_reach_longer():
    """A ROS 2 base with its own cmd_vel timeout (the inventory's cmd_timeout) executes the last command that long
    should the agent die: the robot's reach (its state's `stop`) counts it, its command keeps its validity, and it
    goes no faster (a longer reservation asks more room of robots it has not heard)."""
    from swarm.drives.sim import SimDrive

    class SlowBase(SimDrive):
        base_timeout_s = 0.5

    cfg = protocol.replace(CFG, lockstep=False)
    reach = {}
    for drive_cls in (SimDrive, SlowBase):
        w = Wire(cfg)
        w.agent.close()
        w.agent = robot.Agent(MemoryBus(w.net), cfg, F, drive=drive_cls(MemoryBus(w.net), F, cfg.id))
        w.agent.start([])
        w.agent._first_pose_t = 0.0
        w.put(keys.leader_ref(F), Ref(t=1.0, seq=50, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
        w.put(keys.robot_pose(F, cfg.id), Pose(t=1.0, seq=50, x=-1.0, y=0.0, theta=0.0))
        assert w.agent.tick_realtime(1.0)
        reach[drive_cls.__name__] = (w.states[-1].stop, w.agent.last_cmd.v, w.agent.last_cmd.until)
        w.agent.close()
    (stop0, v0, until0), (stop1, v1, until1) = reach["SimDrive"], reach["SlowBase"]
    assert v0 >= v1 > 0.0 and until0 == until1 < 1.5
    assert stop1 >= v1 * 0.5 > stop0


@pytest.mark.unit
def test_a_real_time_robot_blocked_by_a_neighbour_stands_turns_in_place_and_promises_to_stand():
    """A neighbour 0.9 m ahead whose state is 0.5 s old may be anywhere within V x (that age plus this robot's
    reservation): no forward motion is safe, so the robot stands (turning in place as the law asks), says so in
    its state (`still`, a time ahead) and keeps to it: its next command moves it no more, whatever the law wants,
    until that time."""
    from swarm.core.clock import FakeClock

    cfg = protocol.replace(CFG, lockstep=False)
    clock = FakeClock()
    w = Wire(cfg)
    w.agent.close()
    w.agent = robot.Agent(MemoryBus(w.net), cfg, F, clock=clock)
    w.agent.start([])
    w.agent._first_pose_t = 0.0  # past the listening start
    w.agent.epoch, w.agent.speed = clock.time() - 2.0, 1.0  # the swarm's clock reads 2.0 now
    w.put(keys.leader_ref(F), Ref(t=2.0, seq=100, x=5.0, y=0.5, theta=0.0, v=0.5, w=0.0))
    w.put(keys.cell(F, 0, 0, 8), State(id=8, t=1.5, seq=75, x=0.9, y=0.02, theta=0.0, r=0.3, R=1.2, frozen=False))
    w.put(keys.robot_pose(F, cfg.id), Pose(t=2.0, seq=100, x=0.0, y=0.0, theta=0.0))
    w.agent._take_inboxes()
    assert w.agent.tick_realtime(2.0)
    law_v, law_w = law_command((0.0, 0.0, 0.0), (5.0, 0.5, 0.0, 0.5, 0.0), 2.0,
                               [(0.9, 0.02, 0.3, 1.2, law.KIND_ROBOT)], cfg=cfg)
    assert law_v > 0  # the law drives it at the neighbour
    assert w.cmds[-1].v == 0.0 and w.cmds[-1].w != 0.0  # stands, turns in place
    still = w.states[-1].still
    assert still > 2.0 and w.agent.held == 1
    clock.advance(0.02)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=2.02, seq=101, x=0.0, y=0.0, theta=0.3))
    w.put(keys.cell(F, 0, 0, 8), State(id=8, t=2.02, seq=101, x=3.0, y=3.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    assert w.agent.tick_realtime(2.02)  # the neighbour is gone, but the promise holds
    assert w.cmds[-1].v == 0.0 and w.states[-1].still == still
    clock.advance(still - 2.02 + 0.01)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=still + 0.01, seq=102, x=0.0, y=0.0, theta=0.3))
    assert w.agent.tick_realtime(still + 0.01)
    assert w.cmds[-1].v > 0.0 and w.states[-1].still == 0.0  # past its promise, free to go
    w.agent.close()


@pytest.mark.unit
def test_a_neighbour_not_heard_is_kept_however_old_until_news_puts_it_beyond_the_cells_this_robot_hears():
    """The knowledge rule: not hearing a robot says nothing of where it is (its link may be stalled or its session
    down), so a neighbour whose newest state lies in the block of cells this robot hears is kept however old,
    its motion bound growing with its age (the safety rule holds this robot back); a newer state that puts it
    outside the block (it moved on) takes it as away, until one puts it back; a partition of the run's faults
    that cuts it off keeps it known whatever its state says."""
    from swarm.core.clock import FakeClock
    from swarm.core.faults import Partition

    cfg = protocol.replace(CFG, lockstep=False, v_bound=1.0)
    side = cfg.sense
    for partition in (False, True):
        clock = FakeClock()
        parts = (Partition(groups=((cfg.id,), (7, 8)), start=0.0, end=100.0),) if partition else ()
        agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=clock, partitions=parts)
        agent.start([])
        agent.epoch, agent.speed = clock.time(), 1.0
        for j, x in ((7, 1.3), (8, 0.4)):
            agent.table[j] = State(id=j, t=0.0, seq=1, x=x, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)
            agent.rx[j] = (0.0, clock.monotonic())

        def used(t):
            with agent.lock:
                out = agent._rt_bodies(0.0, 0.0, t, t + 0.2)
            return sorted(x for x, k in zip(out[0], out[4]) if k == law.KIND_ROBOT), sorted(b[0] for b in out[8])

        assert used(0.0) == ([0.4, 1.3], [0.4, 1.3])
        clock.advance(60.0)  # a minute without a word: both kept, each a disk 60 m wide by now
        robots, bounds = used(60.0)
        assert robots == [0.4, 1.3] and bounds == [0.4, 1.3] and agent.forgotten == 0
        with agent.lock:  # 7's state as it left: two cells on, out of the block this robot hears
            agent._take_one(State(id=7, t=60.0, seq=2, x=2.2 * side, y=0.0, theta=0.0, r=0.3, R=1.2,
                                  frozen=False), keys.cell(F, 0, 0, 7))
        robots, bounds = used(60.0)
        assert robots == [0.4] and bounds == ([0.4, 2.2 * side] if partition else [0.4])
        assert agent.forgotten == (0 if partition else 1) and (7 in agent.away) != partition
        with agent.lock:  # and back in
            agent._take_one(State(id=7, t=60.1, seq=3, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False),
                            keys.cell(F, 0, 0, 7))
        assert used(60.1)[0] == [0.4, 1.0] and 7 not in agent.away
        agent.close()


@pytest.mark.unit
def test_a_neighbour_heard_in_order_is_bounded_by_what_it_announced_and_the_gaps_in_this_robots_poses():
    """On links that keep order, a neighbour's command this robot has not heard of began no earlier than the
    newest pose came (both pass the router, the command on to the world), or in a gap of this robot's poses: a
    silent neighbour (its link stalled: so are its commands) may be within its announced stop plus V over the
    time since that pose and over each gap since its state came (plus the longest reservation), however long it
    has been silent. With a fault bus (which drops and delays messages one by one), the speed bound over its age."""
    from swarm.core.clock import FakeClock

    for faulty in (False, True):
        cfg = protocol.replace(CFG, lockstep=False, v_bound=1.0)
        clock = FakeClock()
        agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=clock, counters=object() if faulty else None)
        agent.start([])
        agent.epoch, agent.speed = clock.time(), 1.0
        V, eps = cfg.v_bound, safety.CLOCK_SKEW_S

        def pose(seq, t):
            with agent.lock:
                agent._on_pose(Pose(t=t, seq=seq, x=0.0, y=0.0, theta=0.0), keys.robot_pose(F, cfg.id))

        def bound(t):
            with agent.lock:
                return agent._rt_bodies(0.0, 0.0, t, t + 0.2)[8][0][3]

        pose(1, 0.0)
        clock.advance(0.02)
        pose(2, 0.02)
        agent.table[7] = State(id=7, t=0.02, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False,
                               stop=0.3, still=0.0)
        agent.rx[7] = (0.0, clock.monotonic() + 1e-9)  # it came after pose 2
        for k in range(3, 53):  # a second of poses, each a period on; the neighbour silent
            clock.advance(0.02)
            pose(k, 0.02 * (k - 1))
        t = 0.02 * 51
        live = V * (0.2 + (t - 0.02) + eps)
        assert bound(t) == pytest.approx(live if faulty else 0.3 + V * (0.2 + eps))
        clock.advance(0.06)  # a pose lost: states may have been missed in the 0.06 s since the last one
        pose(54, t + 0.06)
        gap = 0.3 + V * (0.2 + eps + 0.06 + safety.VALIDITY_MAX_S + safety.RAMP_S)
        assert bound(t + 0.06) == pytest.approx(V * (0.2 + (t + 0.06 - 0.02) + eps) if faulty else gap)
        for k in range(55, 105):  # heard again, a second on: it grows no more
            clock.advance(0.02)
            pose(k, t + 0.06 + 0.02 * (k - 54))
        assert bound(t + 1.06) == pytest.approx(V * (0.2 + (t + 1.06 - 0.02) + eps) if faulty else gap)
        agent.close()


@pytest.mark.unit
def test_a_real_time_robot_that_moves_to_another_cell_puts_its_states_in_the_one_it_left_for_a_while():
    """Real time: after a cell change its states go to its new cell and, for DEPART_S, to the cell it left too
    (the first at once, then every DEPART_EVERY-th: each message more makes a lossy link stall more often), so a
    robot that heard it there learns where it went; lock-step puts each state on its own cell only."""
    from swarm.core.clock import FakeClock

    for lockstep in (False, True):
        cfg = protocol.replace(CFG, lockstep=lockstep, v_bound=1.0)
        net = MemoryNet()
        agent = robot.Agent(MemoryBus(net), cfg, F, clock=FakeClock())
        seen = []
        tap = MemoryBus(net)
        tap.subscribe(f"{keys.base(F)}/cell/**", lambda k, d: seen.append(k))
        side = cfg.sense
        every = robot.DEPART_EVERY
        path = [(0.0, 0.5)] + [(0.02 * k, 1.6) for k in range(1, 2 * every + 1)] + [(0.1 + robot.DEPART_S, 1.8)]
        for seq, (t, x) in enumerate(path):
            agent._publish_state(Pose(t=t, seq=seq, x=x, y=0.0, theta=0.0), seq)
        a, b = keys.cell(F, 0, 0, cfg.id), keys.cell(F, 1, 0, cfg.id)
        assert side < 1.6 < 2 * side
        # real time: a copy on a at the change (the 1st state in b), at the 10th and the 20th; none past DEPART_S
        rt = [a, b, a] + [b] * (every - 2) + [b, a] + [b] * (every - 1) + [b, a] + [b]
        assert seen == ([a] + [b] * (2 * every + 1) if lockstep else rt)
        tap.close()
        agent.close()


@pytest.mark.unit
def test_a_real_time_robot_takes_the_still_robots_the_world_lists_as_bodies():
    """Real time: robot 5, standing where this robot never heard it (not in its table), is a static body from the
    world's bodies message, for the law and for the safety rule (static until the listing's t + BODIES_HOLD_S);
    a message older than the last one is refused by its window and changes nothing; an empty one takes it away;
    a list that stopped coming is dropped past its time to live. A dead robot the world lists is where the world
    has it, not where its last state put it; one it has not listed yet keeps its motion bound."""
    from swarm.core.clock import FakeClock
    from swarm.proto.protocol import Bodies, Body

    cfg = protocol.replace(CFG, lockstep=False)
    agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=FakeClock())
    agent.start([])
    agent.epoch, agent.speed = agent.clock.time() - 1.0, 1.0  # now: t = 1.0 on the swarm's clock
    key = keys.world_bodies(F)

    def bodies(t):
        nx, ny, nr, nR, nk, na, robots, stale, safe, _delay = agent._rt_bodies(0.0, 0.0, t, t + 0.1)
        return (nx, ny, nr, nR, nk), robots, safe

    with agent.lock:
        assert bodies(1.0)[0][0] == []
        agent._on_bodies(Bodies(t=1.0, seq=50, bodies=(Body(5, 0.8, 0.1, 0.3, 1.2), Body(cfg.id, 0.0, 0.0, 0.3, 1.2),
                                                        Body(6, 40.0, 0.0, 0.3, 1.2))), key)
        (nx, ny, nr, nR, nk), robots, safe = bodies(1.0)
        # robot 5 as a static body (a dead robot, which the paper's law takes as an obstacle); not itself; not robot 6, out of this robot's cells (the rule has it, far)
        assert (nx, ny, nr, nR, nk) == ([0.8], [0.1], [0.3], [1.2], [law.KIND_DEAD]) and robots == 0
        assert (0.8, 0.1, 0.3, 0.0) in safe and (40.0, 0.0, 0.3, 0.0) in safe
        agent._on_bodies(Bodies(t=0.98, seq=49, bodies=()), key)  # older: refused, nothing changes
        assert bodies(1.0)[0][0] == [0.8] and agent.bad.stale == 1
        agent._on_bodies(Bodies(t=1.02, seq=51, bodies=()), key)  # none still any more
        assert bodies(1.02)[0][0] == []
        # a dead robot: its last state 0.2 m from where the world stopped it; until the world lists it, the law
        # has it there and the rule keeps its motion bound (the speed bound over its age and this reservation:
        # this robot's newest state of it need not be its last); then the world's place wins
        agent.table[5] = State(id=5, t=0.9, seq=45, x=0.6, y=0.1, theta=0.0, r=0.3, R=1.2, frozen=False, stop=0.3,
                               still=0.0)
        agent.dead.add(5)
        assert bodies(1.02)[0][0] == [0.6]
        assert bodies(1.02)[2] == [(0.6, 0.1, 0.3, pytest.approx(cfg.v_bound * (0.1 + safety.CLOCK_SKEW_S)))]
        agent._on_bodies(Bodies(t=1.04, seq=52, bodies=(Body(5, 0.8, 0.1, 0.3, 1.2),)), key)
        assert bodies(1.04)[0][0] == [0.8] and [b[0] for b in bodies(1.04)[2]] == [0.8]
        # listed long enough ago that it may move again: the rule lets it grow
        agent.clock.advance(safety.BODIES_HOLD_S)
        assert bodies(1.04 + safety.BODIES_HOLD_S)[2][0][3] > 0.0
        agent.clock.advance(robot.RT_BODIES_TTL_S)  # a list that stopped coming is dropped
        assert bodies(2.5)[0][0] == [0.6] and agent.rt_static == {}
    agent.close()


@pytest.mark.unit
def test_a_real_time_robot_counts_the_bad_poses_its_drive_refused_with_its_own():
    """In real time the drive takes the poses: one that does not decode is refused and counted by the drive, and
    the robot's count (its statuses', the world's bad_messages, its exit line) adds the drive's to its own."""
    from swarm.drives.sim import SimDrive

    cfg = protocol.replace(CFG, lockstep=False)
    net = MemoryNet()
    agent = robot.Agent(MemoryBus(net), cfg, F, drive=SimDrive(MemoryBus(net), F, cfg.id))
    agent.start([])
    try:
        attacker = MemoryBus(net)
        for _ in range(3):
            attacker.put(keys.robot_pose(F, cfg.id), b"\xc1\xff")
        assert agent.drive.drain() == [] and agent.drive.bad.count == 3  # the robot's loop drains its drive
        assert agent.bad_count() == agent.bad.count + 3
    finally:
        agent.close()


@pytest.mark.unit
def test_a_real_time_robot_takes_the_runs_epoch_only_from_a_clock_that_agrees_with_its_own():
    """The run's epoch is taken once, from the first clock. A forged one far off (10^5 s) would put every true
    pose and reference outside the robot's window for the whole run, and the swarm would stand still: it is
    refused and counted, and the true clock's epoch is taken."""
    from swarm.core.clock import FakeClock
    from swarm.drives.sim import SimDrive

    cfg = protocol.replace(CFG, lockstep=False)
    net = MemoryNet()
    clock = FakeClock()
    agent = robot.Agent(MemoryBus(net), cfg, F, drive=SimDrive(MemoryBus(net), F, cfg.id), clock=clock)
    agent.start([])
    try:
        forger = MemoryBus(net)
        bad = agent.bad.count
        forger.put(keys.world_clock(F), protocol.encode(protocol.Clock(t=0.0, seq=0, epoch=clock.time() + 1e5,
                                                                       speed=1.0)))
        assert agent.epoch is None and agent.bad.count == bad + 1
        forger.put(keys.world_clock(F), protocol.encode(protocol.Clock(t=0.5, seq=25, epoch=clock.time() - 0.5,
                                                                       speed=1.0)))
        assert agent.epoch == clock.time() - 0.5 and agent.bad.count == bad + 1
    finally:
        agent.close()

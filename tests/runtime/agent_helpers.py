"""Shared by the robot agent's tests (tests/runtime/test_agent_lockstep.py, test_agent_realtime.py,
test_agent_compiled.py, test_inline.py): the family and the agent's Config, `Wire` (an agent on a MemoryNet
plus a probe bus that records what it publishes and plays lock-step ticks in the world's order) and
`law_command` (the core law called directly with the agent's inputs, to hold its commands to, bit for bit)."""

from __future__ import annotations

from agents import robot
from swarm.proto import keys, protocol
from swarm.core import law
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Clock, Config, Pose, Ref, State

F = "t"
CFG = Config(id=3, x=0.0, y=0.0, theta=0.0, dx=1.5, dy=-0.5, r=0.3, R=1.2, k1=0.5, k2=0.5, k3=1.0, tu=1.0,
             vt=0.05, threshold=law.THRESHOLD_FROZEN, governor=True, dt=0.02, sense=1.5, reach=1.2,
             lockstep=True, robots=16)


class Wire:
    """An agent on a MemoryNet plus a probe bus that records what it publishes."""

    def __init__(self, cfg=CFG, obstacles=(), ahead=False):
        self.net = MemoryNet()
        self.agent = robot.Agent(MemoryBus(self.net), cfg, F, wait_timeout=60.0, ahead=ahead)
        self.agent.start([protocol.Obstacle(*o) for o in obstacles])
        self.probe = MemoryBus(self.net)
        self.cmds: list[protocol.Cmd] = []
        self.states: list[protocol.State] = []
        self.statuses: list[protocol.Status] = []
        self.probe.subscribe(keys.robot_cmd(F, cfg.id), lambda k, b: self.cmds.append(protocol.decode(b, "cmd")))
        self.probe.subscribe(f"swarm/{F}/cell/*/*/{cfg.id}", lambda k, b: self.states.append(protocol.decode(b, "state")))
        self.probe.subscribe(keys.robot_status(F, cfg.id),
                             lambda k, b: self.statuses.append(protocol.decode(b, "status")))

    def put(self, key, msg):
        self.probe.put(key, protocol.encode(msg))

    def rebus(self, bus_class):
        """The agent again, started on a bus of bus_class (a MemoryBus that records something) on the same net;
        returns that bus."""
        self.agent.close()
        bus = bus_class(self.net)
        self.agent = robot.Agent(bus, self.agent.cfg, F, wait_timeout=60.0)
        self.agent.start([])
        return bus

    def far_states(self, k, but=()):
        """state_k of every robot of the run but this one and `but`, far away (far_states below)."""
        for key, data in far_states(k, self.agent.cfg, but):
            self.probe.put(key, data)

    def tick(self, k, pose, ref, neighbours=()):
        """One lock-step tick in the world's order: ref (a tick ahead), pose, the neighbours'
        states, and at k = 0 the clock (the world's start barrier)."""
        t = k * CFG.dt
        self.put(keys.leader_ref(F), Ref(t=t, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
        self.put(keys.robot_pose(F, CFG.id), Pose(t=t, seq=k, x=pose[0], y=pose[1], theta=pose[2]))
        acted = self.agent.tick_lockstep()  # starts the tick: publishes its state, decides whom to wait for
        for j, (x, y, th) in neighbours:
            cx, cy = keys.cell_of(x, y, CFG.sense)
            self.put(keys.cell(F, cx, cy, j), State(id=j, t=t, seq=k, x=x, y=y, theta=th, r=0.3, R=1.2, frozen=False))
        if k == 0:  # every other robot of the run says where it starts (far away): tick 0 waits for them all
            self.far_states(k, {j for j, _ in neighbours})
            assert not acted, "tick 0 must wait for the start barrier"
            self.put(keys.world_clock(F), Clock(t=t, seq=k, epoch=0.0, speed=1.0))
        return acted or self.agent.tick_lockstep()


def far_states(k, cfg=CFG, but=()):
    """(key, payload) of state_k of every robot of cfg's run but cfg's own and `but`, each far from everyone
    (out of reach): what the rest of a run says at tick 0, which a robot waits for."""
    out = []
    for j in range(cfg.robots):
        if j != cfg.id and j not in but:
            x = 1000.0 + 10.0 * j
            cx, cy = keys.cell_of(x, 0.0, cfg.sense)
            out.append((keys.cell(F, cx, cy, j), protocol.encode(State(
                id=j, t=k * cfg.dt, seq=k, x=x, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))))
    return out


def law_command(pose, ref, t, bodies, mem=None, cfg=CFG, horizon=None, obstacle_r=0.0):
    """The core law called directly with the same inputs (horizon: the governor's, default dt)."""
    mem = mem if mem is not None else [0.0] * law.M_SIZE
    p = [0.0] * law.P_SIZE
    p[law.P_K1], p[law.P_K2], p[law.P_K3], p[law.P_TU], p[law.P_VT] = cfg.k1, cfg.k2, cfg.k3, cfg.tu, cfg.vt
    p[law.P_THRESHOLD], p[law.P_GOVERNOR], p[law.P_SENSE], p[law.P_REACH] = cfg.threshold, 1.0, cfg.sense, cfg.reach
    p[law.P_OBSTACLE_R] = obstacle_r
    p[law.P_DT] = cfg.dt if horizon is None else horizon
    nx, ny, nr, nR, nk = ([b[i] for b in bodies] for i in range(5))
    return law.robot_command(pose[0], pose[1], pose[2], cfg.dx, cfg.dy, cfg.r, t, *ref, nx, ny, nr, nR, nk,
                             [0.0] * len(bodies), len(bodies), mem, p)

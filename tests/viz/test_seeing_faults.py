"""Seeing faults without a browser: the fault marks from events (swarm.view.faultmarks), the robots' states
and rings in the viewer and their counts in the overlay, a live watcher fed with world/events, `swarm sim
--viz` under faults, and the status line and summary of `swarm up` and `swarm sim`.
The browser side is in test_browser.py."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.cli import console
from swarm.core import faults as fl
from swarm.core import scenario_file
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Event, Progress, Status
from swarm.view import viz
from swarm.view.faultmarks import FaultMarks, robot_list
from swarm.view.meshcat_objects import CommandLog
from swarm.view.viz import DEAD, FROZEN, HUD, HUNG, STALE, STOPPED, TRACKING, SceneInfo, Viewer, state_codes
from swarm.view.watch import SwarmWatcher, play_simulation
from tests.viz.test_overlay import Clock, hud_texts
from tests.viz.test_viz_unit import FLEET, snapshot

pytestmark = pytest.mark.unit

# --------------------------------------------------------------------------- the marks from events


def test_fault_events_mark_robots_dead_hung_and_cut_off_until_they_end():
    m = FaultMarks(6)
    assert m.apply(1.0, "kill", (5,)) and m.apply(2.0, "hang", (1,)) and m.apply(3.0, "partition", (3, 4, 5))
    assert (m.killed.tolist(), m.hung.tolist(), m.cut.tolist()) == (
        [0, 0, 0, 0, 0, 1], [0, 1, 0, 0, 0, 0], [0, 0, 0, 1, 1, 1])
    assert not m.apply(3.0, "partition", (3, 4, 5))  # told twice (the bus and the schedule): once
    assert not m.apply(2.5, "signal", (1,))  # what the supervisor did: the scheduled event says it
    assert not m.apply(4.0, "kill", (6,)) and m.ignored == 1  # no such robot: nothing changes
    assert m.apply(5.0, "resume", (1,)) and m.apply(6.0, "partition_end", (3, 4, 5)) and m.apply(7.0, "restart", (5,))
    assert not m.any
    m.apply(8.0, "kill", (0,))
    m.reset()
    assert not m.any and m.apply(1.0, "kill", (5,))  # a new run: the same event is new again


def test_a_schedule_advances_with_time_and_starts_over_when_time_goes_back():
    faults = fl.Faults(kills=(fl.Kill(robot=1, at=0.5, restart=1.0),), hangs=(fl.Hang(robot=2, at=0.2, duration=0.5),),
                       partitions=(fl.Partition(groups=((0,),), start=1.0, end=2.0),))
    m = FaultMarks(3, fl.timeline(faults, 3))
    seen = []
    for t in (0.0, 0.2, 0.5, 0.7, 1.0, 1.5, 2.0, 0.5):
        m.advance(t)
        seen.append((t, m.killed.tolist(), m.hung.tolist(), m.cut.tolist()))
    for t, killed, hung, cut in seen:  # the schedule's own queries, at every time asked
        assert killed == [fl.process_state(faults, i, t) == "dead" for i in range(3)], t
        assert hung == [fl.process_state(faults, i, t) == "hung" for i in range(3)], t
        assert cut == [fl.partition_group(faults, i, t) != 0 for i in range(3)], t
    assert seen[4][3] == [False, True, True]  # robots 1 and 2: the group the lists leave out


def test_robot_lists_are_short():
    assert robot_list([]) == "–"
    assert robot_list([7]) == "7"
    assert robot_list([3, 0, 1, 2, 5, 8, 9]) == "0-3, 5, 8, 9"
    assert robot_list(range(12, 37, 1)) == "12-36"


# --------------------------------------------------------------------------- states, rings, counts


@pytest.mark.parametrize("alive, stopped, hung, killed, code", [
    (True, False, True, False, HUNG),
    (False, True, True, False, HUNG),  # a hung process past its lease loses its token: still hung
    (True, True, False, False, STOPPED),
    (True, False, True, True, DEAD),  # killed: dead whatever the snapshot still says
    (True, False, False, True, DEAD),
    (False, False, False, False, DEAD),
])
def test_hung_and_killed_robots_get_their_state(alive, stopped, hung, killed, code):
    got = state_codes(np.array([alive]), np.array([stopped]), np.array([True]), np.array([0.0]),
                      hung=np.array([hung]), killed=np.array([killed]))
    assert got.tolist() == [code]


def _rings(sink: CommandLog) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rings of the last frame: positions (K, 2), scales (K,), colours (K, 3) 0..255."""
    obj = sink.last[f"{viz.ROOT}/marks"]["object"]["object"]
    m = np.frombuffer(obj["instanceMatrix"]["array"].data, np.float32).reshape(-1, 16)
    colours = np.frombuffer(obj["instanceColor"]["array"].data, np.float32).reshape(-1, 3)
    return m[:, 12:14], np.hypot(m[:, 0], m[:, 1]), np.rint(colours * 255)


def test_rings_mark_the_robots_cut_off_and_on_stale_data_and_the_overlay_counts_them():
    sink, clock = CommandLog(), Clock()
    viewer = Viewer(sink, SceneInfo(r=0.3, R=1.2, name="faults"), clock=clock)
    q = np.c_[np.arange(5.0) * 2, np.zeros(5), np.zeros(5)]
    codes = np.array([TRACKING, HUNG, DEAD, STOPPED, FROZEN])
    viewer.set_marks(cut=[False, True, True, True, False], stale_data=[True, False, False, True, False])
    viewer.draw(1.0, q, codes)
    pos, scale, colour = _rings(sink)
    red = np.rint(np.array(viz.rgb(viz.CUT_COLOR)) * 255)
    yellow = np.rint(np.array(viz.rgb(viz.STALE_DATA_COLOR)) * 255)
    # robot 2 is dead: no ring; robots 1 and 3 cut off (red, outer), robots 0 and 3 on stale data (yellow, inner)
    got = sorted((float(p[0]), round(float(s), 4), tuple(c)) for p, s, c in zip(pos, scale, colour))
    assert got == sorted([(2.0, 0.285, tuple(red)), (6.0, 0.285, tuple(red)), (0.0, 0.21, tuple(yellow)),
                          (6.0, 0.21, tuple(yellow))])
    colours = np.frombuffer(sink.last[f"{viz.ROOT}/robots"]["object"]["object"]["instanceColor"]["array"].data,
                            np.float32).reshape(5, 3)
    np.testing.assert_array_equal(colours, viz.PALETTE[codes])  # hung magenta, dead black, stopped purple
    texts = hud_texts(sink)
    assert (texts["dead_hung"], texts["stopped_cut"], texts["stale_data"], texts["alive"]) == (
        "dead 1  hung 1", "stopped 1  cut off 2", "stale data 2", "alive 4 of 5")
    panel = sink.last[f"{HUD}/panel"]["object"]["geometries"][0]
    corners = np.frombuffer(panel["data"]["attributes"]["position"]["array"].data, np.float32).reshape(-1, 3)
    height = np.ptp(corners[:, 1])
    assert height == pytest.approx(0.15 + viz.HUD_ROW_H)  # the panel grew a line for the faults
    # next frame without marks (set_marks holds for one frame): the rings go, once; the counts stay, at 0
    start = len(sink.commands)
    clock.now += 1.0
    viewer.draw(1.1, q, np.zeros(5, int))
    viewer.draw(1.2, q, np.zeros(5, int))
    assert [c[:2] for c in sink.commands[start:] if c[1] == f"{viz.ROOT}/marks"] == [("delete", f"{viz.ROOT}/marks")]
    texts = hud_texts(sink)
    assert (texts["dead_hung"], texts["stopped_cut"], texts["stale_data"]) == (
        "dead 0  hung 0", "stopped 0  cut off 0", "stale data –")  # (stale data not given: not known)
    with pytest.raises(ValueError, match="3 cut marks"):
        viewer.set_marks(cut=[True, False, True])
        viewer.draw(1.3, q, np.zeros(5, int))


def test_a_run_without_faults_has_no_fault_line_and_no_rings():
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo(name="clean"), clock=Clock())
    q = np.c_[np.arange(3.0) * 2, np.zeros(3), np.zeros(3)]
    viewer.set_marks(cut=np.zeros(3, bool), stale_data=np.zeros(3, bool))
    viewer.draw(0.0, q, np.array([TRACKING, STOPPED, STALE]))  # stopped at the start: no fault
    assert set(hud_texts(sink)) == {"name", "t", "min_distance", "alive", "converged", "frozen"}
    assert f"{viz.ROOT}/marks" not in {path for kind, path, _ in sink.commands if kind == "set_object"}
    # a scene with scheduled faults shows the line from the start
    sink2 = CommandLog()
    scene = SceneInfo(name="faults", timeline=((5.0, "kill", (1,), ""),))
    Viewer(sink2, scene, clock=Clock()).draw(0.0, q, np.zeros(3, int))
    assert hud_texts(sink2)["dead_hung"] == "dead 0  hung 0"


def test_the_legend_shows_the_fault_states_and_rings():
    sink = CommandLog()
    Viewer(sink, SceneInfo())
    labels = {path.split("/")[-2]: data["object"]["object"]["userData"]["text"] for path, data in sink.last.items()
              if path.startswith(f"{HUD}/legend/") and path.endswith("/label")}
    assert (labels["hung"], labels["dead"], labels["cut"], labels["stale_data"], labels["stale"]) == (
        "hung", "dead", "cut off", "stale neighbour data", "no recent status")
    ring = sink.last[f"{HUD}/legend/cut/swatch"]["object"]
    assert ring["materials"][0]["color"] == viz.CUT_COLOR
    xy = np.frombuffer(ring["geometries"][0]["data"]["attributes"]["position"]["array"].data, np.float32).reshape(-1, 3)
    assert np.hypot(xy[:, 0], xy[:, 1]).min() > 0.005  # a ring, like the one in the scene, not a square


# --------------------------------------------------------------------------- a live watcher


class MarkingViewer:
    """A viewer that keeps each frame's codes and rings."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, list, list, list | None]] = []
        self._marks = (None, None)

    def set_scene(self, scene) -> None:
        pass

    def set_marks(self, cut=None, stale_data=None) -> None:
        self._marks = (cut, stale_data)

    def draw(self, t, q, codes, leader=None, stats=None) -> None:
        cut, stale = self._marks
        self.frames.append((round(t, 6), np.asarray(codes).tolist(), np.asarray(cut).tolist(),
                            None if stale is None else np.asarray(stale).tolist()))
        self._marks = (None, None)

    def refresh_overlay(self) -> None:
        pass


def _event(t: float, name: str, robots: tuple[int, ...]) -> bytes:
    return protocol.encode(Event(t=t, seq=int(round(t / 0.02)), event=name, robots=robots, detail=""))


def _status(stale: int, t: float = 0.0) -> bytes:
    return protocol.encode(Status(t=t, ex=0.0, ey=0.0, etheta=0.0, frozen=False, neighbours=3, stale=stale, bad=0))


def test_a_live_watcher_colours_and_rings_robots_from_the_worlds_fault_events():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = MarkingViewer()
    clock = Clock()
    w = SwarmWatcher(MemoryBus(net), FLEET, viewer, scene=SceneInfo(), wall=clock)
    w.start(draw_thread=False)
    try:
        for i in range(4):
            pub.put(keys.robot_status(FLEET, i), _status(stale=2 if i == 3 else 0))
        pub.put(keys.world_snapshot(FLEET), snapshot(0, n=4))
        assert w.step()
        assert viewer.frames[-1] == (0.0, [TRACKING] * 4, [False] * 4, [False, False, False, True])
        pub.put(keys.world_events(FLEET), _event(0.02, "hang", (1,)))
        pub.put(keys.world_events(FLEET), _event(0.02, "kill", (2,)))
        pub.put(keys.world_events(FLEET), _event(0.02, "partition", (1, 3)))
        pub.put(keys.world_events(FLEET), _event(0.02, "signal", (2,)))  # swarm up's SIGKILL: nothing more
        pub.put(keys.world_events(FLEET), b"\x93junk")
        pub.put(keys.world_events(FLEET), _event(0.02, "hang", (9,)))  # no such robot
        # robot 1's token lapsed while hung: hung, not dead; robot 2 killed: dead though still alive here
        pub.put(keys.world_snapshot(FLEET), snapshot(1, n=4, alive=[True, False, True, True]))
        assert w.step()
        assert viewer.frames[-1] == (0.02, [TRACKING, HUNG, DEAD, TRACKING], [False, True, False, True],
                                     [False, False, False, True])
        assert w.events == 3 and w.bad.count == 2
        clock.now += 2.0  # robot 3's status is 2 s old: its stale count says nothing any more
        for i in (0, 1, 2):
            pub.put(keys.robot_status(FLEET, i), _status(0))
        pub.put(keys.world_events(FLEET), _event(0.04, "resume", (1,)))
        pub.put(keys.world_events(FLEET), _event(0.04, "partition_end", (1, 3)))
        pub.put(keys.world_snapshot(FLEET), snapshot(2, n=4))
        assert w.step()
        assert viewer.frames[-1] == (0.04, [TRACKING, TRACKING, DEAD, STALE], [False] * 4, [False] * 4)
        assert not w.step()  # nothing new: no frame
        pub.put(keys.world_events(FLEET), _event(0.06, "partition", (0,)))  # a mark alone is news
        assert w.step() and viewer.frames[-1][2] == [True, False, False, False]
        pub.put(keys.world_snapshot(FLEET), snapshot(0, n=4))  # a new run: the marks start over
        assert w.step() and viewer.frames[-1][1][2] == TRACKING and not any(viewer.frames[-1][2])
    finally:
        w.close()


class StatsViewer(MarkingViewer):
    """A MarkingViewer that keeps each frame's overlay stats too."""

    def __init__(self) -> None:
        super().__init__()
        self.stats: list = []

    def draw(self, t, q, codes, leader=None, stats=None) -> None:
        super().draw(t, q, codes, leader, stats)
        self.stats.append(stats)


def test_the_viewer_shows_the_emergency_stop_with_its_reason_while_it_is_engaged():
    """The world's estop event puts "E-STOP: reason" in the overlay's first cell (a frame of its own: it is
    news even when no robot changed), its release takes it away; the scene's name is back."""
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = StatsViewer()
    w = SwarmWatcher(MemoryBus(net), FLEET, viewer, scene=SceneInfo(name="paper-50hz"), wall=Clock())
    w.start(draw_thread=False)
    try:
        pub.put(keys.world_snapshot(FLEET), snapshot(0, n=3))
        assert w.step() and viewer.stats[-1] is None
        pub.put(keys.world_events(FLEET), protocol.encode(Event(t=0.02, seq=1, event="estop", robots=(),
                                                                detail="operator: person in the arena")))
        assert w.step() and viewer.stats[-1].estop == "operator: person in the arena"
        view = Viewer(CommandLog(), SceneInfo(name="paper-50hz"), clock=Clock())
        q = np.zeros((3, 3))
        assert view.overlay_texts(0.0, q, np.zeros(3, int), None, viewer.stats[-1])["name"] == \
            "E-STOP: operator: person in the arena"
        assert not w.step()  # nothing new
        pub.put(keys.world_events(FLEET), protocol.encode(Event(t=0.04, seq=2, event="estop_release", robots=(),
                                                                detail="")))
        assert w.step() and viewer.stats[-1] is None
        assert view.overlay_texts(0.0, q, np.zeros(3, int), None, viewer.stats[-1])["name"] == "paper-50hz"
        assert w.bad.count == 0
    finally:
        w.close()


def test_a_watcher_that_joins_late_starts_from_the_scenarios_schedule():
    """Given the scenario (as `swarm up` gives its viewer), a watcher whose first snapshot is at 1 s knows
    the kill at 0.5 s it never heard; the same event heard later counts once."""
    faults = fl.Faults(kills=(fl.Kill(robot=2, at=0.5),), hangs=(fl.Hang(robot=0, at=2.0, duration=1.0),))
    scene = SceneInfo(timeline=tuple(fl.timeline(faults, 3)))
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = MarkingViewer()
    w = SwarmWatcher(MemoryBus(net), FLEET, viewer, scene=scene, wall=Clock())
    w.start(draw_thread=False)
    try:
        pub.put(keys.world_snapshot(FLEET), snapshot(50))  # t = 1 s
        assert w.step() and viewer.frames[-1][1] == [TRACKING, TRACKING, DEAD]
        pub.put(keys.world_events(FLEET), _event(0.5, "kill", (2,)))
        pub.put(keys.world_snapshot(FLEET), snapshot(51))
        assert w.step() and w.events == 0 and viewer.frames[-1][1][2] == DEAD
        pub.put(keys.world_snapshot(FLEET), snapshot(120))  # the hang at 2 s: from the bus only, live
        assert w.step() and viewer.frames[-1][1][0] == TRACKING
    finally:
        w.close()


# --------------------------------------------------------------------------- swarm sim --viz


def test_the_simulator_in_the_viewer_shows_its_faults(tmp_path):
    """A hang, a kill and a partition in `swarm sim --viz`'s loop: each frame's states and rings follow the
    schedule at its time. Robots on stale neighbour data come from the simulator's state, step by step:
    half the states are lost, so some robot's law takes an old one; never a dead or hung robot."""
    from swarm.core.sim import Simulation
    from swarm.view.watch import sim_fault_flags

    (tmp_path / "f.toml").write_text("[faults]\n[[faults.hang]]\nrobot = 1\nat = 0.2\nduration = 0.4\n"
                                     "[[faults.partition]]\ngroups = [[0, 1, 2]]\nstart = 0.4\nend = 0.8\n"
                                     "[[faults.drop]]\nclass = \"state\"\np = 0.5\n")
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(
        robots=7, duration=1.2, faults=str(tmp_path / "f.toml"), kill="6@0.3"))
    viewer = MarkingViewer()
    assert play_simulation(Simulation(scn), viewer, speed=3.0) is False  # 0.4 s of wall time
    assert len(viewer.frames) >= 3 and viewer.frames[-1][0] == pytest.approx(1.2)
    f = scn.faults
    for t, codes, cut, stale in viewer.frames:
        assert [c == HUNG for c in codes] == [fl.process_state(f, i, t) == "hung" for i in range(7)], t
        assert [c == DEAD for c in codes] == [fl.process_state(f, i, t) == "dead" for i in range(7)], t
        assert cut == [fl.partition_group(f, i, t) != 0 for i in range(7)], t
        assert stale is not None and not any(s and c in (DEAD, HUNG) for s, c in zip(stale, codes))
    sim = Simulation(scn)
    seen = 0
    for k in range(scn.steps + 1):
        sim.advance(k + 1)
        stopped, stale = sim_fault_flags(sim)
        assert stopped.tolist() == sim.faults.stopped.tolist()
        busy = [fl.process_state(f, i, k * scn.dt) == "alive" for i in range(7)]
        assert not any(s and not b for s, b in zip(stale, busy)), k
        seen += int(stale.any())
    assert seen >= 3
    clean = Simulation(scenario_file.load("paper-50hz", scenario_file.Overrides(robots=3, duration=0.1)))
    clean.advance(3)
    assert [a.tolist() for a in sim_fault_flags(clean)] == [[False] * 3] * 2  # no faults: every state current


# --------------------------------------------------------------------------- the status line and the summary


def _progress(**kw) -> Progress:
    base = dict(t=12.5, seq=625, duration=120.0, robots=37, alive=37, converged=30, frozen=2, min_distance=0.812,
                misses=0, bad=0)
    return Progress(**{**base, **kw})


def test_the_status_line_shows_dropped_messages_and_dead_and_hung_robots_only_when_there_are_some():
    clean = console.progress_line(_progress())
    assert "dropped" not in clean and "dead" not in clean and "hung" not in clean
    line = console.progress_line(_progress(alive=36, dropped=6789, hung=1))
    assert "alive 36/37  dropped 6789  dead 1  hung 1  converged 30" in line
    assert "hung" not in console.progress_line(_progress(dropped=5)) and "dropped 5  converged" in \
        console.progress_line(_progress(dropped=5))
    assert console.fault_fields() == "" and console.fault_fields(0, 2, 0) == "  dead 2"


def test_the_summary_lists_the_fault_counters_of_a_run_with_faults():
    m = {"robots": 37, "obstacles": 0, "seed": 0, "dt": 0.02, "governor": True, "duration_s": 120.0,
         "interrupted": False, "converged_at_s": 50.0, "final_position_error_max_m": 0.0,
         "final_orientation_error_max_rad": 0.0, "min_robot_distance_m": 0.5, "min_obstacle_distance_m": 0.5,
         "collisions": 0, "last_freeze_end_s": 20.0, "wall_s": 3.0, "messages_dropped": 0, "cmd_misses": 0,
         "bad_messages": 0, "robots_alive_at_end": 37}
    clean = console.summary(m, "paper-50hz")
    assert "faults" not in clean and "dropped" not in clean
    faulty = {**m, "messages_dropped": 6789, "robots_alive_at_end": 36, "faults": {
        "dropped": {"state": 6000, "pose": 0, "cmd": 289, "ref": 500}, "delayed": {"state": 0, "pose": 0, "cmd": 0,
                                                                                "ref": 0},
        "killed": 1, "restarted": 0, "hung": 2, "partitions": 1, "cmd_held": 12, "watchdog_stops": 1,
        "max_state_age_s": 0.42}}
    rows = {line.split("  ")[1].strip(): line.split("  ", 2)[2].strip() for line in
            console.summary(faulty, "paper-50hz").splitlines()[1:]}
    assert rows["faults"] == "killed 1, restarted 0, hung 2, partitions 1"
    assert rows["messages dropped"] == "6789 (state 6000, cmd 289, ref 500)"
    assert rows["world"] == "commands held 12, watchdog stops 1"
    assert rows["oldest state used"] == "0.42 s"
    assert rows["robots alive"] == "36 of 37 at the end"
    assert "messages delayed" not in rows


def test_the_summary_says_when_the_real_time_world_fell_behind():
    m = {"robots": 7, "obstacles": 0, "seed": 0, "dt": 0.02, "governor": True, "duration_s": 20.0,
         "interrupted": False, "converged_at_s": None, "final_position_error_max_m": 0.1,
         "final_orientation_error_max_rad": 0.1, "min_robot_distance_m": 0.5, "min_obstacle_distance_m": None,
         "collisions": 0, "last_freeze_end_s": None, "wall_s": 11.0, "messages_dropped": 0, "cmd_misses": 0,
         "bad_messages": 0, "samples": 937, "samples_missed": 64}
    assert "world behind" not in console.summary({**m, "samples_missed": 0}, "paper-50hz")
    assert "64 control periods not sampled (of 1001)" in console.summary(m, "paper-50hz")

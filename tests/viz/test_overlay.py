"""The viewer's overlay without a browser: the legend of every colour, the counts of a frame (given,
or worked out from the frame), their pacing, and where they come from (world/progress, the simulator).
The browser side is in test_browser.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Progress
from swarm.view import viz
from swarm.view.meshcat_objects import CommandLog
from swarm.view.viz import DEAD, FROZEN, HUD, LEGEND, STOPPED, TRACKING, SceneInfo, Stats, Viewer
from swarm.view.watch import SwarmWatcher, play_simulation
from tests.viz.test_viz_unit import FLEET, FakeViewer, snapshot

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 50.0

    def __call__(self) -> float:
        return self.now


def hud_texts(sink: CommandLog) -> dict[str, str]:
    """The overlay's top lines as last sent: cell -> text."""
    out = {}
    for path, data in sink.last.items():
        if path.startswith(HUD + "/") and path.count("/") == HUD.count("/") + 1 and data["type"] == "set_object":
            obj = data["object"]["object"]
            if "userData" in obj:
                out[path.rsplit("/", 1)[1]] = obj["userData"]["text"]
    return out


def sent_hud(sink: CommandLog, since: int) -> list[str]:
    return [path for kind, path, _ in sink.commands[since:] if kind == "set_object" and path.startswith(HUD + "/")
            and "/legend" not in path and not path.endswith("/panel")]


def test_the_legend_names_every_colour_the_viewer_uses():
    sink = CommandLog()
    Viewer(sink, SceneInfo(name="demo"))
    labels, swatches = {}, {}
    for path, data in sink.last.items():
        if path.startswith(f"{HUD}/legend/") and data["type"] == "set_object":
            entry, part = path.split("/")[-2:]
            obj = data["object"]
            if part == "label":
                labels[entry] = obj["object"]["userData"]["text"]
                assert obj["textures"][0]["type"] == "_text" and obj["textures"][0]["text"] == labels[entry]
                assert obj["materials"][0]["map"] == obj["textures"][0]["uuid"]
            elif part == "swatch":
                swatches[entry] = obj["materials"][0]["color"]
    assert list(labels.values()) == [text for _, text, _, _ in LEGEND]
    assert labels["tracking"] == "tracking" and labels["stopped"] == "stopped (watchdog)"
    # one swatch per colour in the scene, each exactly the colour drawn
    assert [swatches[k] for k in viz.STATE_NAMES] == list(viz.STATE_COLORS)
    assert (swatches["leader"], swatches["obstacle"], swatches["zone"]) == (viz.GHOST_COLOR, viz.OBSTACLE_COLOR,
                                                                          viz.ZONE_COLOR)
    assert (swatches["cut"], swatches["stale_data"]) == (viz.CUT_COLOR, viz.STALE_DATA_COLOR)  # the rings'
    assert len(set(swatches.values())) == len(swatches) == len(LEGEND)  # every colour its own
    # every overlay object is drawn over the scene, under the camera (it stays put on the screen)
    for path, data in sink.last.items():
        if path.startswith(HUD) and data["type"] == "set_object":
            assert data["object"]["materials"][0]["depthTest"] is False
            assert data["object"]["object"]["matrix"][14] == -viz.HUD_DEPTH


def test_the_counts_given_with_a_frame_are_shown():
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo(name="paper-50hz"), clock=Clock())
    viewer.draw(12.345, np.zeros((37, 3)) + np.arange(37)[:, None], np.zeros(37, int), (0.0, 0.0, 0.0),
                stats=Stats(alive=36, converged=30, frozen=2, min_distance=0.8123))
    assert hud_texts(sink) == {"name": "paper-50hz", "t": "t = 12.35 s", "min_distance": "min distance 0.812 m",
                               "alive": "alive 36 of 37", "converged": "converged 30 of 37", "frozen": "frozen 2"}


def test_the_counts_a_frame_does_not_bring_are_worked_out_from_it():
    """Three robots: one dead, one frozen, one in its slot facing the leader's way; no Stats."""
    offsets = np.array([[0.0, 0.0], [1.5, 0.0], [0.0, 1.5]])
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo(offsets=offsets), clock=Clock())
    leader = (2.0, 1.0, 0.3)
    q = np.array([[2.0 + 0.01, 1.0, 0.3 + 2 * math.pi], [5.0, 1.0, 0.0], [5.0, 3.0, 0.0]])
    viewer.draw(1.0, q, np.array([TRACKING, FROZEN, DEAD]), leader)
    texts = hud_texts(sink)
    assert texts["name"] == "swarm"  # a scene without a name
    assert texts["alive"] == "alive 2 of 3" and texts["frozen"] == "frozen 1"
    assert texts["converged"] == "converged 1 of 3"  # 0.01 m away, heading equal modulo 2 pi
    # the closest live pair: robots 0 and 1, 2.99 m (robot 2 is dead, 2.0 m from robot 1)
    assert texts["min_distance"] == "min distance 2.990 m"
    # without slots nothing says what converged means
    sink2 = CommandLog()
    Viewer(sink2, SceneInfo(), clock=Clock()).draw(1.0, q, np.zeros(3, int), leader)
    assert hud_texts(sink2)["converged"] == "converged –"


def test_the_smallest_distance_is_a_running_minimum_reset_by_a_new_run():
    sink, clock = CommandLog(), Clock()
    viewer = Viewer(sink, SceneInfo(), clock=clock)
    for t, gap in ((0.0, 3.0), (1.0, 1.25), (2.0, 4.0)):
        clock.now += 1.0
        viewer.draw(t, np.array([[0.0, 0.0, 0.0], [gap, 0.0, 0.0]]), np.zeros(2, int))
    assert hud_texts(sink)["min_distance"] == "min distance 1.250 m"
    clock.now += 1.0
    viewer.draw(0.5, np.array([[0.0, 0.0, 0.0], [2.5, 0.0, 0.0]]), np.zeros(2, int))  # time went back
    assert hud_texts(sink)["min_distance"] == "min distance 2.500 m"


def test_the_overlay_is_paced_and_sends_only_what_changed():
    sink, clock = CommandLog(), Clock()
    viewer = Viewer(sink, SceneInfo(name="x"), clock=clock)
    q, codes = np.zeros((2, 3)), np.array([TRACKING, STOPPED])
    q[1, 0] = 2.0
    start = len(sink.commands)
    viewer.draw(0.0, q, codes)
    assert len(sent_hud(sink, start)) == 6  # the first frame: every line
    start = len(sink.commands)
    clock.now += 0.1
    viewer.draw(0.02, q, codes)
    assert sent_hud(sink, start) == []  # within HUD_PERIOD_S: nothing
    clock.now += viz.HUD_PERIOD_S
    viewer.draw(0.04, q, codes)
    assert sent_hud(sink, start) == [f"{HUD}/t"]  # only the time changed
    assert hud_texts(sink)["t"] == "t = 0.04 s"
    start = len(sink.commands)
    viewer.draw(0.06, q, codes)  # held back by the pacing...
    assert sent_hud(sink, start) == []
    viewer.refresh_overlay()  # ...until asked for (the last frame of a run)
    assert sent_hud(sink, start) == [f"{HUD}/t"] and hud_texts(sink)["t"] == "t = 0.06 s"
    no_overlay = CommandLog()
    Viewer(no_overlay, SceneInfo(), overlay=False).draw(0.0, q, codes)
    assert not any(path.startswith(HUD) and kind == "set_object" for kind, path, _ in no_overlay.commands)


def progress(alive=7, converged=3, frozen=2, min_distance=0.9, t=1.0) -> bytes:
    return protocol.encode(Progress(t=t, seq=50, duration=120.0, robots=7, alive=alive, converged=converged,
                                    frozen=frozen, min_distance=min_distance, misses=0, bad=0))


def test_a_live_watcher_takes_the_counts_from_the_worlds_progress():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    w = SwarmWatcher(MemoryBus(net), FLEET, viewer, scene=SceneInfo())
    w.start(draw_thread=False)
    try:
        pub.put(keys.world_snapshot(FLEET), snapshot(0, n=7))
        assert w.step() and viewer.stats[-1] is None  # no progress yet: the viewer counts
        pub.put(keys.world_progress(FLEET), progress())
        pub.put(keys.world_snapshot(FLEET), snapshot(1, n=7))
        assert w.step()
        assert viewer.stats[-1] == Stats(alive=7, converged=3, frozen=2, min_distance=0.9)
        pub.put(keys.world_progress(FLEET), progress(alive=6, min_distance=-1.0))  # < 0: none yet
        pub.put(keys.world_snapshot(FLEET), snapshot(2, n=7))
        assert w.step() and viewer.stats[-1] == Stats(alive=6, converged=3, frozen=2, min_distance=None)
        pub.put(keys.world_progress(FLEET), b"\x93junk")
        pub.put(keys.world_snapshot(FLEET), snapshot(3, n=7))
        assert w.step() and viewer.stats[-1].alive == 6  # a bad one is dropped and counted
        assert w.bad.count >= 1
        refreshed = viewer.refreshed
        assert not w.step() and viewer.refreshed == refreshed + 1  # nothing new: the overlay's last lines
        pub.put(keys.world_snapshot(FLEET), snapshot(0, n=7))  # a new run
        assert w.step() and viewer.stats[-1] is None
    finally:
        w.close()


def test_the_simulator_in_the_viewer_shows_its_own_counts():
    from swarm.core.sim import Simulation

    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=3.0))
    sim = Simulation(scn)
    viewer = FakeViewer()
    assert play_simulation(sim, viewer, speed=1000.0) is False
    p = sim.progress()
    assert viewer.stats[-1] == Stats(alive=7, converged=p.converged, frozen=p.frozen, min_distance=p.min_distance)
    assert viewer.refreshed == 1
    sink = CommandLog()
    real = Viewer(sink, SceneInfo.from_scenario(scn))
    assert play_simulation(Simulation(scn), real, speed=1000.0) is False
    texts = hud_texts(sink)
    assert texts["t"] == f"t = {sim.recording().t[-1]:.2f} s" and texts["name"] == "paper-50hz"
    assert texts["frozen"] == f"frozen {p.frozen}" and texts["alive"] == "alive 7 of 7"

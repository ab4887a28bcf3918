"""The viewer's pieces without a browser: state colours, one object per frame, frame skipping, bad
messages, the leader and the scene from a live swarm, simulator playback, the CLI's checks."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from swarm.proto import keys, protocol
from swarm.core import kinematics, scenario_file
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.cli.main import main
from swarm.proto.protocol import Ref, RobotSnap, Snapshot, Status
from swarm.core.scenario_file import Overrides
from swarm.view.meshcat_objects import CommandLog
from swarm.view.viz import DEAD, FROZEN, PALETTE, STALE, STOPPED, TRACKING, SceneInfo, Viewer, state_codes
from swarm.view.watch import SwarmWatcher, fetch_scene, play_simulation
from tests.viz.helpers import wait_until

FLEET = "vz"


def snapshot(seq: int, n: int = 3, alive=None, stopped=None, dt: float = 0.02) -> bytes:
    alive = [True] * n if alive is None else alive
    stopped = [False] * n if stopped is None else stopped
    return protocol.encode(Snapshot(t=seq * dt, seq=seq, robots=tuple(
        RobotSnap(i, float(i), 0.5 * i, 0.1 * i, 0.3, 0.0, stopped[i], alive[i]) for i in range(n))))


def status(frozen: bool, t: float = 0.0) -> bytes:
    return protocol.encode(Status(t=t, ex=0.1, ey=0.0, etheta=0.0, frozen=frozen, neighbours=2, stale=0, bad=0))


class FakeViewer:
    """Records what the watcher asks for; draw() can be held to play a slow browser."""

    def __init__(self, hold: threading.Event | None = None):
        self.hold = hold
        self.frames: list[tuple[float, np.ndarray, np.ndarray, object]] = []
        self.stats: list = []  # the Stats given with each frame
        self.scenes: list[SceneInfo] = []
        self.entered = threading.Event()
        self.refreshed = 0

    def set_scene(self, scene) -> None:
        self.scenes.append(scene)

    def draw(self, t, q, codes, leader=None, stats=None) -> None:
        self.entered.set()
        if self.hold is not None:
            assert self.hold.wait(10), "never released"
        self.frames.append((t, np.array(q), np.array(codes), leader))
        self.stats.append(stats)

    def refresh_overlay(self) -> None:
        self.refreshed += 1


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


# --------------------------------------------------------------------------- states and colours


@pytest.mark.unit
@pytest.mark.parametrize("alive, stopped, frozen, age, code", [
    (True, False, False, 0.1, TRACKING),
    (True, False, True, 0.1, FROZEN),
    (True, False, True, 1.5, STALE),  # an old status says nothing about frozen any more
    (True, True, True, 0.1, STOPPED),
    (True, True, False, 5.0, STOPPED),
    (False, True, True, 5.0, DEAD),
    (False, False, False, 0.0, DEAD),
])
def test_state_code_from_the_flags(alive, stopped, frozen, age, code):
    got = state_codes(np.array([alive]), np.array([stopped]), np.array([frozen]), np.array([age]))
    assert got.tolist() == [code]


@pytest.mark.unit
def test_every_state_has_its_own_colour():
    assert len({tuple(c) for c in PALETTE.tolist()}) == len(PALETTE) == 6


# --------------------------------------------------------------------------- one object per frame


def frame_commands(n: int):
    """The commands of a second frame of n robots (the first places ground and camera), the sink,
    the poses and the state codes drawn."""
    sink = CommandLog()
    rng = np.random.default_rng(n)
    offsets = rng.uniform(-10, 10, (n, 2))
    # a wall clock that stands still: the overlay is sent with the first frame only
    viewer = Viewer(sink, SceneInfo(offsets=offsets, obstacles=[[3.0, 4.0, 0.3, 1.2]]), trails=False,
                    clock=lambda: 0.0)
    q = np.c_[rng.uniform(-20, 20, (n, 2)), rng.uniform(-3, 3, n)]
    viewer.draw(0.0, q, np.zeros(n, int), (0.0, 0.0, 0.0))  # the first frame places the ground and camera
    first = len(sink.commands)
    codes = rng.integers(0, 5, n)
    viewer.draw(0.02, q, codes, (0.01, 0.0, 0.0))
    return sink.commands[first:], sink, q, codes


@pytest.mark.unit
@pytest.mark.parametrize("n", [37, 500])
def test_a_frame_is_one_instanced_mesh_and_three_transforms_whatever_n(n):
    cmds, sink, _, codes = frame_commands(n)
    assert [(kind, path) for kind, path, _ in cmds] == [
        ("set_transform", "/swarm"), ("set_object", "/swarm/robots"), ("set_transform", "/swarm/formation"),
        ("set_transform", "/swarm/formation/leader")]
    obj = sink.last["/swarm/robots"]["object"]["object"]
    assert obj["type"] == "InstancedMesh" and obj["count"] == n and obj["frustumCulled"] is False
    colours = np.frombuffer(obj["instanceColor"]["array"].data, np.float32).reshape(n, 3)
    np.testing.assert_array_equal(colours, PALETTE[codes])


@pytest.mark.unit
def test_the_instances_are_the_robots_poses_and_the_twin_matches_the_material():
    _, sink, q, _ = frame_commands(37)
    robots = sink.last["/swarm/robots"]["object"]
    m = np.frombuffer(robots["object"]["instanceMatrix"]["array"].data, np.float32).reshape(37, 4, 4)  # column-major
    np.testing.assert_allclose(m[:, 3, :2], q[:, :2], rtol=1e-6)  # translation column
    np.testing.assert_allclose(np.arctan2(m[:, 0, 1], m[:, 0, 0]), np.arctan2(np.sin(q[:, 2]), np.cos(q[:, 2])),
                               atol=1e-6)
    twin = sink.last["/swarm/keep/robots"]["object"]
    same = ("type", "vertexColors", "side", "transparent", "opacity", "depthWrite")
    assert {k: twin["materials"][0][k] for k in same} == {k: robots["materials"][0][k] for k in same}
    assert twin["object"]["type"] == "InstancedMesh" and "instanceColor" in twin["object"]
    assert twin["object"]["count"] == 1


@pytest.mark.unit
def test_the_slots_are_the_leader_plus_the_unrotated_offsets():
    # The law's slot (docs/design.md): x_id = x_l + d_ix. The slots' node is translated, never rotated.
    offsets = np.array([[1.5, 0.0], [0.0, 1.5]])
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo(offsets=offsets), trails=False)
    viewer.draw(1.0, np.zeros((2, 3)), np.zeros(2, int), (4.0, -2.0, 1.0))
    slots = sink.last["/swarm/formation/slots"]["object"]["object"]
    m = np.frombuffer(slots["instanceMatrix"]["array"].data, np.float32).reshape(2, 4, 4)
    np.testing.assert_allclose(m[:, 3, :2], offsets)
    assert sink.last["/swarm/formation"]["matrix"][:2] == [1.0, 0.0]  # no rotation
    assert sink.last["/swarm/formation"]["matrix"][12:14] == [4.0, -2.0]


@pytest.mark.unit
def test_trails_are_one_line_segments_object_resent_at_a_low_rate():
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo())
    q = np.zeros((5, 3))
    for k in range(60):  # 60 frames in well under a second: the trails go out once
        q[:, 0] += 0.05
        viewer.draw(0.05 * k, q, np.zeros(5, int))
    sent = [c for c in sink.commands if c[:2] == ("set_object", "/swarm/trails")]
    assert len(sent) == 1
    assert sink.last["/swarm/trails"]["object"]["object"]["type"] == "LineSegments"


@pytest.mark.unit
def test_draw_refuses_mismatched_shapes():
    viewer = Viewer(CommandLog(), None)
    with pytest.raises(ValueError, match="3 poses but 2 state codes"):
        viewer.draw(0.0, np.zeros((3, 3)), np.zeros(2, int))


# --------------------------------------------------------------------------- the watcher


def watcher_on(net: MemoryNet, viewer, scene: SceneInfo | None = SceneInfo(), **kw) -> SwarmWatcher:
    w = SwarmWatcher(MemoryBus(net), FLEET, viewer, scene=scene, **kw)
    return w


@pytest.mark.unit
def test_a_slow_viewer_skips_to_the_newest_snapshot_and_never_blocks_the_publisher():
    net = MemoryNet()
    pub = MemoryBus(net)
    hold = threading.Event()
    viewer = FakeViewer(hold)
    w = watcher_on(net, viewer)
    w.start()
    try:
        pub.put(keys.world_snapshot(FLEET), snapshot(0))
        assert viewer.entered.wait(5), "the first frame was never drawn"
        published = threading.Event()

        def publish() -> None:  # the viewer is stuck in draw(): the publisher must not notice
            for seq in range(1, 201):
                pub.put(keys.world_snapshot(FLEET), snapshot(seq))
                pub.put(keys.robot_status(FLEET, seq % 3), status(False))
            published.set()
        threading.Thread(target=publish, daemon=True).start()
        assert published.wait(10), "the publisher blocked while the viewer was stuck in draw()"
        assert viewer.frames == []  # still stuck in its first draw(): the 400 messages went by without it
        hold.set()
        wait_until(lambda: len(viewer.frames) >= 2, 5, "the second frame")
        assert [round(f[0] / 0.02) for f in viewer.frames] == [0, 200]  # the newest, nothing in between
        assert w.received == 201 and w.skipped == 199 and w.bad.count == 0
    finally:
        w.close()
    assert not w.running


@pytest.mark.unit
def test_frames_are_paced_at_max_hz():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    w = watcher_on(net, viewer, max_hz=10.0)
    w.start()
    try:
        started = time.monotonic()
        seq = 0
        while time.monotonic() - started < 1.0:
            pub.put(keys.world_snapshot(FLEET), snapshot(seq))
            seq += 1
            time.sleep(0.002)  # a publisher at ~500 Hz
        n = len(viewer.frames)
    finally:
        w.close()
    assert 4 <= n <= 12, f"{n} frames in 1 s at max 10 Hz (from {seq} snapshots)"
    assert seq > 100


@pytest.mark.unit
def test_bad_messages_are_dropped_and_counted_and_drawing_goes_on():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    w = watcher_on(net, viewer)
    w.start(draw_thread=False)
    bad_nan = protocol.encode(Snapshot(t=math.nan, seq=1, robots=()))
    for payload in (b"\x00garbage", protocol.encode(Ref(0.0, 0, 0.0, 0.0, 0.0, 0.0, 0.0)), bad_nan):
        pub.put(keys.world_snapshot(FLEET), payload)
        assert w.step() is False
    pub.put(keys.robot_status(FLEET, 1), b"\xc1")  # never valid msgpack
    pub.put(keys.leader_ref(FLEET), b"not a ref")
    pub.put(keys.world_snapshot(FLEET), snapshot(7))
    assert w.step() is True
    assert w.bad.count == 5  # three snapshots, the status and the reference
    assert len(viewer.frames) == 1 and viewer.frames[0][0] == pytest.approx(0.14)
    w.close()


@pytest.mark.unit
def test_frozen_stopped_dead_and_stale_reach_the_colours():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    clock = Clock()
    w = watcher_on(net, viewer, wall=clock)
    w.start(draw_thread=False)
    for i in range(4):
        pub.put(keys.robot_status(FLEET, i), status(frozen=(i == 1)))
    pub.put(keys.world_snapshot(FLEET), snapshot(1, n=5, alive=[True, True, True, False, True],
                                                 stopped=[False, False, True, False, False]))
    assert w.step()
    # robot 4 never sent a status, but the watcher has only just started: not stale yet
    assert viewer.frames[-1][2].tolist() == [TRACKING, FROZEN, STOPPED, DEAD, TRACKING]
    clock.now += 1.5  # no status for 1.5 s: every live, moving robot goes stale; redrawn without a snapshot
    assert w.step()
    assert viewer.frames[-1][2].tolist() == [STALE, STALE, STOPPED, DEAD, STALE]
    assert not w.step()  # nothing changed: no frame
    pub.put(keys.robot_status(FLEET, 0), status(frozen=True))
    assert w.step()
    assert viewer.frames[-1][2].tolist()[0] == FROZEN
    w.close()


@pytest.mark.unit
def test_without_a_leader_table_the_leader_is_its_reference_advanced_along_the_arc():
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    w = watcher_on(net, viewer)
    w.start(draw_thread=False)
    pub.put(keys.leader_ref(FLEET), protocol.encode(Ref(t=1.0, seq=50, x=2.0, y=1.0, theta=0.3, v=0.5, w=0.1)))
    pub.put(keys.world_snapshot(FLEET), snapshot(60))  # t = 1.2
    assert w.step()
    dx, dy, dth = kinematics.arc_displacement(0.3, 0.5, 0.1, 0.2)
    np.testing.assert_allclose(viewer.frames[-1][3], (2.0 + dx, 1.0 + dy, 0.3 + dth), rtol=0, atol=1e-12)
    w.close()


@pytest.mark.unit
def test_with_a_scenario_the_leader_is_exact_from_its_segments():
    scn = scenario_file.load("paper-50hz", Overrides(robots=3))
    net = MemoryNet()
    pub = MemoryBus(net)
    viewer = FakeViewer()
    w = watcher_on(net, viewer, scene=SceneInfo.from_scenario(scn))
    w.start(draw_thread=False)
    pub.put(keys.world_snapshot(FLEET), snapshot(900))  # t = 18 s, on the left arc
    assert w.step()
    x, y, th, _, _ = kinematics.leader_state(scn.leader.table(), 18.0)
    assert viewer.frames[-1][3] == (x, y, th)
    w.close()


@pytest.mark.unit
def test_without_a_scenario_the_scene_comes_from_the_worlds_queryables():
    from world.world import World

    scn = scenario_file.load("paper-50hz", Overrides(robots=4))
    net = MemoryNet()
    world = World(MemoryBus(net), scn, FLEET)
    world.start()
    try:
        found = fetch_scene(MemoryBus(net), FLEET, scn.n)
        assert found is not None
        np.testing.assert_array_equal(found.offsets, scn.offsets)
        np.testing.assert_array_equal(found.obstacles, scn.obstacles)
        assert (found.r, found.R) == (scn.r, scn.R)
        viewer = FakeViewer()
        w = watcher_on(net, viewer, scene=None)
        w.start(draw_thread=False)
        MemoryBus(net).put(keys.world_snapshot(FLEET), snapshot(3, n=4))
        assert w.step()
        assert len(viewer.scenes) == 1 and len(viewer.scenes[0].offsets) == 4
        w.close()
    finally:
        world.close()
    assert fetch_scene(MemoryBus(MemoryNet()), FLEET, 4) is None  # no world: no scene (and no exception)


# --------------------------------------------------------------------------- the simulator in the viewer


@pytest.mark.unit
def test_play_simulation_runs_to_the_end_and_shows_the_last_sample():
    from swarm.core.sim import Simulation

    scn = scenario_file.load("paper-50hz", Overrides(robots=3, duration=2.0))
    sim = Simulation(scn)
    sink = CommandLog()
    viewer = Viewer(sink, SceneInfo.from_scenario(scn))
    started = time.monotonic()
    assert play_simulation(sim, viewer, speed=20.0) is False
    assert sim.done and 0.08 <= time.monotonic() - started < 5.0  # 2 s at 20x: paced, not instant
    rec = sim.recording()
    m = np.frombuffer(sink.last["/swarm/robots"]["object"]["object"]["instanceMatrix"]["array"].data,
                      np.float32).reshape(3, 4, 4)
    np.testing.assert_allclose(m[:, 3, :2], rec.q[-1][:, :2], rtol=1e-6)
    assert viewer.frames >= 3


@pytest.mark.unit
def test_play_simulation_stops_when_asked():
    from swarm.core.sim import Simulation

    scn = scenario_file.load("paper-50hz", Overrides(robots=3, duration=100.0))
    sim = Simulation(scn)
    calls = []
    assert play_simulation(sim, Viewer(CommandLog(), None), speed=1.0, should_stop=lambda: calls.append(1) or
                           len(calls) > 3) is True
    assert not sim.done


# --------------------------------------------------------------------------- the command line


def run_cli(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse refuses a bad value itself
        return int(e.code)


@pytest.fixture
def taken_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.mark.unit
@pytest.mark.parametrize("argv, message", [
    (["up", "--viz-port", "65536"], "must be a port in 0..65535"),
    (["up", "--viz-port", "-1"], "must be a port in 0..65535"),
    (["viz", "--viz-port", "http"], "not a port number"),
    (["up", "--viz-host", "no-such-host.invalid"], "unknown host"),
    (["viz", "--viz-host", "192.0.2.1"], "not an address of this machine"),
    (["up", "--no-viz", "--viz-rings"], "--viz-rings has no effect with --no-viz"),
    (["sim", "--viz-port", "7000"], "--viz-port needs --viz"),
    (["sim", "--speed", "2"], "--speed needs --viz"),
    (["sim", "--viz", "--speed", "0"], "must be a finite number > 0"),
])
def test_bad_viewer_values_are_refused_with_exit_2(argv, message, capsys):
    assert run_cli(argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.unit
@pytest.mark.parametrize("command", [["up", "--robots", "2", "--fleet", "taken"], ["viz"], ["sim", "--viz"]])
def test_a_taken_viewer_port_is_refused_before_anything_starts(command, taken_port, capsys):
    assert run_cli([*command, "--viz-port", str(taken_port)]) == 2
    assert f"--viz-port {taken_port}: cannot listen on 127.0.0.1:{taken_port}" in capsys.readouterr().err


@pytest.mark.integration
def test_drawing_modules_import_no_transport():
    code = ("import sys, swarm.view.viz, swarm.view.watch, swarm.view.meshcat_server; "
            "print(','.join(m for m in ('zenoh', 'numba', 'IPython') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.unit
def test_swarm_up_reads_this_runs_viewer_url_then_reports_an_early_exit(tmp_path):
    from types import SimpleNamespace

    from swarm.cli.up import ViewerUrl

    log = tmp_path / "viz.log"
    log.write_text("viewer: http://127.0.0.1:1111/static/\n")  # an earlier run in the same --log-dir
    child = SimpleNamespace(log=log, proc=SimpleNamespace(rc=None))
    child.proc.poll = lambda: child.proc.rc
    url = ViewerUrl(child, 60.0, offset=log.stat().st_size)
    assert url.poll() is None
    with open(log, "a") as f:
        f.write("viewer: http://127.0.0.1:2222/static/\n")
    assert url.poll() == "viewer: http://127.0.0.1:2222/static/"
    assert url.poll() is None
    child.proc.rc = 1
    assert "the viz process exited (exit code 1); the swarm goes on without it" in url.poll()
    assert url.poll() is None

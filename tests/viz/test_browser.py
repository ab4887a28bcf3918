"""The viewer in a real browser (headless Chromium, software WebGL): robots in the scene and on
screen, a frozen robot changes colour, the shader program survives set_object (the twin), the legend
and the overlay's text on the page following the run, and the real `swarm up` and `swarm viz
--connect` paths, killed with SIGKILL, leave nothing behind.

Screenshots go to $SWARM_SCREENSHOT (a file, or a directory for all of them) or the test's tmp dir;
docs/viewer.png is the 37-robot one.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.view.meshcat_server import MeshcatServer
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from swarm.view.viz import DEAD, FROZEN, STALE, STOPPED, TRACKING, SceneInfo, Viewer
from tests.viz.helpers import (SCENE_ROWS, URL_LINE, Child, assert_all_gone, browser_page, chromium_processes, colour_of,
                               count_pixels, free_port, instance_colours, listening, meshcat_server_of,
                               needs_chromium, robots_js, screenshot_path, settle, wait_until)

pytestmark = [pytest.mark.browser, needs_chromium]

PROGRAMS_JS = "() => viewer.renderer.info.programs.map(p => p.id).join(',')"


def test_37_robots_on_screen_and_a_frozen_robot_turns_orange(tmp_path):
    """In process: the first 10 s of the paper-50hz run drawn from the simulator (trails, frozen
    robots among the slots), then one more robot marked frozen. Its screenshot is docs/viewer.png."""
    before_chromium = chromium_processes()
    scn = scenario_file.load("paper-50hz", Overrides(robots=37))
    sim = Simulation(scn)
    sim.advance(int(round(10.0 / scn.dt)) + 1)
    rec = sim.recording()
    every = int(round(0.2 / (rec.t[1] - rec.t[0])))
    with MeshcatServer() as server:
        viewer = Viewer(server, SceneInfo.from_scenario(scn))
        for k in range(0, len(rec.t), every):  # the run so far, for the trails
            viewer.draw(rec.t[k], rec.q[k], np.where(rec.frozen[k], FROZEN, TRACKING), tuple(rec.leader[k]))
        q, t, leader = rec.q[-1], rec.t[-1], tuple(rec.leader[-1])
        codes = np.where(rec.frozen[-1], FROZEN, TRACKING)
        tracking = np.flatnonzero(codes == TRACKING)
        assert 5 <= len(tracking) <= 32  # both colours on screen
        viewer.reframe()
        viewer.draw(t, q, codes, leader)
        viewer.send_trails()
        with browser_page(server.web_url) as page:
            page.wait_for_function(robots_js(37))
            settle(page)
            np.testing.assert_array_equal(instance_colours(page), [colour_of(c) for c in codes])
            programs = page.evaluate(PROGRAMS_JS)
            for _ in range(5):  # set_object every frame must not recompile the shader (the static twin)
                viewer.draw(t, q, codes, leader)
                settle(page)
            assert page.evaluate(PROGRAMS_JS) == programs
            first = screenshot_path(tmp_path, "viewer-37.png")
            page.screenshot(path=str(first))
            green, orange = count_pixels(first, TRACKING), count_pixels(first, FROZEN)
            assert green >= 25 * len(tracking), f"{green} green pixels for {len(tracking)} tracking robots"
            assert orange >= 25 * (37 - len(tracking)), f"{orange} orange pixels for {37 - len(tracking)} frozen"

            k = int(tracking[0])
            codes[k] = FROZEN
            viewer.draw(t, q, codes, leader)
            page.wait_for_function("() => { const c = viewer.scene.getObjectByName('swarm_robots').instanceColor;"
                                   f" return Math.abs(c.array[{3 * k}] - {colour_of(FROZEN)[0] / 255}) < 1e-3; }}")
            settle(page)
            second = screenshot_path(tmp_path, "viewer-37-one-more-frozen.png")
            page.screenshot(path=str(second))
            assert count_pixels(second, FROZEN) >= orange + 20, "the newly frozen robot is not orange on screen"
            assert count_pixels(second, TRACKING) <= green - 20
            assert page.errors == []
    wait_until(lambda: chromium_processes() <= before_chromium, 10, "Chromium to exit after browser.close()")


HUD_TEXT_JS = "name => { const o = viewer.scene.getObjectByName(name); return o ? o.userData.text : null; }"
# the pixels the browser drew for a label's text: non-transparent pixels of its canvas texture
INK_JS = ("name => { const c = viewer.scene.getObjectByName(name).material.map.image;"
          " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;"
          " for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++; return n; }")


def test_the_legend_and_the_overlay_are_on_the_page_and_follow_the_run(tmp_path):
    """The legend names every colour and shows it; the overlay's time, counts and smallest distance are
    drawn as text on the page and change as the run goes on (the simulator's first 6 s, 7 robots)."""
    from swarm.view.viz import LEGEND, STATE_COLORS
    from swarm.view.watch import play_simulation

    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=6.0))
    with MeshcatServer() as server:
        viewer = Viewer(server, SceneInfo.from_scenario(scn))
        sim = Simulation(scn)
        sim.advance(int(round(1.0 / scn.dt)) + 1)  # the first second
        rec = sim.recording()
        viewer.draw(rec.t[-1], rec.q[-1], np.where(rec.frozen[-1], FROZEN, TRACKING), tuple(rec.leader[-1]))
        with browser_page(server.web_url) as page:
            page.wait_for_function(robots_js(7))
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_t') === 't = {rec.t[-1]:.2f} s'")
            shown = {name: page.evaluate(HUD_TEXT_JS, f"swarm_legend_{name}") for name, *_ in LEGEND}
            assert shown == {name: text for name, text, *_ in LEGEND}
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_name") == "paper-50hz"
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_alive") == "alive 7 of 7"
            first = {k: page.evaluate(HUD_TEXT_JS, f"swarm_hud_{k}") for k in ("t", "frozen", "min_distance")}
            assert first["min_distance"].startswith("min distance ") and first["min_distance"].endswith(" m")
            ink = page.evaluate(INK_JS, "swarm_hud_t")
            assert ink > 100, f"the time's text drew {ink} pixels"
            for name, *_ in LEGEND:
                assert page.evaluate(INK_JS, f"swarm_legend_{name}") > 50
            settle(page)
            png = screenshot_path(tmp_path, "viewer-overlay-1s.png")
            page.screenshot(path=str(png))
            from PIL import Image

            img = np.asarray(Image.open(png).convert("RGB")).astype(int)
            legend_band = img[-100:]
            for k, colour in enumerate(STATE_COLORS):  # every state's swatch is on screen, in its exact colour
                want = np.rint(np.array([(colour >> 16) & 255, (colour >> 8) & 255, colour & 255]))
                hits = int((np.abs(legend_band - want).sum(axis=2) <= 12).sum())
                assert hits >= 60, f"{hits} pixels of the {k} swatch's colour in the legend"
            dark_top = int((img[:90].sum(axis=2) < 200).sum())
            assert dark_top > 500, f"{dark_top} dark (text) pixels in the overlay's panel"

            assert play_simulation(sim, viewer, speed=50.0) is False  # on to the end: 6 s
            final = f"t = {sim.recording().t[-1]:.2f} s"
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_t') === '{final}'")
            later = {k: page.evaluate(HUD_TEXT_JS, f"swarm_hud_{k}") for k in ("t", "frozen", "min_distance")}
            p = sim.progress()
            assert later["t"] == final != first["t"]
            assert later["frozen"] == f"frozen {p.frozen}"
            assert later["min_distance"] == f"min distance {p.min_distance:.3f} m"
            settle(page)
            png2 = screenshot_path(tmp_path, "viewer-overlay-6s.png")
            page.screenshot(path=str(png2))
            img2 = np.asarray(Image.open(png2).convert("RGB")).astype(int)
            assert (np.abs(img2[:90] - img[:90]).sum(axis=2) > 60).sum() > 50, "the overlay's pixels did not change"
            assert page.errors == []


def test_swarm_up_draws_the_live_swarm_and_a_sigkill_leaves_nothing_behind(tmp_path):
    """The real path: `swarm up` with its viewer child; then SIGKILL `swarm up` alone."""
    # long enough to be running still when it is killed (lock-step at 7 robots does 120 simulated s in 20-30 s
    # here: a run that had ended left its processes exiting, zombies, when the test read their command lines)
    child = Child(["up", "--robots", "7", "--duration", "1200", "--listen", f"tcp/127.0.0.1:{free_port()}",
                   "--fleet", "vizup", "--log-dir", str(tmp_path / "logs"), "--quiet"], tmp_path / "up.err")
    try:
        url = child.expect(URL_LINE, 60).group(1)
        assert url.startswith("http://127.0.0.1:")
        server = meshcat_server_of(child)
        assert {ip for ip, _ in listening(server)} == {"127.0.0.1"}
        with browser_page(url) as page:
            page.wait_for_function(robots_js(7), timeout=60_000)
            live = {tuple(colour_of(s)) for s in (TRACKING, FROZEN)}
            # the run is going: every robot tracking or frozen (not stopped or stale), and moving
            page.wait_for_function("() => { const o = viewer.scene.getObjectByName('swarm_robots');"
                                   " const c = o.instanceColor.array; for (let i = 0; i < 7; i++) {"
                                   f" const r = Math.round(c[3*i] * 255); if (!{sorted(int(c[0]) for c in live)}"
                                   ".includes(r)) return false; } return true; }", timeout=60_000)
            x0 = page.evaluate("() => viewer.scene.getObjectByName('swarm_robots').instanceMatrix.array[12]")
            page.wait_for_function("x0 => viewer.scene.getObjectByName('swarm_robots').instanceMatrix.array[12]"
                                   " !== x0", arg=x0, timeout=30_000)
            # the overlay: the world's progress counts, and the time going on
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_alive') === 'alive 7 of 7'", timeout=30_000)
            t0 = page.evaluate(HUD_TEXT_JS, "swarm_hud_t")
            assert t0.startswith("t = ") and page.evaluate(HUD_TEXT_JS, "swarm_legend_stopped") == "stopped (watchdog)"
            page.wait_for_function(f"t0 => ({HUD_TEXT_JS})('swarm_hud_t') !== t0", arg=t0, timeout=30_000)
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_converged").startswith("converged ")
            settle(page)
            png = screenshot_path(tmp_path, "viewer-up-7.png")
            page.screenshot(path=str(png))
            shown = count_pixels(png, TRACKING) + count_pixels(png, FROZEN)
            assert shown >= 7 * 15, f"only {shown} robot pixels for 7 robots"
            # (the legend shows every colour: count the scene's rows only)
            assert count_pixels(png, STOPPED, rows=SCENE_ROWS) + count_pixels(png, STALE, rows=SCENE_ROWS) + \
                count_pixels(png, DEAD, 4, rows=SCENE_ROWS) < 7 * 15
            assert page.errors == []
        tree = child.tree()
        names = [" ".join(p.cmdline()) for p in tree]
        assert sum(" robot --id " in n for n in names) == 7 and sum(" viz " in n for n in names) == 1
        child.proc.kill()  # SIGKILL the launcher only: its children must follow by themselves
        assert_all_gone(tree, 15, "swarm up killed with SIGKILL")
    finally:
        child.close()


def test_swarm_viz_connect_takes_the_scene_from_the_world_and_dies_with_a_sigkill(tmp_path):
    """`swarm viz --connect` with no scenario flag: obstacles and slots from the world's queryables,
    the leader from its reference."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    swarm = Child(["up", "--no-viz", "--robots", "3", "--duration", "600", "--listen", endpoint, "--fleet", "vizc",
                   "--log-dir", str(tmp_path / "logs"), "--quiet"], tmp_path / "up.err")
    viz = None
    try:
        viz = Child(["viz", "--connect", endpoint, "--fleet", "vizc"], tmp_path / "viz.err")
        url = viz.expect(URL_LINE, 60).group(1)
        scn = scenario_file.load("paper-50hz", Overrides(robots=3))
        with browser_page(url) as page:
            page.wait_for_function(robots_js(3), timeout=60_000)
            page.wait_for_function("n => { const s = viewer.scene.getObjectByName('swarm_slots');"
                                   " const o = viewer.scene.getObjectByName('swarm_obstacles');"
                                   " return !!s && s.count === n[0] && !!o && o.count === n[1]; }",
                                   arg=[3, len(scn.obstacles)], timeout=60_000)
            slots = page.evaluate("() => Array.from(viewer.scene.getObjectByName('swarm_slots').instanceMatrix.array)")
            np.testing.assert_allclose(np.array(slots).reshape(3, 16)[:, 12:14], scn.offsets, atol=1e-5)
            page.wait_for_function("() => { const f = viewer.scene.getObjectByName('formation');"
                                   " return !!f && f.visible && f.position.x !== 0; }", timeout=30_000)
            assert page.errors == []
        server = meshcat_server_of(viz)
        viz.proc.kill()
        assert_all_gone([server], 10, "the server of a SIGKILLed swarm viz")
        assert swarm.proc.poll() is None  # the swarm did not notice
    finally:
        if viz is not None:
            viz.close()
        swarm.close()


def test_swarm_replay_waits_for_a_browser_then_plays_to_the_end(tmp_path):
    """With --wait (the default on a terminal), a replay holds its first frame until a page connects,
    so the user sees it whole."""
    rec = tmp_path / "run.mcap"
    made = subprocess.run([sys.executable, "-m", "swarm.cli", "sim", "--robots", "3", "--duration", "2",
                           "--record", str(rec), "--quiet"], capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    replay = Child(["replay", str(rec), "--wait", "--exit"], tmp_path / "replay.err")
    try:
        url = replay.expect(URL_LINE, 60).group(1)
        replay.expect("waiting for a browser", 30)
        assert not any("done" in line for line in replay.seen) and replay.proc.poll() is None
        with browser_page(url) as page:
            replay.expect("a browser is connected, starting", 30)
            page.wait_for_function(robots_js(3), timeout=60_000)
            drawn = int(replay.expect(r"replay: done, (\d+) frames drawn", 60).group(1))
            assert drawn >= 20  # 2 s recorded at 20 Hz (41 frames); a frame already overdue is skipped
            # the overlay ends on the last frame (counted from the frames: a recording has no progress)
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_t') === 't = 2.00 s'", timeout=10_000)
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_alive") == "alive 3 of 3"
            assert page.errors == []
        assert replay.proc.wait(30) == 0
    finally:
        replay.close()


def test_dead_hung_and_cut_off_robots_and_stale_data_get_their_colours_on_screen(tmp_path):
    """A `swarm sim --record` run with a hang, a kill and a partition, replayed (swarm replay's own loop) up
    to t = 0.7 s: robot 2 hung and cut off, robot 3 cut off, robot 4 dead. Then one more frame says robot 0
    uses stale neighbour data. Colours and rings in the scene and on screen, counts in the overlay."""
    import threading

    from swarm.cli.playback import replay_into
    from swarm.view import record
    from swarm.view.viz import CUT_COLOR, HUNG, STALE_DATA_COLOR, rgb

    (tmp_path / "f.toml").write_text("[faults]\n[[faults.hang]]\nrobot = 2\nat = 0.3\nduration = 0.6\n"
                                     "[[faults.partition]]\ngroups = [[0, 1]]\nstart = 0.5\nend = 1.5\n")
    scn = scenario_file.load("paper-50hz", Overrides(robots=5, duration=1.0, seed=1, faults=str(tmp_path / "f.toml"),
                                                     kill="4@0.4"))
    path = tmp_path / "faults.mcap"
    record.record_simulation(path, scn, Simulation(scn, record_period=record.record_period(20.0, scn.dt)), 20.0)
    stop = threading.Event()
    with MeshcatServer() as server:
        viewer = Viewer(server, SceneInfo.from_scenario(scn))
        last = []

        def at(frame) -> None:
            last[:] = [frame]
            if frame.t >= 0.7 - 1e-9:
                stop.set()

        with browser_page(server.web_url) as page:
            drawn, early = replay_into(path, viewer, 1000.0, stop, max_hz=None, on_frame=at)
            assert early and last[0].t == pytest.approx(0.72)
            viewer.refresh_overlay()
            want = [TRACKING if not f else FROZEN for f in last[0].frozen.tolist()]
            want[2], want[4] = HUNG, DEAD
            page.wait_for_function(robots_js(5))
            page.wait_for_function("() => !!viewer.scene.getObjectByName('swarm_marks')")
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_stopped_cut') !== null")
            settle(page)
            np.testing.assert_array_equal(instance_colours(page), [colour_of(c) for c in want])
            rings = page.evaluate("() => { const o = viewer.scene.getObjectByName('swarm_marks');"
                                  " return [o.count, Array.from(o.instanceColor.array)]; }")
            red = np.rint(np.array(rgb(CUT_COLOR)) * 255)
            assert rings[0] == 2 and (np.rint(np.array(rings[1]).reshape(-1, 3) * 255) == red).all()
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_dead_hung") == "dead 1  hung 1"
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_stopped_cut") == "stopped 0  cut off 2"
            assert page.evaluate(HUD_TEXT_JS, "swarm_hud_alive") == "alive 4 of 5"
            png = screenshot_path(tmp_path, "viewer-faults.png")
            page.screenshot(path=str(png))
            scene_rows = slice(120, SCENE_ROWS.stop)  # under the overlay's three lines, above the legend
            assert count_pixels(png, HUNG, rows=scene_rows) >= 15, "the hung robot is not magenta on screen"
            assert count_pixels(png, DEAD, 4, rows=scene_rows) >= 15, "the dead robot is not black on screen"
            from PIL import Image

            img = np.asarray(Image.open(png).convert("RGB")).astype(int)[scene_rows]
            assert int((np.abs(img - red).sum(axis=2) <= 12).sum()) >= 15, "no red ring on screen"
            # robot 0 on stale neighbour data: a yellow ring
            viewer.set_marks(cut=last[0].cut, stale_data=[True, False, False, False, False])
            viewer.draw(last[0].t, last[0].q, np.array(want))
            viewer.refresh_overlay()
            page.wait_for_function("() => viewer.scene.getObjectByName('swarm_marks').count === 3")
            page.wait_for_function(f"() => ({HUD_TEXT_JS})('swarm_hud_stale_data') === 'stale data 1'")
            settle(page)
            page.screenshot(path=str(png))
            img = np.asarray(Image.open(png).convert("RGB")).astype(int)[scene_rows]
            yellow = np.rint(np.array(rgb(STALE_DATA_COLOR)) * 255)
            assert int((np.abs(img - yellow).sum(axis=2) <= 12).sum()) >= 15, "no yellow ring on screen"
            assert page.evaluate(HUD_TEXT_JS, "swarm_legend_stale_data") == "stale neighbour data"
            assert page.errors == []

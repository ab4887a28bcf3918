"""What the viewer costs: Python time per frame, and how much it slows a running swarm.

    python bench/viz_cost.py [--robots 37 500] [--frames 150] [--duration 10] [--repeats 2] [--no-page] [--no-up]

Section 1, the viewer's own cost per frame (median and p95, milliseconds of the draw thread):
  `step` is what SwarmWatcher does for one frame: decode and validate the N-robot snapshot, the
  state colours, and Viewer.draw (one InstancedMesh + 3 transforms, each a ZMQ round trip to a
  real meshcat server); `draw` is Viewer.draw alone. Paced at 30 Hz like the watcher, on the
  paper-50hz run resized to N robots, with no browser and with a headless Chromium page
  connected (software WebGL: a real GPU browser renders far faster; the page only adds load).
Section 1b, the recorder's own cost per frame (bench/record_cost.py's bench_recorder: decode,
  events and MCAP writing of one tick's traffic: a snapshot, the reference, N commands, N/5 statuses).
Section 2, the slowdown of a running swarm: `swarm up --robots 37 --duration 10` in lock-step,
  with --no-viz, with the viewer, with the recorder (--record, no viewer), with both, and with the
  viewer and a headless page watching it; wall time of the world's run (launch excluded), ticks per
  second and the slowdown against --no-viz (median of --repeats runs, interleaved).
Sections are functions in SECTIONS at the bottom, run in order.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from swarm.proto import keys, protocol
from swarm.core import scenario_file
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.view.meshcat_server import MeshcatServer
from swarm.proto.protocol import RobotSnap, Snapshot, Status
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from swarm.view.viz import SceneInfo, Viewer
from swarm.view.watch import SwarmWatcher

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--window-size=1024,768"]
HZ = 30.0


def have_browser() -> bool:
    import importlib.util

    return importlib.util.find_spec("playwright") is not None and Path(CHROMIUM).exists()


@contextlib.contextmanager
def page_on(url: str, robots: int):
    """A headless Chromium page on the viewer, once it shows `robots` robots (robots=0: just loaded)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": 1024, "height": 768})
            page.goto(url)
            if robots:
                page.wait_for_function("n => { const o = window.viewer && viewer.scene.getObjectByName("
                                       "'swarm_robots'); return !!o && o.count === n; }", arg=robots, timeout=120_000)
            yield page
        finally:
            browser.close()


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(np.array(xs), q))


# --------------------------------------------------------------------------- section 1


def frame_cost(n: int, frames: int, with_page: bool) -> dict:
    scn = scenario_file.load("paper-50hz", Overrides(robots=n, duration=20.0))
    sim = Simulation(scn, record_period=0.04)
    sim.advance(sim.n_steps + 1)
    rec = sim.recording()
    scene = SceneInfo.from_scenario(scn)
    net = MemoryNet()
    pub = MemoryBus(net)
    fleet = "vizcost"
    with MeshcatServer() as server:
        viewer = Viewer(server, scene)
        watcher = SwarmWatcher(MemoryBus(net), fleet, viewer, scene=scene)
        watcher.start(draw_thread=False)

        def publish(k: int) -> None:
            s = k % len(rec.t)
            snap = Snapshot(t=float(rec.t[s]), seq=k, robots=tuple(
                RobotSnap(i, *map(float, rec.q[s, i]), 0.5, 0.0, False, True) for i in range(n)))
            pub.put(keys.world_snapshot(fleet), protocol.encode(snap))
            if k % 3 == 0:  # statuses at 10 Hz, like the agents
                for i in range(n):
                    pub.put(keys.robot_status(fleet, i), protocol.encode(Status(
                        t=float(rec.t[s]), ex=0.0, ey=0.0, etheta=0.0, frozen=bool(rec.frozen[s, i]), neighbours=0,
                        stale=0, bad=0)))

        publish(0)
        watcher.step()  # the first frame places ground and camera
        with page_on(server.web_url, n) if with_page else contextlib.nullcontext():
            steps = []
            viewer.costs.clear()
            sent0 = server.client.bytes
            next_at = time.perf_counter()
            for k in range(1, frames + 1):
                publish(k)
                t0 = time.perf_counter()
                watcher.step()
                steps.append(time.perf_counter() - t0)
                next_at += 1.0 / HZ
                time.sleep(max(0.0, next_at - time.perf_counter()))
            sent = server.client.bytes - sent0
        watcher.close()
    draws = viewer.costs[-frames:]
    return {"robots": n, "page": with_page, "step_ms": (1e3 * statistics.median(steps), 1e3 * pct(steps, 95)),
            "draw_ms": (1e3 * statistics.median(draws), 1e3 * pct(draws, 95)), "kb_per_frame": sent / frames / 1024}


def viewer_cost(a) -> None:
    print("Section 1: the viewer's Python cost per frame, paced at 30 Hz (ms, median / p95)")
    pages = [False] + ([True] if a.page and have_browser() else [])
    if a.page and not have_browser():
        print(f"  (no headless page: {CHROMIUM} or playwright is missing)")
    print(f"  {'robots':>6}  {'page':<14} {'step (decode + draw)':>22}  {'draw alone':>14}  {'sent/frame':>10}")
    for n in a.robots:
        for with_page in pages:
            r = frame_cost(n, a.frames, with_page)
            print(f"  {n:>6}  {'headless' if with_page else 'none':<14} {r['step_ms'][0]:>9.2f} / {r['step_ms'][1]:<9.2f}"
                  f"  {r['draw_ms'][0]:>5.2f} / {r['draw_ms'][1]:<6.2f}  {r['kb_per_frame']:>7.1f} KiB", flush=True)


# --------------------------------------------------------------------------- section 2


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def up_run(kind: str, n: int, duration: float, out: Path) -> dict:
    """One `swarm up` run; kind: "no-viz", "viz", "rec" (recorder, no viewer), "viz+rec" or "viz+page".
    Returns its metrics."""
    tag = f"{kind.replace('+', '-')}-{time.monotonic_ns()}"
    metrics = out / f"m-{tag}.json"
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(n), "--duration", str(duration),
           "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", "vizcost", "--metrics", str(metrics),
           "--log-dir", str(out / f"logs-{tag}"), "--quiet"]
    if kind in ("no-viz", "rec"):
        cmd.append("--no-viz")
    if kind in ("rec", "viz+rec"):
        cmd += ["--record", str(out / f"r-{tag}.mcap")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, start_new_session=True)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    try:
        if kind == "viz+page":
            url = None
            end = time.monotonic() + 120
            while url is None and time.monotonic() < end and proc.poll() is None:
                with contextlib.suppress(queue.Empty):
                    m = re.match(r"viewer: (http\S+)", lines.get(timeout=0.5))
                    url = m.group(1) if m else None
            if url is None:
                raise RuntimeError("swarm up printed no viewer URL")
            with page_on(url, 0):
                proc.wait(timeout=120 + 20 * duration)
        else:
            proc.wait(timeout=120 + 20 * duration)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    if proc.returncode != 0:
        raise RuntimeError(f"swarm up ({kind}) failed with exit code {proc.returncode}; logs in {out}")
    return json.loads(metrics.read_text())


def swarm_slowdown(a) -> None:
    if not a.up:
        return
    kinds = ["no-viz", "viz", "rec", "viz+rec"] + (["viz+page"] if a.page and have_browser() else [])
    print(f"\nSection 2: `swarm up --robots {a.up_robots} --duration {a.duration:g}` in lock-step "
          f"(median of {a.repeats} interleaved runs)")
    runs: dict[str, list[dict]] = {k: [] for k in kinds}
    with tempfile.TemporaryDirectory(prefix="swarm-viz-cost-") as tmp:
        for _ in range(a.repeats):
            for k in kinds:
                runs[k].append(up_run(k, a.up_robots, a.duration, Path(tmp)))
    base = statistics.median(m["run_wall_s"] for m in runs["no-viz"])
    print(f"  {'viewer':<10} {'run wall s':>10} {'ticks/s':>8} {'whole command s':>16} {'slowdown':>9}")
    for k in kinds:
        run_s = statistics.median(m["run_wall_s"] for m in runs[k])
        ticks = statistics.median(m["duration_s"] / m["dt"] / m["run_wall_s"] for m in runs[k])
        whole = statistics.median(m["wall_s"] for m in runs[k])
        print(f"  {k:<10} {run_s:>10.2f} {ticks:>8.1f} {whole:>16.2f} {100 * (run_s / base - 1):>+8.1f}%", flush=True)


# --------------------------------------------------------------------------- main

def recorder_cost(a) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from record_cost import bench_recorder

    print("\nSection 1b: the recorder's cost per frame (one tick of traffic; record_hz 20)")
    for n in a.robots:
        bench_recorder(n, max(100, a.frames))


# The sections, run in order.
SECTIONS = [viewer_cost, recorder_cost, swarm_slowdown]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, nargs="+", default=[37, 500], help="robots for section 1")
    p.add_argument("--frames", type=int, default=150, help="frames per case in section 1")
    p.add_argument("--up-robots", type=int, default=37, help="robots of the swarm in section 2")
    p.add_argument("--duration", type=float, default=10.0, help="simulated seconds per swarm up run")
    p.add_argument("--repeats", type=int, default=2, help="swarm up runs per case")
    p.add_argument("--no-page", dest="page", action="store_false", help="no headless browser page")
    p.add_argument("--no-up", dest="up", action="store_false", help="skip section 2 (the swarm up runs)")
    a = p.parse_args(argv)
    for section in SECTIONS:
        section(a)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`swarm replay` and `swarm report`: the commands that read a recording (swarm.view.record's MCAP file).

    swarm replay run.mcap [--speed X] [--viz-host H] [--viz-port P] [--wait | --no-wait] [--exit]
    swarm report run.mcap -o DIR

Replay waits for a browser page to connect (--wait; the default on a terminal), then draws the recorded
snapshots in the viewer exactly as recorded (poses, and the colours from the recorded alive, stopped and
frozen flags, the recorded fault events and the statuses' stale counts), paced by their simulated time
at --speed and at most MAX_HZ frames a wall second (a frame whose successor is already due is skipped,
never drawn late). The reading itself is swarm.view.report's, so a replay and a report see the same data.
A recording without its footer (a killed run) is read up to its last complete chunk, and both
commands say on stderr how much came back (swarm.view.report.Recovery).
"""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

import numpy as np

from swarm.cli.common import EXIT_INTERRUPTED, EXIT_OK, BadInput, Failure, StopEvent, check_viz_port, viz_options

log = logging.getLogger("swarm.playback")

MAX_HZ = 30.0


def _recording(path: Path) -> Path:
    if not path.is_file():
        raise BadInput(f"{path}: no such file")
    return path


def replay_into(path: Path, viewer, speed: float, stop: threading.Event, max_hz: float = MAX_HZ,
                on_frame=None) -> tuple[int, bool]:
    """Draw the frames of `path` into `viewer` at `speed`; returns (frames drawn, stopped early)."""
    from swarm.view import report
    from swarm.view.viz import DEAD, HUNG, state_codes

    drawn = 0
    set_marks = getattr(viewer, "set_marks", None)
    for f in report.pace(report.iter_frames(path, faults=True), speed, max_hz=max_hz, sleep=stop.wait):
        if stop.is_set():
            return drawn, True
        codes = state_codes(f.alive, f.stopped, f.frozen, np.zeros(len(f.q)), hung=f.hung, killed=f.killed)
        if set_marks is not None:
            set_marks(cut=f.cut, stale_data=f.stale_data & (codes != DEAD) & (codes != HUNG))
        viewer.draw(f.t, f.q, codes)  # the overlay counts what the frame shows (a recording has no progress)
        drawn += 1
        if on_frame is not None:
            on_frame(f)
    refresh = getattr(viewer, "refresh_overlay", None)
    if refresh is not None:  # the overlay shows the last frame
        refresh()
    return drawn, stop.is_set()


def cmd_replay(args, started: float) -> int:
    from swarm.view import report
    from swarm.view.meshcat_server import MeshcatServer, ServerError
    from swarm.view.viz import SceneInfo, Viewer

    path = _recording(args.recording)
    try:
        recovered = report.recovery(path)
        scn, info = report.read_scenario(path)
    except report.ReportError as e:
        raise BadInput(str(e)) from None
    if recovered is not None:
        print(f"swarm replay: warning: {path}: {recovered.message()}", file=sys.stderr, flush=True)
    viz = viz_options(args, True, "")
    check_viz_port(viz)
    with StopEvent() as stop:
        server = MeshcatServer(viz.host, viz.port, start_timeout_s=viz.timeout)
        try:
            server.start()
            print(f"viewer: {server.web_url}", flush=True)
            print(f"replay: {path} ({scn.n} robots, {scn.name}, recorded from {info.get('source', '?')}) "
                  f"at {args.speed:g}x", flush=True)
            viewer = Viewer(server, SceneInfo.from_scenario(scn), rings=viz.rings)
            wait = args.wait or (not args.no_wait and sys.stdout.isatty())  # a script must never hang here
            if wait and not _wait_for_browser(server, stop):
                return EXIT_INTERRUPTED
            try:
                drawn, early = replay_into(path, viewer, args.speed, stop)
            except report.ReportError as e:
                raise Failure(str(e)) from None
            if early:
                return EXIT_INTERRUPTED
            print(f"replay: done, {drawn} frames drawn", flush=True)
            if args.exit:
                return EXIT_OK
            print(f"replay: the viewer stays at {server.web_url} until Ctrl-C", flush=True)
            while not stop.wait(0.25):
                pass
            return EXIT_INTERRUPTED
        except ServerError as e:
            raise Failure(f"viewer: {e}") from None
        finally:
            server.stop()


def _wait_for_browser(server, stop: threading.Event, poll_s: float = 0.2) -> bool:
    """Hold the replay until a browser page is connected (a replay nobody sees is over before the
    page opens). False if stopped first."""
    if server.client.browsers() > 0:
        return True
    print(f"replay: waiting for a browser on {server.web_url} (Ctrl-C to stop; --no-wait starts at once)", flush=True)
    while not stop.wait(poll_s):
        if server.client.browsers() > 0:
            print("replay: a browser is connected, starting", flush=True)
            return True
    return False


def cmd_report(args, started: float) -> int:
    from swarm.view import report

    path = _recording(args.recording)
    if args.out.exists() and not args.out.is_dir():
        raise BadInput(f"-o {args.out}: exists and is not a directory")
    try:
        recovered = report.recovery(path)
        if recovered is not None:
            print(f"swarm report: warning: {path}: {recovered.message()}", file=sys.stderr, flush=True)
        files = report.write_report(path, args.out)
    except report.ReportError as e:
        raise BadInput(str(e)) from None
    print(f"report: {args.out / 'index.html'} ({len(files)} files in {args.out})")
    return EXIT_OK

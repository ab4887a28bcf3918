"""Shared pieces of the viewer tests: headless Chromium, pixel counts, child processes with deadlines."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from swarm.view.viz import STATE_COLORS, rgb
from tests.integration.helpers import free_port, wait_until  # noqa: F401  (for the viewer tests)

CHROMIUM = "/usr/bin/chromium"
# software WebGL (SwiftShader), offline, no profile noise
FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--window-size=1024,768"]
needs_chromium = pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} is not installed "
                                    "(apt-get install chromium; CI installs it)")
URL_LINE = re.compile(r"^viewer: (http\S+)")


@contextlib.contextmanager
def browser_page(url: str, timeout_s: float = 30.0):
    """A headless Chromium page on `url` (closed on the way out, whatever happens); page errors
    are collected in page.errors."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=FLAGS, timeout=timeout_s * 1000)
        try:
            page = browser.new_page(viewport={"width": 1024, "height": 768})
            page.set_default_timeout(timeout_s * 1000)
            page.errors = []
            page.on("pageerror", lambda e: page.errors.append(str(e)))
            page.goto(url)
            yield page
        finally:
            browser.close()


def robots_js(n: int) -> str:
    """A JS predicate: the scene's robots mesh holds n instances."""
    return (f"() => {{ const o = window.viewer && viewer.scene.getObjectByName('swarm_robots');"
            f" return !!o && o.count === {n}; }}")


def instance_colours(page) -> np.ndarray:
    """(N, 3) the robots' instance colours in the page, 0..255."""
    rows = page.evaluate("() => Array.from(viewer.scene.getObjectByName('swarm_robots').instanceColor.array)")
    return np.rint(np.array(rows, float).reshape(-1, 3) * 255)


def colour_of(state: int) -> np.ndarray:
    return np.rint(np.array(rgb(STATE_COLORS[state])) * 255)


def settle(page) -> None:
    """Two animation frames: what was received has been rendered."""
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")


# Rows of a 768-pixel-high screenshot between the overlay's top panel (two lines; 120 with the faults'
# third) and its legend of three rows (whose swatches show every state's colour): where only the scene's
# robots can have those colours.
SCENE_ROWS = slice(90, 768 - 112)


def count_pixels(png: Path, state: int, tolerance: int = 12, rows: slice = slice(None)) -> int:
    """Pixels of the state's colour (robots are unlit, so their tops have the exact colour), in `rows`."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(int)[rows]
    return int((np.abs(img - colour_of(state)).sum(axis=2) <= tolerance).sum())


def screenshot_path(tmp_path: Path, name: str) -> Path:
    """$SWARM_SCREENSHOT (a file, or a directory for every screenshot) if set, else tmp_path/name."""
    target = os.environ.get("SWARM_SCREENSHOT")
    if not target:
        return tmp_path / name
    t = Path(target)
    if t.is_dir():
        return t / name
    t.parent.mkdir(parents=True, exist_ok=True)
    return t


class Child:
    """A command in its own session, stdout read line by line on a thread (so reads have deadlines),
    stderr to a file; killed with its whole group on the way out."""

    def __init__(self, argv: list[str], log: Path):
        self.log = log
        self._err = open(log, "wb")
        self.proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", *argv], stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=self._err, text=True, start_new_session=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def expect(self, pattern: re.Pattern | str, timeout_s: float) -> re.Match:
        pattern = re.compile(pattern) if isinstance(pattern, str) else pattern
        end = time.monotonic() + timeout_s
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no line matching {pattern.pattern!r} within {timeout_s} s; got {self.seen}; "
                                     f"exit code {self.proc.poll()}; stderr: {self.stderr()[-2000:]}")
            try:
                line = self.lines.get(timeout=min(left, 0.2))
            except queue.Empty:
                continue
            self.seen.append(line)
            m = pattern.search(line)
            if m:
                return m

    def stderr(self) -> str:
        try:
            return self.log.read_text(errors="replace")
        except OSError:
            return ""

    def tree(self) -> list[psutil.Process]:
        """This process and every descendant still alive."""
        try:
            me = psutil.Process(self.proc.pid)
            return [me, *me.children(recursive=True)]
        except psutil.NoSuchProcess:
            return []

    def close(self) -> None:
        leftovers = self.tree()
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        for p in leftovers:
            with contextlib.suppress(psutil.NoSuchProcess):
                p.kill()
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(10)
        self._err.close()


def meshcat_server_of(child: Child, timeout_s: float = 30.0) -> psutil.Process:
    def find():
        for p in child.tree():
            with contextlib.suppress(psutil.NoSuchProcess):
                if "swarm.view.meshcat_server" in p.cmdline():
                    return p
        return None

    return wait_until(find, timeout_s, "the meshcat server process")


def listening(p: psutil.Process) -> set[tuple[str, int]]:
    return {(c.laddr.ip, c.laddr.port) for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN}


def assert_all_gone(procs: list[psutil.Process], timeout_s: float, what: str) -> None:
    """Every process in `procs` exits within timeout_s; those that do not are reported, then killed
    (an orphan of a killed launcher is no longer in anybody's process tree: nothing else would)."""
    _, alive = psutil.wait_procs(procs, timeout=timeout_s)
    names = ", ".join(f"{p.pid} {' '.join(_cmd(p))[:80]}" for p in alive)
    for p in alive:
        with contextlib.suppress(psutil.Error):
            p.kill()
    assert not alive, f"{what}: still running after {timeout_s} s: {names}"


def _cmd(p: psutil.Process) -> list[str]:
    try:
        return p.cmdline()
    except psutil.Error:
        return ["?"]


def chromium_processes() -> set[int]:
    out = set()
    for p in psutil.process_iter(["name", "exe"]):
        with contextlib.suppress(psutil.Error):
            if "chrom" in (p.info["name"] or "") or (p.info["exe"] or "").startswith(CHROMIUM):
                out.add(p.pid)
    return out


"""bench/zenoh_floor.py (the floor docs/performance.md compares swarm with) runs, in both modes, and leaves nothing."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

pytestmark = pytest.mark.integration

BENCH = Path(__file__).resolve().parents[2] / "bench" / "zenoh_floor.py"


@pytest.mark.parametrize("mode, figure", [("realtime", r"round trip median [\d.]+ ms, p99 [\d.]+ ms"),
                                          ("lockstep", r"[\d.]+ ticks/s"),
                                          ("lockstep --wait", r"lock-step waiting for states, .* [\d.]+ ticks/s"),
                                          ("lockstep --wait --callbacks",
                                           r"lock-step waiting for states in callbacks, .* [\d.]+ ticks/s")])
def test_floor_bench_measures_and_cleans_up(mode, figure):
    before = {p.pid for p in psutil.process_iter()}
    out = subprocess.run([sys.executable, str(BENCH), "--robots", "5", "--duration", "1", "--mode", *mode.split()],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert re.search(figure, out.stdout), out.stdout
    assert re.search(r"robot [\d.]+ % each", out.stdout), out.stdout
    loop, process = map(float, re.search(r"loop thread (\d+) us .* the whole robot process (\d+) us", out.stdout).groups())
    assert 0 < loop <= process, out.stdout  # the loop thread is part of its process
    if "--wait" in mode:  # 5 robots in formation share cells: each waited for some states every tick
        assert float(re.search(r"([\d.]+) states per robot", out.stdout).group(1)) > 1.0, out.stdout
    left = [p for p in psutil.process_iter(["pid", "cmdline"])
            if p.pid not in before and "zenoh_floor" in " ".join(p.info["cmdline"] or [])]
    for p in left:
        p.kill()
    assert not left, left

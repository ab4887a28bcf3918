"""bench/world_tick.py (the world's part of a lock-step tick, quoted in docs/performance.md) runs and says what it timed."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

BENCH = Path(__file__).resolve().parents[2] / "bench" / "world_tick.py"


def test_world_tick_bench_times_every_part():
    out = subprocess.run([sys.executable, str(BENCH), "--robots", "5", "--repeat", "2"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    parts = re.findall(r"^  (.+?)\s+(\d+) us$", out.stdout, re.M)
    names = [p for p, _ in parts]
    assert names[:3] == ["5 commands taken, each robot's next pose stepped and encoded (World._on_cmd)",
                         "the same, the last one ending the tick: the poses in, clock and poses out (_take_over)",
                         "5 exact arcs (the run loop, when it ends a tick)"], out.stdout
    assert names[3] == "wait-rule check" and names[4].startswith("metrics sample"), out.stdout
    assert names[5:] == ["metrics sample, pairs in numpy", "clock and 5 poses published (the run loop)"], out.stdout
    assert all(int(us) >= 0 for _, us in parts)


def test_world_tick_bench_refuses_a_bad_count():
    out = subprocess.run([sys.executable, str(BENCH), "--robots", "1"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--robots must be at least 2" in out.stderr

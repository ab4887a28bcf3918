"""bench/robot_tick.py (docs/performance.md) drives one robot's agent as `swarm up` would, message by message: a
change to what a tick waits for, or to the agent's callbacks, that the bench does not follow fails here (it
exits naming the tick that was never computed) rather than when someone next measures."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

BENCH = Path(__file__).resolve().parents[2] / "bench" / "robot_tick.py"


@pytest.mark.timeout(240)
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_robot_tick_computes_every_period_it_feeds(mode):
    out = subprocess.run([sys.executable, str(BENCH), "--mode", mode, "--ticks", "40", "--bus", "memory"],
                         capture_output=True, text=True, timeout=200)
    assert out.returncode == 0, out.stdout + out.stderr
    heard = re.search(r"40 periods: ([\d.]+) neighbours a period, 0 bad messages", out.stdout)
    assert heard and float(heard.group(1)) > 0, out.stdout
    assert re.search(r"CPU per period: mean [\d.]+ us, median [\d.]+ us, p90 [\d.]+ us", out.stdout), out.stdout

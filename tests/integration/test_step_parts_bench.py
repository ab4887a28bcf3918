"""bench/step_parts.py (docs/performance.md, "A period measured inside the swarm") times the parts it names in a
real `swarm up`: a part of every period that is renamed or no longer on the step's path fails here (its
calls fall to zero, or the robots cannot be patched and write no sums)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

BENCH = Path(__file__).resolve().parents[2] / "bench" / "step_parts.py"


@pytest.mark.timeout(240)
def test_step_parts_times_every_part_of_a_real_time_step():
    out = subprocess.run([sys.executable, str(BENCH), "--robots", "4", "--duration", "3"],
                         capture_output=True, text=True, timeout=200)
    assert out.returncode == 0, out.stdout + out.stderr
    rows = re.findall(r"^ *(\S.*?) +([\d.]+) +([\d.]+)$", out.stdout, re.M)
    parts = {label: (float(us), float(calls)) for label, us, calls in rows}
    sys.path.insert(0, str(BENCH.parent))
    try:
        import step_parts
    finally:
        sys.path.remove(str(BENCH.parent))
    for label, *_ in step_parts.PARTS:
        assert label in parts, out.stdout
    # parts of every period: called in most periods (the first ones listen and compute no command)
    for label in ("Runner work (the whole step)", "tick_realtime", "_take_inboxes", "drain (10 inboxes, zenoh)",
                  "_publish_state", "_publish", "SimDrive.send"):
        us, calls = parts[label]
        assert calls >= 0.9 and us > 0, (label, out.stdout)
    assert parts["Runner work (the whole step)"][0] >= parts["tick_realtime"][0], out.stdout  # inclusive
    assert re.search(r"robots loop CPU \(their log, timers in\) +[\d.]+", out.stdout), out.stdout

"""Pure layers import neither zenoh nor numba (checked in a fresh interpreter)."""

import subprocess
import sys

import pytest

PURE = ["swarm.law", "swarm.kinematics", "swarm.grid", "swarm.scenario", "swarm.scenario_file",
        "swarm.generators", "swarm.keys", "swarm.protocol"]


@pytest.mark.parametrize("module", PURE)
def test_pure_module_imports_no_transport_and_no_compiler(module):
    code = (f"import sys, {module}; bad = [m for m in ('zenoh', 'numba', 'subprocess_helpers') if m in sys.modules];"
            "print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "", f"{module} pulled in {out.stdout.strip()}"

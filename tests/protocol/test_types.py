"""The type checker passes: `python -m mypy` over swarm/, agents/ and world/ with the project's configuration
(pyproject.toml [tool.mypy]: swarm.core and swarm.proto as strictly as mypy's --strict goes module by module)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


def test_mypy_finds_no_error(tmp_path):
    pytest.importorskip("mypy", reason="the type checker is in the test extra: pip install -e '.[test]'")
    out = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "cache"), "--no-pretty"],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-6000:] + out.stderr[-2000:]
    assert "Success: no issues found" in out.stdout, out.stdout

"""The docs as a site: `mkdocs build --strict` (mkdocs.yml) passes, so every page is in the navigation, every
link and anchor between pages resolves, and the Material theme renders it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(180)
def test_the_docs_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="mkdocs is in the test extra: pip install -e '.[test]'")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                          "-d", str(tmp_path / "site")], capture_output=True, text=True, timeout=170, env=env)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    built = {p.parent.name + ".md" for p in (tmp_path / "site").glob("*/index.html")} | {"index.md"}
    assert pages <= built, f"pages not built: {sorted(pages - built)}"

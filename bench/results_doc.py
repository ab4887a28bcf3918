"""docs/results.md as sections, each written by the bench that measures it (never by hand).

A section runs from `<!-- begin KEY -->` to `<!-- end KEY -->`; write_section replaces its own and keeps the
others, in the order of SECTIONS (a section not yet in the file goes where that order puts it).
"""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results.md"
SECTIONS = ("paper", "sim-speed", "numpy")
HEAD = ("# Results\n\nEach section below is written by the command it names (do not edit by hand): the paper "
        "experiment's tables, then the simulator's speed.\n")


def machine() -> str:
    """The machine a figure was measured on: CPU model, cores, Python, commit."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=RESULTS.parent, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    return f"{model}, {os.cpu_count()} cores, Python {platform.python_version()}, commit {commit}"


def write_section(key: str, text: str, path: Path = RESULTS) -> None:
    """Put `text` (markdown, without the markers) as section `key` of `path`."""
    if key not in SECTIONS:
        raise ValueError(f"unknown section {key!r} (sections: {', '.join(SECTIONS)})")
    old = path.read_text() if path.exists() else ""
    parts: dict[str, str] = {}
    for k in SECTIONS:
        begin, end = f"<!-- begin {k} -->", f"<!-- end {k} -->"
        if begin in old and end in old:
            parts[k] = old[old.index(begin) + len(begin):old.index(end)].strip("\n")
    parts[key] = text.strip("\n")
    body = "\n\n".join(f"<!-- begin {k} -->\n{parts[k]}\n<!-- end {k} -->" for k in SECTIONS if k in parts)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"{HEAD}\n{body}\n")

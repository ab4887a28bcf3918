"""Shared helpers of the tests: scenario documents, a small TOML writer, and the tier rule.

The standard library reads TOML (tomllib) but cannot write it; the scenario tests need
to write many slightly broken files, so `toml_text` turns the dictionaries they edit
into TOML text (tables, arrays of tables, inline tables, nan/inf literals).

Every test carries exactly one tier marker (pyproject.toml): unit, integration or browser, or
slow, which may go with integration or browser. Collection fails on a test without one, or
with two, naming it (CONTRIBUTING.md, "Test tiers").
"""

from __future__ import annotations

import copy
import math
import os
from pathlib import Path
from typing import Any, Callable

import pytest

# a helper module whose asserts fail inside a test: pytest rewrites them, so a failure shows the values
pytest.register_assert_rewrite("tests.runtime.agent_helpers")


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def toml_text(doc: dict) -> str:
    """TOML text for a scenario-shaped document: scalars first, then [tables], then [[arrays]]."""
    lines = []
    for k, v in doc.items():
        if not isinstance(v, dict) and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v)):
            lines.append(f"{k} = {_value(v)}")
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(f"\n[{k}]")
            lines.extend(f"{kk} = {_value(vv)}" for kk, vv in v.items())
    for k, v in doc.items():
        if isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                lines.append(f"\n[[{k}]]")
                lines.extend(f"{kk} = {_value(vv)}" for kk, vv in item.items())
    return "\n".join(lines) + "\n"


# A small valid scenario (two robots, one obstacle) in the shape of docs/scenarios.md.
BASE_DOC = {
    "run": {"duration": 20.0, "dt": 0.01, "seed": 0},
    "control": {"k1": 0.5, "k2": 0.5, "k3": 1.0, "tu": 1.0, "vt": 0.05, "threshold": "frozen", "governor": False},
    "bodies": {"r": 0.3, "R": 1.2},
    "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 10.0, "v": 0.5, "w": 0.0}]},
    "formation": {"offsets": [[0.0, 0.0], [1.5, 0.0]], "assignment": "ordered"},
    "robots": {"poses": [[-8.0, 1.0, 0.3], [-9.0, -2.0, 1.2]]},
    "obstacles": [{"center": [-3.0, 0.0], "r": 0.3, "R": 1.2}],
}


@pytest.fixture
def base_doc() -> dict:
    """A fresh deep copy of BASE_DOC for a test to edit."""
    return copy.deepcopy(BASE_DOC)


@pytest.fixture
def write_scenario(tmp_path: Path) -> Callable[..., str]:
    """write_scenario(doc_or_text, name="scenario.toml") -> the file's path as a str."""

    def write(doc: dict | str, name: str = "scenario.toml") -> str:
        path = tmp_path / name
        path.write_text(doc if isinstance(doc, str) else toml_text(doc), encoding="utf-8")
        return str(path)

    return write


TIERS = ("unit", "integration", "browser", "slow")
TESTS = Path(__file__).resolve().parent


def tier_error(markers: set[str]) -> str | None:
    """Why a test with these marker names breaks the tier rule, or None if it keeps it."""
    tiers = markers & set(TIERS)
    if not tiers:
        return "no tier marker"
    if len(tiers - {"slow"}) > 1 or tiers == {"unit", "slow"}:
        return "more than one tier: " + ", ".join(t for t in TIERS if t in tiers)
    return None


UNIT_WORKERS = 2  # processes `pytest -m unit` runs in (pytest-xdist): the inner loop uses both cores of a laptop


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config: pytest.Config) -> None:
    """`pytest -m unit` alone runs on UNIT_WORKERS processes (pytest-xdist, when installed): the unit tier is CPU
    bound and has no shared state between tests. Any other selection, an explicit -n, `-p no:xdist`, or
    SWARM_TEST_SERIAL=1 runs in this process as usual (the integration tests start processes of their own)."""
    opt = config.option
    if (getattr(opt, "markexpr", "") or "").strip() != "unit" or not config.pluginmanager.hasplugin("xdist"):
        return
    if getattr(opt, "numprocesses", None) or os.environ.get("SWARM_TEST_SERIAL") or \
            os.environ.get("PYTEST_XDIST_WORKER") or getattr(opt, "usepdb", False):
        return
    opt.numprocesses = min(UNIT_WORKERS, os.cpu_count() or 1)
    if opt.numprocesses > 1 and getattr(opt, "dist", "no") == "no":
        opt.dist = "load"


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Refuse to run when a collected test under tests/ breaks the tier rule (before -m deselects any)."""
    bad = []
    for item in items:
        if TESTS not in Path(item.path).resolve().parents:
            continue
        why = tier_error({m.name for m in item.iter_markers()})
        if why:
            bad.append(f"{item.nodeid}: {why}")
    if bad:
        raise pytest.UsageError(
            "every test needs exactly one tier marker: @pytest.mark.unit, integration or browser, or slow "
            "(alone or with integration or browser); see CONTRIBUTING.md\n  " + "\n  ".join(bad))

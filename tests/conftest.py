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
import functools
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
PROCESSES = "processes"  # the one xdist scope of every test file but the unit tier's, in the whole suite
# The whole suite on two workers: one runs the unit tier, the other every other test file, in order. These files
# go first in that order: they run lock-step swarms, compile, or type-check (none of them times anything in
# real time), so the minutes the unit tests load the machine are not the minutes a real-time swarm runs.
PROCESSES_FIRST = ("tests/integration/test_userlaw_runs.py", "tests/integration/test_cli_sim.py",
                   "tests/integration/test_campaign.py", "tests/protocol/test_types.py",
                   "tests/protocol/test_layers.py", "tests/protocol/test_docs.py", "tests/integration/test_docs_site.py")
COLLECTED = pytest.StashKey[list]()  # config.stash: every test collected, before any is deselected
SPLIT_ENV = "SWARM_TEST_SPLIT"  # set by the controller of a whole-suite run: its workers order the tests (PROCESSES_FIRST)


def _xdist_usable(config: pytest.Config) -> bool:
    opt = config.option
    return config.pluginmanager.hasplugin("xdist") and getattr(opt, "numprocesses", None) is None and not (
        os.environ.get("SWARM_TEST_SERIAL") or os.environ.get("PYTEST_XDIST_WORKER") or getattr(opt, "usepdb", False))


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config: pytest.Config) -> None:
    """Two selections run on pytest-xdist's workers when it is installed. `pytest -m unit` alone: on UNIT_WORKERS
    processes (the unit tier is CPU bound and has no shared state between tests). The whole suite (`pytest`, no
    path, -m or -k): on two, one for the unit tier and one for every other test file, one after another (they
    start processes and routers of their own, on ports and namespaces that two of them at once would share:
    pytest_xdist_make_scheduler), so the unit tier costs no time of its own. Any other selection, an explicit -n
    (-n 0 included), -x, --maxfail, --sw, `-p no:xdist`, or SWARM_TEST_SERIAL=1 runs in this process as usual."""
    opt = config.option
    if not _xdist_usable(config) or (os.cpu_count() or 1) < 2:
        return
    mark = (getattr(opt, "markexpr", "") or "").strip()
    if mark == "unit":
        opt.numprocesses = min(UNIT_WORKERS, os.cpu_count() or 1)
        if getattr(opt, "dist", "no") == "no":
            opt.dist = "load"
    elif not mark and not getattr(opt, "keyword", "") and not getattr(opt, "file_or_dir", None) and \
            getattr(opt, "dist", "no") == "no" and not getattr(opt, "maxfail", 0) and not getattr(opt, "stepwise", False):
        # (-x, --maxfail, --sw: one process, which stops where asked; the worker of the other tests would not)
        opt.numprocesses, opt.dist = 2, "load"
        os.environ[SPLIT_ENV] = "1"  # the workers inherit it


def _marks(node) -> set[str]:
    """The tier names in `pytest.mark.<tier>` expressions under an AST node (decorators, a pytestmark value)."""
    import ast

    return {n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute) and n.attr in TIERS and
            isinstance(n.value, ast.Attribute) and n.value.attr == "mark"}


@functools.cache
def _tiers_of_file(path: str) -> tuple[frozenset[str], dict[str, frozenset[str]]] | None:
    """(the module's pytestmark tiers, {test or class name: its decorators' tiers}) of a test file, or None when
    it cannot be read."""
    import ast

    try:
        tree = ast.parse((TESTS.parent / path).read_text())
    except (OSError, SyntaxError):
        return None
    module: set[str] = set()
    named: dict[str, frozenset[str]] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            module |= _marks(node.value)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            named[node.name] = frozenset(set().union(*[_marks(d) for d in node.decorator_list]))
            for sub in node.body if isinstance(node, ast.ClassDef) else ():
                if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    named[f"{node.name}::{sub.name}"] = frozenset(set().union(*[_marks(d) for d in sub.decorator_list]))
    return frozenset(module), named


def unit_test(nodeid: str) -> bool:
    """Whether a test is of the unit tier, read from its file's text (the controller of an xdist run collects
    nothing): its own or its class's tier decorators, else the module's pytestmark. Whatever this cannot tell
    counts as not a unit test: at worst a unit test runs in the PROCESSES scope, one after another with the rest."""
    path, _, rest = nodeid.partition("::")
    tiers = _tiers_of_file(path)
    if tiers is None or not rest:
        return False
    module, named = tiers
    names = [name.split("[", 1)[0] for name in rest.split("::")]
    marks = set(module) | named.get(names[0], frozenset()) | named.get("::".join(names[:2]), frozenset())
    return marks == {"unit"}


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist's: unknown under -p no:xdist
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """The whole suite's two workers (pytest_cmdline_main): xdist's scope scheduling, each unit-tier test its own
    scope, every other file's tests one scope (PROCESSES), the largest, which the first worker takes whole.
    (xdist's own --dist loadgroup would do it by marker, but its groups are lost on pytest 9's node ids.)"""
    if not os.environ.get(SPLIT_ENV):
        return None
    from xdist.scheduler import LoadScopeScheduling

    class TierScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return nodeid if unit_test(nodeid) else PROCESSES

    return TierScheduling(config, log)


@pytest.fixture
def collected_tests(request) -> list[pytest.Item]:
    """Every test this run collected, before -m or -k deselected any (tests/unit/test_suite_split.py)."""
    return request.config.stash[COLLECTED]


def _processes_in_order(config: pytest.Config, items: list[pytest.Item]) -> None:
    """PROCESSES_FIRST's files first (a stable sort: the same order on every worker, as xdist requires)."""
    if os.environ.get(SPLIT_ENV):
        first = {f: i for i, f in enumerate(PROCESSES_FIRST)}
        items.sort(key=lambda it: first.get(it.nodeid.split("::")[0], len(first)))


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
    config.stash[COLLECTED] = list(items)  # every test collected, before -m or -k deselects (test_suite_split.py)
    if bad:
        raise pytest.UsageError(
            "every test needs exactly one tier marker: @pytest.mark.unit, integration or browser, or slow "
            "(alone or with integration or browser); see CONTRIBUTING.md\n  " + "\n  ".join(bad))
    _processes_in_order(config, items)

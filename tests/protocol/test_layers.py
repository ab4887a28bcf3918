"""The layers of docs/architecture.md, as tests.

- swarm.core and swarm.proto are pure: imported in a fresh interpreter they load no zenoh, no
  meshcat, no matplotlib; numba only in jit, the kernels and sim; no module of theirs imports subprocess.
- agents/ imports nothing of world/ or swarm.view; world/ nothing of agents/ or swarm.view; neither anything of
  swarm.launch or swarm.cli above them (what a process does to itself is swarm.process, below them).
- no import cycle of any length among the project's modules, imports inside functions included.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("swarm", "agents", "world")


def _modules() -> dict[str, Path]:
    """Every module of the project: dotted name -> file."""
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """The project modules `name` imports anywhere in its file (top level or inside functions)."""
    path = MODULES[name]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")
                base = ".".join(up[:len(up) - node.level + 1] + ([base] if base else []))
            # "from pkg import mod" imports the module pkg.mod; "from mod import name" the module mod
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in MODULES:  # import a.b.c of a non-module attribute: its module
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


GRAPH = {name: _imports(name) for name in MODULES}

CORE = sorted(m for m in MODULES if m.startswith(("swarm.core.", "swarm.proto.")))
COMPILED = {"swarm.core.jit", "swarm.core.kernel", "swarm.core.faultkernel", "swarm.core.sim"}


@pytest.mark.unit
def test_the_walk_finds_the_layers():
    assert {"swarm.core.law", "swarm.proto.keys", "swarm.net.bus", "agents.robot", "world.world",
            "swarm.cli.main"} <= set(MODULES)
    assert "swarm.core.law" in GRAPH["agents.lockstep"] and "agents.agent" in GRAPH["agents.robot"]


@pytest.mark.unit
def test_no_import_cycle():
    """Tarjan's strongly connected components over the module graph: none may hold two modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(GRAPH[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    sys.setrecursionlimit(10_000)
    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    assert cycles == [], f"import cycles: {cycles}"


def _reaches(start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for w in GRAPH[todo.pop()]:
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


@pytest.mark.unit
@pytest.mark.parametrize("module", [m for m in MODULES if m.startswith("agents")])
def test_agents_import_nothing_of_world_or_view(module):
    bad = sorted(m for m in _reaches(module) if m.startswith(("world", "swarm.view", "swarm.launch", "swarm.cli")))
    assert bad == [], f"{module} reaches {bad}"


@pytest.mark.unit
@pytest.mark.parametrize("module", [m for m in MODULES if m.startswith("world")])
def test_world_imports_nothing_of_agents_or_view(module):
    bad = sorted(m for m in _reaches(module) if m.startswith(("agents", "swarm.view", "swarm.launch", "swarm.cli")))
    assert bad == [], f"{module} reaches {bad}"


@pytest.mark.unit
@pytest.mark.parametrize("module", CORE)
def test_pure_layers_reach_no_process_or_view_code(module):
    """core and proto reach only core and proto (never net, launch, view or cli), and no module
    they reach names subprocess."""
    reach = _reaches(module) | {module}
    outside = sorted(m for m in reach if not m.startswith(("swarm.core", "swarm.proto")))
    assert outside == [], f"{module} reaches {outside}"
    for m in reach:
        text = MODULES[m].read_text(encoding="utf-8")
        assert "import subprocess" not in text and "from subprocess" not in text, f"{m} imports subprocess"


@pytest.mark.integration
@pytest.mark.parametrize("module", CORE)
def test_pure_module_loads_no_transport_viewer_or_compiler(module):
    forbidden = ("zenoh", "meshcat", "matplotlib") + (() if module in COMPILED else ("numba", "subprocess"))
    code = (f"import sys, {module}; bad = [m for m in {forbidden!r} if m in sys.modules]; print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "", f"{module} pulled in {out.stdout.strip()}"


@pytest.mark.unit
def test_only_the_bus_touches_zenoh():
    users = sorted(m for m, p in MODULES.items() if "import zenoh" in p.read_text(encoding="utf-8"))
    assert all(m.startswith("swarm.net") for m in users), users


MODULE_LINES_MAX = 800  # docs/architecture.md: a module a new engineer can read through
CLASS_LINES_MAX = 400


@pytest.mark.unit
def test_no_module_or_class_outgrows_a_reading():
    """Every module of swarm/, agents/ and world/ (and every C file) under MODULE_LINES_MAX lines and every class under
    CLASS_LINES_MAX: a concern that outgrows that is split into a layer of its own (as agents/ and world/ are)."""
    big = []
    for name, path in MODULES.items():
        text = path.read_text(encoding="utf-8")
        if len(text.splitlines()) > MODULE_LINES_MAX:
            big.append(f"module {name}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > CLASS_LINES_MAX:
                big.append(f"class {name}.{node.name}: {node.end_lineno - node.lineno + 1} lines")
    for path in [*ROOT.glob("swarm/**/*.c"), *ROOT.glob("swarm/**/*.h")]:  # the compiled parts too
        if len(path.read_text(encoding="utf-8").splitlines()) > MODULE_LINES_MAX:
            big.append(f"{path.relative_to(ROOT)}: {len(path.read_text(encoding='utf-8').splitlines())} lines")
    assert not big, "; ".join(big)

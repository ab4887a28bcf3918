"""One error hierarchy: every exception class of the project derives from swarm.core.errors.SwarmError (directly, or
through another of the project's), so `except SwarmError` catches every error swarm raises on purpose."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]
BUILTIN = {"Exception", "BaseException", "ValueError", "RuntimeError", "OSError", "KeyError", "TypeError",
           "LookupError", "ArithmeticError", "IOError"}


def _classes() -> list[tuple[str, str, list[str]]]:
    """Every top-level class of swarm/, agents/ and world/: (name, where, its bases' names); two modules may each
    have a class of one name (agents.intake.Intake, world.intake.Intake)."""
    out = []
    for pkg in ("swarm", "agents", "world"):
        for path in (ROOT / pkg).rglob("*.py"):
            for node in ast.parse(path.read_text(encoding="utf-8")).body:
                if isinstance(node, ast.ClassDef):
                    bases = [b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else ""
                             for b in node.bases]
                    out.append((node.name, str(path.relative_to(ROOT)), bases))
    return out


def test_every_exception_class_derives_from_swarm_error():
    classes = _classes()
    by_name: dict[str, list[list[str]]] = {}
    for name, _, bases in classes:
        by_name.setdefault(name, []).append(bases)

    def derives(name: str, roots: set[str], seen: frozenset = frozenset()) -> bool:
        """Some class of this name has one of roots among its ancestors (a base of a name defined twice: either)."""
        if name in roots:
            return True
        if name not in by_name or name in seen:
            return False
        return any(derives(b, roots, seen | {name}) for bases in by_name[name] for b in bases)

    errors = sorted((where, n, bases) for n, where, bases in classes
                    if n != "SwarmError" and any(derives(b, BUILTIN) for b in bases))
    assert len(errors) >= 20, errors  # the scan found them
    assert [f"{where}: {n}" for where, n, bases in errors if not any(derives(b, {"SwarmError"}) for b in bases)] == []

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


def _classes() -> dict[str, tuple[str, list[str]]]:
    """Every top-level class of swarm/, agents/ and world/: name -> (where, its bases' names)."""
    out = {}
    for pkg in ("swarm", "agents", "world"):
        for path in (ROOT / pkg).rglob("*.py"):
            for node in ast.parse(path.read_text(encoding="utf-8")).body:
                if isinstance(node, ast.ClassDef):
                    bases = [b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else ""
                             for b in node.bases]
                    out[node.name] = (str(path.relative_to(ROOT)), bases)
    return out


def test_every_exception_class_derives_from_swarm_error():
    classes = _classes()

    def swarm_error(name: str, seen: frozenset = frozenset()) -> bool:
        if name == "SwarmError":
            return True
        if name not in classes or name in seen:
            return False
        return any(swarm_error(b, seen | {name}) for b in classes[name][1])

    def an_exception(name: str, seen: frozenset = frozenset()) -> bool:
        if name in BUILTIN:
            return True
        if name not in classes or name in seen:
            return False
        return any(an_exception(b, seen | {name}) for b in classes[name][1])

    errors = sorted(n for n, (_, bases) in classes.items() if n != "SwarmError" and any(map(an_exception, bases)))
    assert len(errors) >= 20, errors  # the scan found them
    assert [f"{classes[n][0]}: {n}" for n in errors if not swarm_error(n)] == []

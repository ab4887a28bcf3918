"""The one reader of the project's TOML files (scenario, faults, inventory): typed access to a parsed document
whose every refusal is a ScenarioError naming the file, the dotted key and the reason (exit 2 on the command line).

    doc = read_toml(path, "faults file (TOML)")      # ScenarioError: missing, not a file, not UTF-8, not TOML
    rd = Reader(path)
    run = rd.table(doc["run"], "run", allowed=("duration", "dt"), required=("duration",))
    dt = rd.number(run.get("dt", 0.001), "run.dt", gt=0)

Pure: no I/O but read_toml's read of its file.
"""

from __future__ import annotations

import math
import tomllib
from typing import Any

from swarm.core.errors import ScenarioError, read_text_file


def read_toml(path: str, what: str = "file (TOML)") -> dict[str, Any]:
    """The parsed TOML document at `path`; ScenarioError naming the file for anything that keeps it from one."""
    text = read_text_file(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(path, "", f"not valid TOML: {e}") from None


def kind(value: Any) -> str:
    """What a TOML value is, in words ("a table", "an integer")."""
    names = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "a list", dict: "a table"}
    return names.get(type(value), type(value).__name__)


def show(value: Any) -> str:
    """A value for an error message, cut at 60 characters."""
    s = repr(value)
    return s if len(s) <= 60 else s[:57] + "..."


def join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


class Reader:
    """Typed access to a parsed TOML document; every refusal names `where` and the dotted key."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, key: str, reason: str) -> ScenarioError:
        return ScenarioError(self.where, key, reason)

    def table(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, f"must be a table, got {kind(value)}")
        for k in value:
            if k not in allowed:
                raise self.fail(join(key, k), f"unknown key (allowed here: {', '.join(allowed)})")
        for k in required:
            if k not in value:
                raise self.fail(join(key, k), "missing required key")
        return value

    def tables(self, value: Any, key: str, most: int) -> list[dict[str, Any]]:
        """An array of at most `most` tables ([[key]])."""
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.fail(key, f"must be an array of tables ([[{key}]]), got {kind(value)}")
        if len(value) > most:
            raise self.fail(key, f"lists {len(value)} entries; at most {most}")
        return value

    def number(self, value: Any, key: str, *, gt: float | None = None, ge: float | None = None,
               bound: float | None = None, why: str = "") -> float:
        """A finite number; gt / ge: lower limits; bound: |x| <= bound (why: the bound's reason, for the message)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number, got {kind(value)}")
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the float range
            x = math.inf
        if not math.isfinite(x):
            raise self.fail(key, f"must be finite, got {value}")
        if bound is not None and abs(x) > bound:
            raise self.fail(key, f"must be at most {bound:g} in size{f' ({why})' if why else ''}, got {value}")
        if gt is not None and not x > gt:
            raise self.fail(key, f"must be > {gt:g}, got {value}")
        if ge is not None and not x >= ge:
            raise self.fail(key, f"must be >= {ge:g}, got {value}")
        return x

    def integer(self, value: Any, key: str, *, ge: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"must be an integer, got {kind(value)}"
                                 + (f" ({show(value)})" if isinstance(value, (float, str)) else ""))
        if value < ge:
            raise self.fail(key, f"must be >= {ge}, got {value}")
        return value

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, got {kind(value)}")
        return value

    def choice(self, value: Any, key: str, options: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in options:
            raise self.fail(key, f"must be one of {', '.join(repr(o) for o in options)}, got {value!r}")
        return value

    def vector(self, value: Any, key: str, length: int, what: str, bound: float | None = None) -> list[float]:
        if not isinstance(value, list) or len(value) != length:
            raise self.fail(key, f"must be a list of {length} numbers [{what}], got {show(value)}")
        return [self.number(v, f"{key}[{i}]", bound=bound) for i, v in enumerate(value)]

    def time(self, value: Any, key: str) -> float:
        """A time >= 0 [s from the start of the run]."""
        t = self.number(value, key)
        if t < 0:
            raise self.fail(key, f"must be >= 0 s (times count from the start of the run), got {t:g}")
        return t

    def robot(self, value: Any, key: str, robots: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(key, f"must be a robot id (an integer), got {kind(value)}")
        if not 0 <= value < robots:
            raise self.fail(key, f"robot {value} is not in the scenario (it has {robots} robots: 0..{robots - 1})")
        return value

    def robots(self, value: Any, key: str, robots: int) -> tuple[int, ...]:
        if not isinstance(value, list):
            raise self.fail(key, f"must be a list of robot ids, got {kind(value)}")
        return tuple(self.robot(v, f"{key}[{k}]", robots) for k, v in enumerate(value))

"""Compiled copies of the scalar-style modules (the law, kinematics, the grid).

The control law is written once, in plain scalar Python that numba can compile
(`swarm.core.law`, `swarm.core.kinematics`, `swarm.core.grid`). A robot process imports those
modules as they are and never loads numba. The batched simulator calls
`compiled("swarm.core.law")`, which executes the same source file a second time as a
separate module (`swarm.core.law_jit`) whose `@_jit` decorator is `numba.njit`. One source,
two executions: there is no second implementation to drift. (A robot process may run a C
transcription of robot_command instead, swarm/core/_law.c through swarm.core.fastlaw, which a test
holds to law.py's bits: docs/design.md.)

Compiled code is cached on disk under a directory named after a hash of every
kernel source file, so an edited law can never run against a stale cache (numba's
own cache does not track changes in called functions of other files).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Protocol, TypeVar, cast

_F = TypeVar("_F", bound=Callable[..., Any])


class Jit(Protocol):
    """The type of `_jit` in a scalar-style module: the identity in plain Python, `njit` in its compiled twin."""

    def __call__(self, fn: _F, /) -> _F: ...


# Every module whose source ends up inside a compiled kernel, and this one (how they are compiled).
KERNEL_SOURCES = ("swarm.core.jit", "swarm.core.law", "swarm.core.kinematics", "swarm.core.grid", "swarm.core.kernel",
                  "swarm.core.metrics", "swarm.core.faultgen", "swarm.core.faultkernel", "swarm.core.lawplug")


def _source_path(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ImportError(f"cannot find the source of {name}")
    return Path(spec.origin)


def cache_dir() -> Path:
    """Where compiled kernels are cached: $SWARM_CACHE_DIR, else ~/.cache/swarm, plus a source hash."""
    h = hashlib.sha256()
    for name in KERNEL_SOURCES:
        h.update(_source_path(name).read_bytes())
    base = os.environ.get("SWARM_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "swarm"
    )
    return Path(base) / f"numba-{h.hexdigest()[:16]}"


_numba_ready = False


def _setup_numba() -> None:
    global _numba_ready
    if _numba_ready:
        return
    import numba

    if not os.environ.get("NUMBA_CACHE_DIR"):
        d = cache_dir()
        try:
            d.mkdir(parents=True, exist_ok=True)
            cast(Any, numba.config).CACHE_DIR = str(d)  # numba sets its config names through globals()
        except OSError:
            pass  # read-only home: numba falls back to compiling in memory each run
    _numba_ready = True


_caching = True  # off while compiling what must not be cached (a kernel calling Python: swarm.core.userlaw)


def _njit(fn: _F, **options: Any) -> _F:
    """numba.njit with the on-disk cache and numpy's error model, plus `options`."""
    _setup_numba()
    import numba

    return cast(_F, numba.njit(cache=_caching, error_model="numpy", **options)(fn))


def njit(fn: _F) -> _F:
    """numba.njit with the on-disk cache (the kernel's own decorator)."""
    return _njit(fn)


def njit_leaf(fn: _F) -> _F:
    """njit without numba's reference counting (_nrt, not in numba's stubs), for functions that only read and
    write arrays they are given."""
    return _njit(fn, _nrt=False)


def njit_inlined(fn: _F) -> _F:
    """njit_leaf, inlined into every caller by LLVM (a call of many arrays copies them all)."""
    return _njit(fn, _nrt=False, forceinline=True)


def njit_parallel(fn: _F) -> _F:
    """njit with numba's parallel loops (prange), on all the threads numba is allowed."""
    return _njit(fn, parallel=True)


# The scalar-style modules compiled with njit_leaf: none allocates, slices or returns an array.
LEAVES = ("swarm.core.law", "swarm.core.kinematics", "swarm.core.grid", "swarm.core.faultgen")


@contextmanager
def cache_in(path: Path, cached: bool = True) -> Iterator[None]:
    """numba's cache directory is `path` for the functions decorated inside (a dispatcher reads it then); where
    that cannot be (NUMBA_CACHE_DIR set, no directory), or cached is False, they are not cached at all: numba
    tells a cached function by its source file and name, which every twin of a module shares (a law's kernels
    and the parallel kernel with the paper's)."""
    global _caching
    _setup_numba()
    import numba

    config: Any = numba.config
    before, caching = config.CACHE_DIR, _caching
    own = False
    if cached and not os.environ.get("NUMBA_CACHE_DIR"):
        try:
            path.mkdir(parents=True, exist_ok=True)
            config.CACHE_DIR = str(path)
            own = True
        except OSError:
            pass
    _caching = own
    try:
        yield
    finally:
        config.CACHE_DIR = before
        _caching = caching


def compiled(name: str, suffix: str = "_jit", bind: dict[str, Any] | None = None) -> ModuleType:
    """Return the compiled twin of scalar-style module `name` (e.g. "swarm.core.law").

    suffix and bind make another twin: module `name + suffix`, its globals `bind` set before its source runs
    (swarm.core.userlaw binds a user's law this way; its caller picks numba's cache directory)."""
    jit_name = name + suffix
    mod = sys.modules.get(jit_name)
    if mod is not None:
        return mod
    _setup_numba()
    spec = importlib.util.spec_from_file_location(jit_name, _source_path(name))
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    mod.__dict__["__swarm_jit__"] = njit_leaf if name in LEAVES else njit
    mod.__dict__.update(bind or {})
    # numba's cache re-imports a function's module by name when it loads compiled code.
    sys.modules[jit_name] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        del sys.modules[jit_name]
        raise
    return mod

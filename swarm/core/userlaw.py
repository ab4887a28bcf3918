"""A user's control law (docs/control.md): naming it in a scenario, loading it, its compiled copy, and the check
that the compiled copy and the Python agree.

    spec = parse_control(reader, ctl, base_dir)     # [control] law / params / memory -> LawSpec, or None: the paper
    law = load(spec)                                 # imports the file or module, checks the signature and sha256
    command = law.command(compiled=True)             # robot_command's signature (swarm.core.lawplug.plugin_command)
    kernel, faultkernel = law.kernels()              # the simulator's kernels calling it, compiled by numba
    problems = check(law, samples=200, seed=0)       # test calls: errors, non-finite results, compiled != Python

The law's contract: `NAME(me, ref, bodies, params) -> (v, w)`, plus any of the keyword-only arguments `t`,
`mem` and `kinds` it declares (swarm.core.lawplug says what each holds). numba calls a function's keyword-only
arguments by position, wrongly: the law runs as a copy whose keyword-only arguments are positional
(`_positional`), behind an adapter with one fixed signature, call(me, ref, bodies, params, t, mem, kinds).

Compiled copies are cached on disk like the kernels (swarm.core.jit), in a directory of their own per law file
(its sha256): numba keys its cache by source file and function, not by the globals a module was run with, and
the kernels run here with the user's law bound in are the same source files as the paper's.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import keyword
import math
import os
import re
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, cast

import numpy as np

from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from swarm.core.toml_reader import Reader

PAPER = "paper"
EXTRAS = ("t", "mem", "kinds")  # the keyword-only arguments a law may declare
MAX_PARAMS = 64
MAX_MEMORY = 1024
MAX_SAMPLE_BODIES = 8  # bodies in one random test call (check)


class LawError(SwarmError, ValueError):
    """A user's law cannot be used: its file or module, its name, its signature, numba, or its results."""


@dataclass(frozen=True)
class LawSpec:
    """Which law a run uses ([control] law), and what it is given: params, and memory floats per robot.

    ref is where a process finds it, "/abs/path/file.py:NAME" or "package.module:NAME"; sha256 is that of the
    file that defines it (every robot checks its own copy against it)."""

    text: str
    ref: str
    sha256: str
    params: tuple[float, ...] = ()
    memory: int = 0

    @property
    def name(self) -> str:
        return self.ref.rpartition(":")[2]

    @property
    def is_file(self) -> bool:
        return self.ref.rpartition(":")[0].endswith(".py")


def failure_text(e: Exception) -> str:
    """What a law's exception says in a failure line: its type and message, and for an IndexError (a compiled law
    is bounds checked: numba's message names no array) which arrays a law indexes."""
    text = f"{type(e).__name__}: {e}"
    if isinstance(e, IndexError):
        text += " (an index past the end of params: control.params's length, mem: control.memory, or bodies' rows)"
    return text


def sha256_of(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def locate(text: str, base: Path | None) -> tuple[str, Path]:
    """(ref, the source file) of a law named "FILE.py:NAME" (relative to base) or "package.module:NAME"."""
    where, sep, name = text.rpartition(":")
    if not sep or not where or not name:
        raise LawError(f"must be \"paper\", \"FILE.py:NAME\" or \"package.module:NAME\", got {text!r}")
    if not name.isidentifier() or keyword.iskeyword(name):
        raise LawError(f"{name!r} (after the colon) is not a Python name")
    if where.endswith(".py"):
        path = Path(where).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        path = path.resolve()
        if not path.is_file():
            raise LawError(f"no file {path} (a law's file is relative to the scenario file)")
        return f"{path}:{name}", path
    if not all(part.isidentifier() for part in where.split(".")):
        raise LawError(f"{where!r} is neither a file ending in .py nor a module name (package.module)")
    source = module_source(where)
    if source is None:
        raise LawError(f"no module {where!r} with a Python source file on this machine's Python path")
    return f"{where}:{name}", source


def parse_control(rd: Reader, ctl: dict[str, Any], base: Path | None) -> LawSpec | None:
    """The [control] table's law, params and memory (None: the paper's law, which takes neither)."""
    text = ctl.get("law", PAPER)
    if not isinstance(text, str):
        raise rd.fail("control.law", f"must be a string (\"paper\", \"FILE.py:NAME\" or \"package.module:NAME\"), "
                      f"got {type(text).__name__}")
    raw = ctl.get("params", [])
    if not isinstance(raw, list) or len(raw) > MAX_PARAMS:
        raise rd.fail("control.params", f"must be a list of at most {MAX_PARAMS} numbers")
    params = tuple(rd.number(v, f"control.params[{i}]") for i, v in enumerate(raw))
    memory = rd.integer(ctl.get("memory", 0), "control.memory")
    if memory > MAX_MEMORY:
        raise rd.fail("control.memory", f"must be at most {MAX_MEMORY} floats a robot, got {memory}")
    if text == PAPER:
        for key, given in (("params", params), ("memory", memory)):
            if given:
                raise rd.fail(f"control.{key}", "is for a law of your own (control.law = \"FILE.py:NAME\"); the "
                              "paper's law takes its gains from k1, k2, k3")
        return None
    try:
        ref, path = locate(text, base)
    except LawError as e:
        raise rd.fail("control.law", str(e)) from None
    return LawSpec(text, ref, sha256_of(path), params, memory)


_IMPORTED: dict[str, str] = {}  # a module law's module name -> the sha256 of the file it was imported from


def _module_of(spec: LawSpec) -> types.ModuleType:
    where = spec.ref.rpartition(":")[0]
    if not spec.is_file:
        try:
            mod = importlib.import_module(where)
            if _IMPORTED.setdefault(where, spec.sha256) != spec.sha256:  # edited since: the file's code, not the old
                mod = importlib.reload(mod)
                _IMPORTED[where] = spec.sha256
            return mod
        except Exception as e:
            raise LawError(f"law {spec.text!r}: importing {where} failed: {type(e).__name__}: {e}") from None
    name = f"swarm_law_{spec.sha256[:16]}"
    loaded = sys.modules.get(name)
    if loaded is not None:
        return loaded
    imp = importlib.util.spec_from_file_location(name, where)
    if imp is None or imp.loader is None:
        raise LawError(f"law {spec.text!r}: cannot load {where} as Python")
    mod = importlib.util.module_from_spec(imp)
    sys.modules[name] = mod  # numba reads a cached function's module by name
    try:
        imp.loader.exec_module(mod)
    except Exception as e:
        del sys.modules[name]
        raise LawError(f"law {spec.text!r}: running {where} failed: {type(e).__name__}: {e}") from None
    return mod


def module_source(where: str) -> Path | None:
    """The source file of module `where` (dotted), found on sys.path without importing anything (a name from the
    network must not run a package's code before its file's sha256 is checked); None if there is none."""
    from importlib.machinery import PathFinder

    parts = where.split(".")
    if not parts or not all(p.isidentifier() for p in parts):
        return None
    search: Any = None
    found = None
    for k in range(len(parts)):
        try:
            found = PathFinder.find_spec(".".join(parts[:k + 1]), search)
        except (ImportError, ValueError, OSError):
            return None
        if found is None:
            return None
        search = found.submodule_search_locations
        if k < len(parts) - 1 and search is None:
            return None
    origin = found.origin if found is not None else None
    return Path(origin) if origin and origin.endswith(".py") and Path(origin).is_file() else None


def _positional(fn: types.FunctionType) -> types.FunctionType:
    """fn with its keyword-only arguments made positional, in their order (numba binds them wrongly)."""
    code = fn.__code__
    code = code.replace(co_argcount=code.co_argcount + code.co_kwonlyargcount, co_kwonlyargcount=0)
    out = types.FunctionType(code, fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__)
    out.__qualname__ = fn.__qualname__
    return out


def signature_extras(fn: Callable[..., Any], what: str) -> tuple[str, ...]:
    """The keyword-only arguments fn declares, after checking its signature against the contract."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError) as e:
        raise LawError(f"{what}: no signature to read ({e})") from None
    positional, extras = [], []
    for p in sig.parameters.values():
        if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            raise LawError(f"{what}: takes *{p.name}; the contract is NAME(me, ref, bodies, params) with optional "
                           f"keyword-only {', '.join(EXTRAS)}")
        if p.kind == p.KEYWORD_ONLY:
            if p.name not in EXTRAS:
                raise LawError(f"{what}: keyword-only argument {p.name!r} is none of {', '.join(EXTRAS)}")
            extras.append(p.name)
        else:
            positional.append(p.name)
    if len(positional) != 4:
        raise LawError(f"{what}: takes {len(positional)} positional argument(s) ({', '.join(positional) or 'none'}); "
                       "the contract is NAME(me, ref, bodies, params) with optional keyword-only "
                       f"{', '.join(EXTRAS)}")
    return tuple(extras)




@dataclass
class Law:
    """A loaded law: its spec, the function, and its compiled copies once asked for.

    cached: its compiled copies may go to (and come from) numba's disk cache. True for a law loaded from its
    file or module (the key covers the file's sha256, the name and the keyword arguments it takes); False for a
    function handed over in Python (swarm.simulate(law=fn)), whose globals and closure no hash covers."""

    spec: LawSpec
    fn: types.FunctionType
    extras: tuple[str, ...]
    cached: bool = True
    _built: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def label(self) -> str:
        return self.spec.text

    @property
    def key(self) -> str:
        """What names this law's compiled modules and cache directory: the file's sha256, the function's name and
        the keyword arguments it declares (two laws of one file compile apart); a function handed over in Python
        adds its identity in this process."""
        text = f"{self.spec.sha256}:{self.spec.name}:{','.join(self.extras)}:boundscheck"
        if not self.cached:
            text += f":{id(self.fn)}"
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def _adapter_source(self) -> str:
        args = ", ".join(("me", "ref", "bodies", "params") + self.extras)
        return (f"# swarm's adapter for law {self.spec.ref} (sha256 {self.spec.sha256}): the runtime's fixed\n"
                f"# arguments (me, ref, bodies, params, t, mem, kinds), the ones the law declares.\n"
                f"def call(me, ref, bodies, params, t, mem, kinds):\n    return law({args})\n")

    def cache_dir(self) -> Path:
        from swarm.core import jit

        return jit.cache_dir() / f"law-{self.key}"

    def call(self, compiled: bool) -> Callable[..., Any]:
        """The law behind the fixed signature call(me, ref, bodies, params, t, mem, kinds)."""
        key = "call-jit" if compiled else "call-py"
        if key in self._built:
            return cast(Callable[..., Any], self._built[key])
        law: Any = _positional(self.fn)
        if not compiled:
            fn = self._adapter(law)
        else:
            import numba

            from swarm.core import jit

            with jit.cache_in(self.cache_dir(), self.cached):
                # bounds checked: compiled code reads past an array without a word (a law that reads params[3] of
                # three got whatever lay beyond) and writes past it into the heap; checked, it raises IndexError,
                # which ends the run naming the robot and the step, as any exception of the law
                law = numba.njit(error_model="numpy", boundscheck=True)(law)
                fn = None
                if jit._caching:  # its own cache directory: the adapter from a file there, which numba can cache
                    try:
                        fn = jit.njit(self._adapter_file(law))
                    except OSError:
                        fn = None
                if fn is None:  # compiled in memory, every run
                    fn = numba.njit(error_model="numpy")(self._adapter(law))
        self._built[key] = fn
        return cast(Callable[..., Any], fn)

    def _adapter(self, law: Any) -> Any:
        """call(me, ref, bodies, params, t, mem, kinds) calling `law` with the arguments it declares, in memory."""
        ns: dict[str, Any] = {"__name__": f"swarm_law_call_{self.key}", "law": law}
        exec(compile(self._adapter_source(), f"<adapter of {self.spec.ref}>", "exec"), ns)
        return ns["call"]

    def _adapter_file(self, law: Any) -> Any:
        """The same adapter, from a file in the law's cache directory (written whole: robots start together)."""
        source, target = self._adapter_source(), self.cache_dir() / "adapter.py"
        if not target.is_file() or target.read_text() != source:
            tmp = target.with_name(f"adapter.{os.getpid()}.tmp")
            tmp.write_text(source)
            os.replace(tmp, target)
        name = f"swarm_law_call_{self.key}"
        imp = importlib.util.spec_from_file_location(name, target)
        assert imp is not None and imp.loader is not None
        mod = importlib.util.module_from_spec(imp)
        mod.__dict__["law"] = law
        sys.modules[name] = mod
        imp.loader.exec_module(mod)
        return mod.call

    def _bound(self, compiled: bool) -> dict[str, Any]:
        from swarm.core import law as paper

        if compiled:
            from swarm.core import jit

            return {"__swarm_law__": jit.compiled("swarm.core.law"), "__swarm_law_call__": self.call(True)}
        return {"__swarm_law__": paper, "__swarm_law_call__": self.call(False)}

    def command(self, compiled: bool) -> Callable[..., tuple[float, float]]:
        """plugin_command (swarm.core.lawplug) with this law bound: robot_command's signature."""
        key = "command-jit" if compiled else "command-py"
        if key in self._built:
            return cast(Callable[..., tuple[float, float]], self._built[key])
        suffix = f"_{self.key}"
        if compiled:
            from swarm.core import jit

            with jit.cache_in(self.cache_dir(), self.cached):
                mod = jit.compiled("swarm.core.lawplug", suffix + "_jit", self._bound(True))
        else:
            spec = importlib.util.find_spec("swarm.core.lawplug")
            assert spec is not None and spec.origin is not None
            name = "swarm.core.lawplug" + suffix + "_py"
            mod = sys.modules.get(name) or types.ModuleType(name)
            if name not in sys.modules:
                mod.__dict__.update(self._bound(False))
                sys.modules[name] = mod
                exec(compile(Path(spec.origin).read_text(), spec.origin, "exec"), mod.__dict__)
        self._built[key] = mod.plugin_command
        return cast(Callable[..., tuple[float, float]], mod.plugin_command)

    def kernels(self) -> tuple[types.ModuleType, types.ModuleType]:
        """(kernel, faultkernel) compiled with this law's command in place of the paper's."""
        from swarm.core import jit

        command = self.command(True)
        suffix = f"_{self.key}_jit"
        with jit.cache_in(self.cache_dir(), self.cached):
            kernel = jit.compiled("swarm.core.kernel", suffix, {"__swarm_command__": command})
            faultkernel = jit.compiled("swarm.core.faultkernel", suffix, {"__swarm_command__": command})
        return kernel, faultkernel

    def python_kernels(self) -> tuple[types.ModuleType, types.ModuleType]:
        """(kernel, faultkernel) compiled around this law run as plain Python (_python_kernels)."""
        return _python_kernels(self)


_OBJMODE = """def call(me, ref, bodies, params, t, mem, kinds):
    with numba.objmode(v="float64", w="float64"):
        v, w = pylaw(me, ref, bodies, params, t, mem, kinds)
    return v, w
"""


def _python_kernels(law: Law) -> tuple[types.ModuleType, types.ModuleType]:
    """The kernels compiled around the law run as plain Python (numba's object mode, a call at a time): for a
    law numba cannot compile (swarm sim --python-law). Never cached: the compiled code holds the function."""
    from swarm.core import jit

    jit._setup_numba()
    import numba

    call = law.call(False)

    def pylaw(*args: Any) -> tuple[float, float]:  # two numbers, or the contract's error (no raise in objmode)
        out = call(*args)
        if len(out) != 2:
            raise ValueError(f"it returned {len(out)} values; the contract is (v, w)")
        return float(out[0]), float(out[1])

    ns: dict[str, Any] = {"numba": numba, "pylaw": pylaw}
    exec(compile(_OBJMODE, f"<Python call of {law.spec.ref}>", "exec"), ns)
    bound = {"__swarm_law__": jit.compiled("swarm.core.law"), "__swarm_law_call__": numba.njit(ns["call"])}
    suffix = f"_{law.key}_pyjit"
    jit._caching = False
    try:
        plug = jit.compiled("swarm.core.lawplug", suffix, bound)
        command = {"__swarm_command__": plug.plugin_command}
        return (jit.compiled("swarm.core.kernel", suffix, command),
                jit.compiled("swarm.core.faultkernel", suffix, command))
    finally:
        jit._caching = True


def load(spec: LawSpec, path: str | None = None) -> Law:
    """Import the law `spec` names (from `path` instead of the file spec.ref names, when given: a robot whose
    copy lives elsewhere) and check its signature and its file's sha256 against the spec's."""
    if path is not None:
        spec = LawSpec(spec.text, f"{Path(path).resolve()}:{spec.name}", spec.sha256, spec.params, spec.memory)
    where = spec.ref.rpartition(":")[0]
    source = Path(where) if spec.is_file else module_source(where)
    if source is None or not source.is_file():
        raise LawError(f"law {spec.text!r}: no {where} on this machine (give the file with --law-file PATH)")
    try:
        digest = sha256_of(source)
    except OSError as e:
        raise LawError(f"law {spec.text!r}: cannot read {source}: {e.strerror or e}") from None
    if digest != spec.sha256:
        raise LawError(f"law {spec.text!r}: {source} has sha256 {digest[:16]}..., the run's is "
                       f"{spec.sha256[:16]}...: this machine's copy of the law differs from the one the run uses")
    mod = _module_of(spec)
    fn = getattr(mod, spec.name, None)
    if fn is None:
        raise LawError(f"law {spec.text!r}: {where} defines no {spec.name!r}")
    py = getattr(fn, "py_func", fn)  # a numba dispatcher: its Python function
    if not isinstance(py, types.FunctionType):
        raise LawError(f"law {spec.text!r}: {spec.name} is a {type(fn).__name__}, not a function")
    return Law(spec, py, signature_extras(py, f"law {spec.text!r}"))


def from_function(fn: Callable[..., Any], params: tuple[float, ...] = (), memory: int = 0) -> Law:
    """A Law of a function given in Python (swarm.simulate(law=fn)): one in a file keeps that file's name and
    sha256; one defined in a notebook or an interpreter is named "<python>:NAME", its sha256 that of its source."""
    py = getattr(fn, "py_func", fn)
    if not isinstance(py, types.FunctionType):
        raise LawError(f"law {fn!r} is a {type(fn).__name__}, not a function")
    name = py.__name__
    extras = signature_extras(py, f"law {name!r}")
    if not 0 <= memory <= MAX_MEMORY or len(params) > MAX_PARAMS:
        raise LawError(f"law {name!r}: at most {MAX_PARAMS} params and 0..{MAX_MEMORY} floats of memory")
    file = inspect.getsourcefile(py)
    if file and Path(file).is_file() and name.isidentifier() and getattr(sys.modules.get(py.__module__), name, None) is fn:
        spec = LawSpec(f"{file}:{name}", f"{Path(file).resolve()}:{name}", sha256_of(file), params, memory)
    else:
        try:
            text = inspect.getsource(py)
        except (OSError, TypeError):
            text = repr(py.__code__.co_code)
        spec = LawSpec(f"<python>:{name}", f"<python>:{name}", hashlib.sha256(text.encode()).hexdigest(), params, memory)
    return Law(spec, py, extras, cached=False)  # its globals and closure are not in any hash: compiled afresh


def sample_inputs(rng: np.random.Generator, params: tuple[float, ...], memory: int
                  ) -> tuple[np.ndarray, ...]:
    """One random call's arguments (me, ref, bodies, params, t, mem, kinds), as a run would give them."""
    me = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi)])
    ref = np.array([me[0] + rng.uniform(-2, 2), me[1] + rng.uniform(-2, 2), rng.uniform(-math.pi, math.pi),
                    rng.uniform(-0.5, 1.0), rng.uniform(-0.5, 0.5)])
    k = int(rng.integers(0, MAX_SAMPLE_BODIES + 1))
    r = rng.uniform(0.1, 0.3, k)
    bodies = np.column_stack([me[0] + rng.uniform(-1.5, 1.5, k), me[1] + rng.uniform(-1.5, 1.5, k), r,
                              r + rng.uniform(0.2, 1.0, k)]).reshape(k, 4)
    kinds = np.sort(rng.integers(0, 3, k)).astype(np.int64)
    return (me, ref, bodies, np.array(params, float), np.array([rng.uniform(0, 100)]),
            rng.uniform(-1, 1, memory), kinds)


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _law_lines(law: Law) -> tuple[str, list[str]] | None:
    """(the file the law's function is in, its lines), or None where inspect cannot tell."""
    try:
        return inspect.getsourcefile(law.fn) or "", inspect.getsource(sys.modules[law.fn.__module__]).splitlines()
    except (TypeError, OSError, KeyError):
        return None


def numba_brief(e: Exception, law: Law) -> str:
    """What numba said about the law, without its colours, its pipeline's stages and the adapter's frame (a file
    of swarm's cache that calls the law): its message, and where in the law's own file, found by the name it
    could not resolve when numba does not say."""
    lines = [line.rstrip() for line in _ANSI.sub("", str(e)).splitlines()]
    said, where, skip = [], [], False
    for line in lines:
        text = line.strip()
        if not text or text.startswith(("Failed in nopython mode pipeline", "During:")):
            skip = False
            continue
        if text.startswith("File "):
            skip = "adapter.py" in text  # its code lines follow, up to a blank line
            if not skip:
                where.append(text.rstrip(":"))
            continue
        if not skip and not where:
            said.append(text)
    out = " ".join(said)[:400] or type(e).__name__
    found = re.search(r"name '(\w+)' is not defined", out)
    src = _law_lines(law) if found and not where else None
    if src is not None and found is not None:
        name = found.group(1)
        hits = [i + 1 for i, line in enumerate(src[1]) if re.search(rf"\b{name}\b", line.split("#")[0])]
        if hits:
            where.append(f"{src[0]}, line {hits[0]}")
    return out + (f" ({'; '.join(where[:2])})" if where else "")


def compile_problem(law: Law) -> str:
    """What numba could not compile in the law, or a result that is not two numbers ("" when all is well): it is
    compiled by a first call, on sample inputs; an exception the law itself raises there is not numba's (check()
    reports it with its inputs)."""
    from numba.core.errors import NumbaError

    try:
        fn = law.call(True)
        out = fn(*_sample_args(sample_inputs(np.random.default_rng(0), law.spec.params, law.spec.memory)))
    except NumbaError as e:
        brief = numba_brief(e, law)
        hint = ("define it, or import what it names" if "is not defined" in brief else
                "run it as plain Python with --python-law, or keep to what numba compiles: docs/control.md")
        return f"law {law.label!r}: numba cannot compile it: {type(e).__name__}: {brief}; {hint}"
    except Exception:
        return ""
    if not (isinstance(out, tuple) and len(out) == 2 and all(isinstance(x, (int, float)) for x in out)):
        return f"law {law.label!r}: returned {out!r}; it must return (v, w), two numbers"
    return ""


def check(law: Law, samples: int = 200, seed: int = 0, compiled: bool = True) -> list[str]:
    """Call the law on `samples` random inputs, as Python and (compiled) with numba: what is wrong, [] if nothing.

    Refused: an exception, a result that is not two finite numbers, numba failing to compile it, and a compiled
    result (v, w or memory afterwards) that differs from the Python one in any bit."""
    rng = np.random.default_rng(seed)
    py = law.call(False)
    jit_call = None
    if compiled:
        problem = compile_problem(law)
        if problem:
            return [problem]
        jit_call = law.call(True)
    for s in range(samples):
        args = sample_inputs(rng, law.spec.params, law.spec.memory)
        out = []
        for label, fn in (("Python", py), ("compiled", jit_call)):
            if fn is None:
                continue
            a = [x.copy() for x in args]
            call_args = _sample_args(tuple(a))
            try:
                with np.errstate(all="ignore"):  # the result is judged below; numpy's warnings would only repeat it
                    res = fn(*call_args)
            except Exception as e:
                return [f"law {law.label!r} ({label}) raised {type(e).__name__}: {e} on test call {s} "
                        f"({_describe(args)})"]
            try:
                v, w = (float(x) for x in res)
            except (TypeError, ValueError):
                return [f"law {law.label!r} ({label}) returned {res!r} on test call {s}; it must return (v, w), "
                        "two numbers"]
            if not (math.isfinite(v) and math.isfinite(w)):
                return [f"law {law.label!r} ({label}) returned a non-finite command (v = {v}, w = {w}) on test call "
                        f"{s} ({_describe(args)})"]
            out.append((v, w, call_args[5]))
        if len(out) == 2:
            (v0, w0, m0), (v1, w1, m1) = out
            if (v0, w0) != (v1, w1) or not np.array_equal(m0, m1):
                return [f"law {law.label!r}: compiled and Python differ on test call {s} ({_describe(args)}): "
                        f"Python (v, w) = ({v0!r}, {w0!r}), compiled ({v1!r}, {w1!r}){' and memory' if not np.array_equal(m0, m1) else ''}; "
                        "a sum numpy and numba order differently (np.sum, @) is the usual cause: loop in order"]
    return []


def call_time(law: Law, samples: int = 200, seed: int = 0, compiled: bool = True) -> float:
    """The median wall time [s] of one call of the law (compiled, or as Python) on `samples` random inputs, as a
    robot process calls it (from Python: the call's own cost included). Call it after check() found nothing."""
    import time

    rng = np.random.default_rng(seed)
    fn = law.call(compiled)
    times = []
    for _ in range(samples):
        args = _sample_args(sample_inputs(rng, law.spec.params, law.spec.memory))
        t0 = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _sample_args(args: tuple[np.ndarray, ...]) -> tuple[Any, ...]:
    me, ref, bodies, params, t, mem, kinds = args
    return me, ref, bodies, params, float(t[0]), mem, kinds


def _describe(args: tuple[np.ndarray, ...]) -> str:
    me, ref, bodies = args[:3]
    return f"me = {np.round(me, 3).tolist()}, ref = {np.round(ref, 3).tolist()}, {len(bodies)} bodies"

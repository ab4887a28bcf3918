"""Which law a robot runs, and its parameter and memory vectors (docs/control.md).

The paper's law: swarm.core.fastlaw.robot_command (its C transcription where it was built, else law.py) over
plain lists. A user's law (the run's config names it: `law`, `law_sha256`, `law_params`, `law_memory`): loaded
from this machine's copy of its file or package (checked against the run's sha256; code never travels on the
bus), compiled by numba like `swarm sim` compiles it (the same compiled function: lock-step runs equal the
simulation) or, where numba cannot compile it, as plain Python, which the robot says.
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Any, Callable

from swarm.core import fastlaw, law
from swarm.core.errors import SwarmError

if TYPE_CHECKING:
    from swarm.proto.protocol import Config

log = logging.getLogger("swarm.robot")

SLOW_CALL_SHARE = 0.5  # a user's law call longer than this share of the control period is logged as slow
_LAWS: dict[tuple[str, str, str | None], Any] = {}  # loaded laws by (ref, sha256, --law-file): one per process


class LawFailure(SwarmError, RuntimeError):
    """A user's law raised or could not be loaded on this robot: the run cannot go on for it."""


class Controller:
    """The law a robot runs: command(...) with robot_command's signature, its parameter vector p and its memory."""

    def __init__(self, cfg: Config, law_file: str | None = None) -> None:
        p = [0.0] * law.P_SIZE
        p[law.P_K1], p[law.P_K2], p[law.P_K3] = cfg.k1, cfg.k2, cfg.k3
        p[law.P_TU], p[law.P_VT], p[law.P_THRESHOLD] = cfg.tu, cfg.vt, float(cfg.threshold)
        p[law.P_GOVERNOR] = 1.0 if cfg.governor else 0.0
        p[law.P_DT], p[law.P_SENSE], p[law.P_REACH] = cfg.dt, cfg.sense, cfg.reach
        p[law.P_V_MAX], p[law.P_W_MAX] = cfg.v_max, cfg.w_max
        self.robot = cfg.id
        self.dt = cfg.dt
        self.memory = 0
        self.p: Any = p
        self.command: Callable[..., tuple[float, float]] = fastlaw.robot_command
        self.label = "compiled" if fastlaw.COMPILED else "Python"  # the paper's law, as the robot's log says it
        if cfg.law is None:
            return
        import numpy as np  # a user's law only: a robot of the paper's law never loads numpy

        self.memory = int(cfg.law_memory or 0)
        self.p = np.array(p + list(cfg.law_params or ()), float)
        self.command, self.label = _user_command(cfg, law_file)

    def fresh_memory(self) -> Any:
        """A fresh controller's memory: zeros, the governor's scale 1 (a list for the paper's C law)."""
        if isinstance(self.p, list):
            mem: Any = [0.0] * law.M_SIZE
        else:
            import numpy as np

            mem = np.zeros(law.M_SIZE + self.memory)
        mem[law.M_SCALE] = 1.0
        return mem


def _user_command(cfg: Config, law_file: str | None) -> tuple[Callable[..., tuple[float, float]], str]:
    import numpy as np

    from swarm.core import userlaw

    assert cfg.law is not None and cfg.law_sha256 is not None
    spec = userlaw.LawSpec(cfg.law, cfg.law, cfg.law_sha256, tuple(cfg.law_params or ()), int(cfg.law_memory or 0))
    key = (cfg.law, cfg.law_sha256, law_file)
    loaded = _LAWS.get(key)
    if loaded is None:
        try:
            loaded = _LAWS[key] = userlaw.load(spec, law_file)
        except userlaw.LawError as e:
            raise LawFailure(f"robot {cfg.id}: {e}") from None
    problem = userlaw.compile_problem(loaded)
    compiled = not problem
    if problem:
        log.warning("robot %d: %s; it runs as plain Python", cfg.id, problem)
    command = loaded.command(compiled)
    name = f"{cfg.law} ({'compiled by numba' if compiled else 'Python'})"
    dt = cfg.dt
    slow = [0]  # calls that took longer than SLOW_CALL_SHARE of the control period (logged: the first, then every 100th)

    def run(x: float, y: float, th: float, ox: float, oy: float, r: float, t: float, xl: float, yl: float,
            thl: float, vl: float, wl: float, nx: Any, ny: Any, nr: Any, nR: Any, nk: Any, na: Any, n: int,
            mem: Any, p: Any) -> tuple[float, float]:
        t0 = time.perf_counter()
        try:
            v, w = command(x, y, th, ox, oy, r, t, xl, yl, thl, vl, wl, np.asarray(nx, float), np.asarray(ny, float),
                           np.asarray(nr, float), np.asarray(nR, float), np.asarray(nk, np.int64),
                           np.asarray(na, float), n, mem, p)
        except Exception as e:
            raise LawFailure(f"robot {cfg.id}: the law {cfg.law!r} raised {userlaw.failure_text(e)} at step "
                             f"{int(round(t / dt))} (t = {t:g} s)") from None
        if not (math.isfinite(v) and math.isfinite(w)):  # swarm sim ends the run there too
            raise LawFailure(f"robot {cfg.id}: the law {cfg.law!r} gave a non-finite command (v = {v}, w = {w}) at "
                             f"step {int(round(t / dt))} (t = {t:g} s)")
        took = time.perf_counter() - t0
        if took > SLOW_CALL_SHARE * dt:
            slow[0] += 1
            if slow[0] % 100 == 1:
                log.warning("robot %d: the law %r took %.2f ms at step %d, more than %d %% of the control period "
                            "(%g ms): its commands go out late (%d such calls so far)", cfg.id, cfg.law, took * 1e3,
                            int(round(t / dt)), int(SLOW_CALL_SHARE * 100), dt * 1e3, slow[0])
        return v, w

    return run, name

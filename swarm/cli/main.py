"""`swarm`'s entry point: parse the command line, run the command, turn errors into exit codes.

Exit codes: 0 done, 1 runtime failure, 2 bad input, 3 finished but a check failed, 4 `swarm robot` refused
its run (its law failed), 130 interrupted (docs/metrics.md).
A command-line flag beats the scenario file, which beats the built-in default.
"""

from __future__ import annotations

import importlib
import errno
import os
import re
import sys
import time
from typing import Sequence

from swarm.cli.common import (EXIT_BAD_INPUT, EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, EXIT_REFUSED, BadInput, Failure,
                              Refused)
from swarm.cli.parser import build_parser, value_options


def run_command(func: str, args, started: float) -> int:
    """Run the command named "module:function" (imported only now)."""
    module, _, name = func.partition(":")
    return getattr(importlib.import_module(module), name)(args, started)


def _process_age_s() -> float:
    """Seconds since this process started (Linux /proc, 10 ms steps; 0.0 where that is not known)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


def _dash_values(argv: Sequence[str], takes_value: set[str] | None = None) -> list[str]:
    """`--kill -1@3` and `--initial-pose -1.5,2,0` as `--kill=-1@3`: argparse takes a value that starts with
    a dash and is not a plain number for an option, and says "expected one argument" instead of what is
    wrong with the value. No option of swarm's starts with a dash and a digit, so such a token after an
    option that takes a value (takes_value; None: any long option) is that value."""
    out = list(argv)
    i = 0
    while i < len(out) - 1:
        if out[i].startswith("--") and "=" not in out[i] and len(out[i]) > 2 and re.match(r"-[\d.]", out[i + 1]) \
                and (takes_value is None or out[i] in takes_value):
            out[i:i + 2] = [f"{out[i]}={out[i + 1]}"]
        i += 1
    return out


_GONE = (errno.EPIPE, errno.EIO, errno.ENXIO)  # a closed pipe; a terminal that hung up (closed, logged out)


class _PipeSafe:
    """A console stream that outlives a closed pipe (`swarm sim ... | head -1`) or a closed terminal (its writes
    fail with EIO once it hung up): the run goes on, and its files and exit code are those it would have had;
    what it would still print goes to /dev/null."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as e:
            if e.errno not in _GONE:
                raise
            self._mute()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as e:
            if e.errno not in _GONE:
                raise
            self._mute()

    def _mute(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self._stream.fileno())
        os.close(devnull)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: Sequence[str] | None = None) -> int:
    # wall_s runs from the command's start (docs/metrics.md): the interpreter's start and the
    # imports count too when this is the command (argv None); a caller in-process counts from here
    started = time.perf_counter() - (_process_age_s() if argv is None else 0.0)
    if argv is None:  # the command itself (not a caller in-process): its console may be a pipe that closes
        sys.stdout, sys.stderr = _PipeSafe(sys.stdout), _PipeSafe(sys.stderr)
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(re.match(r"-[\d.]", a) for a in argv):  # rare: only then are the options walked
        argv = _dash_values(argv, value_options(parser))
    args = parser.parse_args(argv)
    args.argv = argv  # for swarm.cli.parser.given_flags, on demand
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    from swarm.core.errors import ScenarioError

    if getattr(args, "log_level", None):  # for this process and every process it starts (their environment)
        os.environ["SWARM_LOG_LEVEL"] = args.log_level

    name = " ".join(w for w in (args.command, getattr(args, "action", None)) if w)  # "scenario check" too
    try:
        return run_command(args.func, args, started)
    except (ScenarioError, BadInput) as e:
        print(f"swarm {name}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Refused as e:
        print(f"swarm {name}: refused: {e}", file=sys.stderr)
        return EXIT_REFUSED
    except Failure as e:
        print(f"swarm {name}: failed: {e}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print(f"swarm {name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # a caller in-process whose own stream broke (the command's own: _PipeSafe)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except Exception as e:  # a runtime failure: one line, plus the traceback on request
        if os.environ.get("SWARM_DEBUG"):
            raise
        if isinstance(e, OSError) and e.filename is not None:  # a file the run could not use: name it
            what = f"{e.filename}" + (f" -> {e.filename2}" if e.filename2 is not None else "") + f": {e.strerror or e}"
        else:
            what = f"{type(e).__name__}: {e}"
        print(f"swarm {name}: failed: {what} (set SWARM_DEBUG=1 for a traceback)", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())

"""The world's progress told to the `swarm up` that started it, over a pipe the world inherits, not the network.

`swarm up` acts on the world's progress: its status line, the metrics it rebuilds when the world is lost, and
the process faults it does for real (a scheduled kill at tick 750 is sent when the world says tick 750; in real
time, at the world's epoch + t). Over zenoh anyone on the router can say it: 20 forged progress messages with
seq 10^6 had a robot killed at once, a flood of seq 0 kept a kill from ever being sent, and a forged clock epoch
did either in real time. The world is the launcher's child, so the launcher hears it on a pipe instead, which
nobody else can write to.

    pipe = ProgressPipe()                      # the launcher, before it starts the world
    sup.start(plan.world, env=pipe.env(), pass_fds=pipe.fds())
    pipe.started()                             # the world's end closed here; a thread reads the other
    pipe.last                                  # the newest progress (protocol.Progress) or None
    pipe.epoch                                 # real time: (epoch, speed) of the world's clock, or None
    pipe.close()

    teller = Teller.from_env()                 # the world: None unless a launcher gave it a pipe
    teller.progress(p, epoch)                  # a line a progress message; never blocks the world
"""

from __future__ import annotations

import logging
import os
import threading

from swarm.proto import protocol

log = logging.getLogger("swarm")

ENV = "SWARM_PROGRESS_FD"  # the world's end of the pipe (a file descriptor it inherited)


class ProgressPipe:
    """The launcher's end: the newest progress and the real-time epoch, read by a thread of its own."""

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        self.last: protocol.Progress | None = None
        self.epoch: tuple[float, float] | None = None
        self.bad = 0  # lines that did not decode (the world wrote them: a bug, counted)
        self._thread: threading.Thread | None = None

    def env(self) -> dict[str, str]:
        return {ENV: str(self._w)}

    def fds(self) -> tuple[int, ...]:
        return (self._w,)

    def started(self) -> None:
        """The world holds its end now: close ours (the reader sees the end of the file when the world exits)."""
        os.close(self._w)
        self._w = -1
        self._thread = threading.Thread(target=self._read, name="progress-pipe", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        with os.fdopen(self._r, "rb", buffering=0) as f:
            for line in iter(f.readline, b""):
                try:
                    kind, _, rest = line.strip().partition(b" ")
                    if kind == b"p":
                        self.last = protocol.decode(bytes.fromhex(rest.decode()), "progress")
                    elif kind == b"e":
                        epoch, speed = (float(v) for v in rest.split())
                        self.epoch = (epoch, speed)
                    else:
                        raise ValueError(f"a line of kind {kind!r}")
                except (ValueError, protocol.ProtocolError) as e:
                    self.bad += 1
                    log.warning("the world's progress pipe: a line that does not read (%s)", e)

    def close(self) -> None:
        if self._w >= 0:  # the world was never started
            os.close(self._w)
            self._w = -1
            os.close(self._r)
        elif self._thread is not None:
            self._thread.join(timeout=1.0)


class Teller:
    """The world's end: writes without blocking (a launcher that stopped reading costs the world nothing)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        os.set_blocking(fd, False)
        os.set_inheritable(fd, False)  # for this process alone: nothing it starts gets the launcher's pipe
        self._epoch_told = False
        self.dropped = 0  # lines the full pipe did not take

    @classmethod
    def from_env(cls) -> "Teller | None":
        fd = os.environ.pop(ENV, None)  # not handed on to anything this process starts
        if fd is None:
            return None
        try:
            return cls(int(fd))
        except (ValueError, OSError) as e:
            log.warning("%s=%s: not a pipe this process holds (%s); the launcher hears no progress", ENV, fd, e)
            return None

    def progress(self, p: protocol.Progress, epoch: float | None = None, speed: float = 1.0) -> None:
        if epoch is not None and not self._epoch_told:
            self._epoch_told = self._write(f"e {epoch!r} {speed!r}\n".encode())
        self._write(b"p " + protocol.encode(p).hex().encode() + b"\n")

    def _write(self, line: bytes) -> bool:
        if self.fd < 0:
            return False
        try:
            sent = os.write(self.fd, line)  # whole or nothing below PIPE_BUF (4096 on Linux; 512 on macOS)
        except BlockingIOError:
            self.dropped += 1
            return False
        except OSError:  # the launcher is gone
            self.fd = -1
            return False
        if sent < len(line):  # torn (a long line on a system with a small PIPE_BUF): the reader would misread
            self.fd = -1  # the rest; stop telling rather than tell wrong
            log.warning("the progress pipe took %d of a %d-byte line; the launcher hears no more progress", sent,
                        len(line))
            return False
        return True

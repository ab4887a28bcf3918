"""A meshcat server bound to one address, that dies with its parent, and a client with timeouts.

    with MeshcatServer(host="127.0.0.1", port=0, log=Path("viz-server.log")) as server:
        print(server.web_url)                 # http://127.0.0.1:PORT/static/
        server.client.send(command)           # a meshcat command (SetObject, SetTransform, ...)
    # leaving: close the socket, SIGTERM, wait, SIGKILL if it does not go

Why not `meshcat.Visualizer()` (measured here): its server listens on every
interface whatever it prints, walks silently to the next port when one is taken, survives a
SIGKILLed parent, pipes a stderr nobody reads, and its REQ socket blocks forever on a dead
server. Here the server half (`python -m swarm.view.meshcat_server`, the `main` below) subclasses
meshcat's ZMQWebSocketBridge to bind HTTP to `host` only (ZMQ always to 127.0.0.1: only this
machine draws), fails at once on a taken port, takes SIGTERM when its parent dies
(PR_SET_PDEATHSIG through swarm.launch.die_with_parent; start it from the main thread, since the
signal follows the thread that forked), ignores Ctrl-C (its parent stops it, in order), and
writes its stderr to a log file or nowhere. The client's socket has send and receive timeouts.
"""

from __future__ import annotations

import argparse
import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import BinaryIO, cast
from swarm.core.errors import SwarmError

LOOPBACK = "127.0.0.1"
START_TIMEOUT_S = 20.0
REPLY_TIMEOUT_S = 5.0


class ServerError(SwarmError, RuntimeError):
    """The meshcat server could not start, or stopped answering."""


BROWSERS = b"swarm/browsers"  # a ZMQ command our server adds to meshcat's: the number of connected pages


class MeshcatClient:
    """Sends meshcat commands over ZMQ REQ/REP, with timeouts (a REQ socket without them blocks
    forever on a dead server). Same `send(command)` as meshcat's ViewerWindow."""

    def __init__(self, zmq_url: str, timeout_s: float = REPLY_TIMEOUT_S):
        import zmq

        self._zmq = zmq
        self.zmq_url, self.timeout_s = zmq_url, timeout_s
        self.socket: zmq.Socket | None = zmq.Context.instance().socket(zmq.REQ)
        ms = int(timeout_s * 1000)
        for opt, value in ((zmq.LINGER, 0), (zmq.RCVTIMEO, ms), (zmq.SNDTIMEO, ms)):
            self.socket.setsockopt(opt, value)
        self.socket.connect(zmq_url)
        self.sent = 0
        self.bytes = 0

    def send(self, command) -> None:
        """Send one command (anything with meshcat's `lower()`) and wait for the server's ack."""
        import umsgpack

        data = command.lower()
        self.send_raw(data["type"], data.get("path", ""), umsgpack.packb(data))

    def send_raw(self, kind: str, path: str, packed: bytes) -> None:
        if self.socket is None:
            raise ServerError("the meshcat client is closed")
        try:
            self.socket.send_multipart([kind.encode(), path.encode(), packed])
            self.socket.recv()
        except self._zmq.Again:
            self.close()  # a REQ socket that missed its reply is unusable
            raise ServerError(f"the meshcat server at {self.zmq_url} did not answer within {self.timeout_s:g} s")
        self.sent += 1
        self.bytes += len(packed)

    def browsers(self) -> int:
        """How many browser pages are connected to the server now."""
        if self.socket is None:
            raise ServerError("the meshcat client is closed")
        try:
            self.socket.send_multipart([BROWSERS])
            return int(self.socket.recv())
        except self._zmq.Again:
            self.close()
            raise ServerError(f"the meshcat server at {self.zmq_url} did not answer within {self.timeout_s:g} s")

    def close(self) -> None:
        if self.socket is not None:
            self.socket.close(linger=0)
            self.socket = None


class MeshcatServer:
    """Starts `python -m swarm.view.meshcat_server` and connects a MeshcatClient to it.

    host: where HTTP listens (default 127.0.0.1; "0.0.0.0" for other machines). port: the HTTP
    port, 0 for a free one. log: a file for the server's stderr (None: discarded)."""

    def __init__(self, host: str = LOOPBACK, port: int = 0, log: Path | None = None,
                 start_timeout_s: float = START_TIMEOUT_S):
        self.host, self.port, self.log, self.start_timeout_s = host, port, log, start_timeout_s
        self.proc: subprocess.Popen | None = None
        self.client: MeshcatClient | None = None
        self.web_url = ""
        self.zmq_url = ""

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def __enter__(self) -> "MeshcatServer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        from swarm.process import PARENT_ENV

        argv = [sys.executable, "-u", "-m", "swarm.view.meshcat_server", "--host", self.host, "--port", str(self.port)]
        err = open(self.log, "ab") if self.log is not None else subprocess.DEVNULL
        try:
            # Same process group as this process: a launcher that kills our group kills the server
            # too; PR_SET_PDEATHSIG covers a SIGKILL of this process alone.
            self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=err,
                                         env=_child_env({PARENT_ENV: str(os.getpid())}))
        finally:
            if self.log is not None:
                cast(BinaryIO, err).close()  # the log file opened above
        try:
            found = self._read_urls()
            self.zmq_url, self.web_url = found["zmq_url"], found["web_url"]
            self.client = MeshcatClient(self.zmq_url)
        except BaseException:
            self.stop()
            raise

    def _read_urls(self) -> dict[str, str]:
        """The server's `zmq_url=` and `web_url=` lines, within the start deadline."""
        assert self.proc is not None and self.proc.stdout is not None
        found: dict[str, str] = {}
        buf = b""
        end = time.monotonic() + self.start_timeout_s
        with selectors.DefaultSelector() as sel:
            sel.register(self.proc.stdout, selectors.EVENT_READ)
            while not ("zmq_url" in found and "web_url" in found):
                left = end - time.monotonic()
                if left <= 0:
                    raise ServerError(f"the meshcat server gave no address within {self.start_timeout_s:g} s"
                                      f"{self._log_tail()}")
                if not sel.select(left):
                    continue
                chunk = os.read(self.proc.stdout.fileno(), 4096)
                if not chunk:
                    self.proc.wait(2.0)
                    raise ServerError(f"the meshcat server exited (code {self.proc.returncode}) before it "
                                      f"listened on {self.host}:{self.port}{self._log_tail()}")
                buf += chunk
                *lines, buf = buf.split(b"\n")
                for line in lines:
                    key, sep, value = line.decode(errors="replace").strip().partition("=")
                    if sep and key in ("zmq_url", "web_url", "error"):
                        found[key] = value
                if "error" in found:
                    self.proc.wait(5.0)
                    raise ServerError(f"the meshcat server {found['error']}")
        self.proc.stdout.close()
        return found

    def _log_tail(self) -> str:
        if self.log is None:
            return ""
        try:
            lines = self.log.read_text(errors="replace").strip().splitlines()[-3:]
        except OSError:
            return ""
        return (": " + " | ".join(lines)) if lines else f" (log: {self.log})"

    def stop(self) -> None:
        """Close the socket, SIGTERM, wait, SIGKILL if it is still there. Idempotent."""
        if self.client is not None:
            self.client.close()
            self.client = None
        p, self.proc = self.proc, None
        if p is None:
            return
        if p.stdout is not None and not p.stdout.closed:
            p.stdout.close()
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(5.0)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5.0)


def _child_env(extra: dict[str, str]) -> dict[str, str]:
    """This environment, with the directory that holds the `swarm` package on PYTHONPATH (so
    `-m swarm.view.meshcat_server` imports whatever way this process found swarm)."""
    root = str(Path(__file__).resolve().parent.parent)
    path = os.environ.get("PYTHONPATH", "")
    if root not in path.split(os.pathsep):
        path = os.pathsep.join(p for p in (root, path) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


# --------------------------------------------------------------------------- the server process


def _bare_meshcat_package() -> None:
    """Make `meshcat.servers.zmqserver` importable without meshcat/__init__.py, which imports
    numpy, IPython and the client (0.7 s of a 1.3 s start); the server needs only tornado and zmq."""
    import importlib.util
    import types

    spec = importlib.util.find_spec("meshcat")
    if spec is None or not spec.submodule_search_locations:
        raise ServerError("meshcat is not installed (pip install meshcat)")
    root = list(spec.submodule_search_locations)[0]
    for name, path in (("meshcat", root), ("meshcat.servers", os.path.join(root, "servers"))):
        if name not in sys.modules:
            mod = types.ModuleType(name)
            mod.__path__ = [path]
            sys.modules[name] = mod


def _serve(host: str, port: int) -> None:
    import socket
    import warnings

    _bare_meshcat_package()
    with warnings.catch_warnings():  # zmq.eventloop.ioloop is deprecated; meshcat still imports it
        warnings.simplefilter("ignore", DeprecationWarning)
        import tornado.httpserver
        import tornado.netutil
        import zmq
        from meshcat.servers import zmqserver

    class LocalBridge(zmqserver.ZMQWebSocketBridge):
        """meshcat's bridge with HTTP bound to `host` only (tornado's app.listen binds every interface)."""

        def make_app(self):
            app = super().make_app()

            def listen(p, **kw):
                socks = tornado.netutil.bind_sockets(p, address=host)
                srv = tornado.httpserver.HTTPServer(app, **kw)
                srv.add_sockets(socks)
                self.real_http_port = socks[0].getsockname()[1]
                return srv

            app.listen = listen
            return app

        def handle_zmq(self, frames):
            if frames[0] == BROWSERS:  # ours: how many browsers are connected
                self.zmq_socket.send(str(len(self.websocket_pool)).encode())
            else:
                super().handle_zmq(frames)

    bridge = LocalBridge(zmq_url=f"tcp://{LOOPBACK}:*", host=host, port=port)  # ZMQ: loopback, any port
    zmq_url = bridge.zmq_socket.getsockopt_string(zmq.LAST_ENDPOINT)
    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    if ":" in shown:
        shown = f"[{shown}]"
    print(f"zmq_url={zmq_url}")
    print(f"web_url=http://{shown}:{bridge.real_http_port}/static/", flush=True)
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)  # nobody reads stdout any more
    bridge.run()


def main(argv: list[str] | None = None) -> int:
    from swarm.process import die_with_parent

    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us after its own Ctrl-C
    p = argparse.ArgumentParser(prog="python -m swarm.view.meshcat_server",
                                description="A meshcat server with HTTP on one address (started by MeshcatServer).")
    p.add_argument("--host", default=LOOPBACK)
    p.add_argument("--port", type=int, default=0)
    args = p.parse_args(argv)
    try:
        _serve(args.host, args.port)
    except OSError as e:  # on stdout too: the parent reads it even when stderr is discarded
        print(f"error=cannot listen on {args.host}:{args.port}: {e.strerror or e}", flush=True)
        print(f"meshcat server: cannot listen on {args.host}:{args.port}: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

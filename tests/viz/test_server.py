"""The meshcat server: loopback only by default, a clear error on a taken port, and never an orphan
(it dies with its parent, even when the parent is SIGKILLed)."""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys
import textwrap

import psutil
import pytest

from swarm.view.meshcat_server import MeshcatServer, ServerError
from tests.viz.helpers import URL_LINE, Child, assert_all_gone, listening, meshcat_server_of

pytestmark = pytest.mark.integration


def test_the_server_listens_on_127_0_0_1_only_by_default():
    with MeshcatServer() as server:
        pid = server.pid
        sockets = listening(psutil.Process(pid))
        http_port = int(server.web_url.rsplit(":", 1)[1].split("/")[0])
        assert server.web_url.startswith("http://127.0.0.1:")
        assert ("127.0.0.1", http_port) in sockets
        assert len(sockets) == 2 and {ip for ip, _ in sockets} == {"127.0.0.1"}, sockets  # HTTP and ZMQ
    assert not psutil.pid_exists(pid)  # stopped and reaped on the way out


def test_viz_host_opens_http_to_other_machines_but_never_zmq():
    with MeshcatServer(host="0.0.0.0") as server:
        sockets = listening(psutil.Process(server.pid))
        zmq_port = int(server.zmq_url.rsplit(":", 1)[1])
        assert ("127.0.0.1", zmq_port) in sockets
        assert {ip for ip, port in sockets if port != zmq_port} == {"0.0.0.0"}


def test_a_taken_port_fails_at_once_with_the_reason(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        server = MeshcatServer(port=port, log=tmp_path / "server.log")
        with pytest.raises(ServerError, match=f"cannot listen on 127.0.0.1:{port}: Address already in use"):
            server.start()
        assert server.proc is None  # nothing left running


def test_the_server_dies_with_a_sigkilled_parent(tmp_path):
    parent = subprocess.Popen([sys.executable, "-c", textwrap.dedent("""
        import sys
        from swarm.view.meshcat_server import MeshcatServer
        s = MeshcatServer()
        s.start()
        print(s.pid, flush=True)
        sys.stdin.read()  # until the test closes our stdin (it SIGKILLs us first)
        """)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, start_new_session=True)
    server = None
    try:
        line = parent.stdout.readline()  # bounded: the parent prints or dies within the start timeout
        server = psutil.Process(int(line))
        assert "swarm.view.meshcat_server" in " ".join(server.cmdline())
        parent.kill()
        parent.wait(10)
        assert_all_gone([server], 10, "the meshcat server of a SIGKILLed parent")
    finally:
        with contextlib.suppress(ProcessLookupError):
            parent.kill()
        if server is not None:
            with contextlib.suppress(psutil.NoSuchProcess):
                server.kill()
        parent.communicate(timeout=10)


def sim_viz(tmp_path) -> Child:
    return Child(["sim", "--viz", "--robots", "3", "--duration", "2", "--speed", "10", "--quiet"],
                 tmp_path / "sim.err")


def test_swarm_sim_viz_plays_the_run_then_waits_for_ctrl_c(tmp_path):
    child = sim_viz(tmp_path)
    try:
        url = child.expect(URL_LINE, 60).group(1)
        server = meshcat_server_of(child)
        assert {ip for ip, _ in listening(server)} == {"127.0.0.1"} and url.startswith("http://127.0.0.1:")
        child.expect(r"^viewer: the run is over", 60)
        assert child.proc.poll() is None  # the viewer stays up
        child.proc.send_signal(signal.SIGINT)
        assert child.proc.wait(15) == 0, child.stderr()
        assert_all_gone([server], 10, "the meshcat server after Ctrl-C")
    finally:
        child.close()


def test_swarm_sim_viz_leaves_no_server_when_sigkilled(tmp_path):
    child = sim_viz(tmp_path)
    try:
        child.expect(URL_LINE, 60)
        tree = child.tree()
        assert any("swarm.view.meshcat_server" in " ".join(p.cmdline()) for p in tree[1:])
        child.proc.kill()
        assert_all_gone(tree, 10, "swarm sim --viz killed with SIGKILL")
    finally:
        child.close()

"""--id auto as processes over a zenoh router on loopback: 7 robots started at once with --id auto get
ids 0-6; two are killed; once their tokens are gone (one lease) the one restarted with its own
--claim-key gets its own id back (though a lower one is free), and a newcomer takes the freed id; the
refusals (--drive ros2, --secure, --claim-key without --id auto) exit 2."""

from __future__ import annotations

import re
import signal
import subprocess
import threading

import pytest

from swarm.net.bus import ZenohBus, zenoh_config
from swarm.proto import keys
from tests.deploy.helpers import ENTRY, ENV, ROOT, Procs, wait_until
from tests.integration.helpers import free_port

pytestmark = pytest.mark.integration
CLAIMED = re.compile(r"claimed id (\d+) \(claim key (\S+)\)")


class Tokens:
    """The robots' liveliness tokens of a fleet, as a test client of the router sees them."""

    def __init__(self, endpoint: str, fleet: str) -> None:
        self.bus = wait_until(lambda: _bus(endpoint), 30, "the router")
        self.lock = threading.Lock()
        self.up: set[int] = set()
        self.bus.watch_alive(keys.alive_any(fleet, "robot"), self._on)

    def _on(self, key: str, up: bool) -> None:
        k = keys.parse(key)
        with self.lock:
            (self.up.add if up else self.up.discard)(k.id)

    def ids(self) -> set[int]:
        with self.lock:
            return set(self.up)


def _bus(endpoint: str):
    try:
        return ZenohBus(zenoh_config(connect=[endpoint]))
    except Exception:
        return None


@pytest.mark.timeout(240)
def test_ids_are_handed_out_freed_and_given_back(tmp_path):
    procs = Procs(tmp_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    net = ["--fleet", "auto", "--connect", endpoint]
    scn = ["--scenario", "paper-50hz", "--robots", "7", "--duration", "600"]
    tokens = None
    try:
        procs.start("router", [*ENTRY, "router", "--listen", endpoint, "--fleet", "auto"])
        procs.start("world", [*ENTRY, "world", *scn, "--mode", "realtime", "--lost-timeout", "600", *net])
        procs.start("leader", [*ENTRY, "leader", *scn, *net])
        tokens = Tokens(endpoint, "auto")

        def robot(name: str, key: str):
            return procs.start(name, [*ENTRY, "robot", "--id", "auto", "--claim-key", key, "--mode", "realtime", *net])

        for k in range(7):
            robot(f"robot-{k}", f"host-{k}")

        def claimed(name: str) -> int | None:
            m = CLAIMED.search(procs.log(name))
            return int(m.group(1)) if m else None

        ids = wait_until(lambda: (lambda got: got if None not in got else None)(
            [claimed(f"robot-{k}") for k in range(7)]), 90, "7 claims")
        assert sorted(ids) == list(range(7)), procs.logs("world")
        wait_until(lambda: tokens.ids() == set(range(7)), 30, "7 robot tokens")
        by_id = {i: k for k, i in enumerate(ids)}

        # kill the robots holding ids 1 and 4 (SIGKILL: no goodbye); their tokens go one lease later
        for i in (1, 4):
            procs.stop(f"robot-{by_id[i]}", signal.SIGKILL)
        wait_until(lambda: tokens.ids() == {0, 2, 3, 5, 6}, 10, "the tokens of robots 1 and 4 to go")

        # the robot of id 4 restarts with its own claim key: its own id back, though 1 is lower and free
        robot("again", f"host-{by_id[4]}")
        assert wait_until(lambda: claimed("again"), 60, "the restarted robot's claim") == 4
        # a newcomer takes the freed id
        robot("newcomer", "host-new")
        assert wait_until(lambda: claimed("newcomer"), 60, "the newcomer's claim") == 1
        wait_until(lambda: tokens.ids() == set(range(7)), 30, "7 robot tokens again")
        # no id left: an eighth robot is refused, with the reason, and exits 1
        robot("eighth", "host-8")
        assert procs.procs["eighth"].wait(60) == 1
        assert "every id of the run is taken (ids 0..6" in procs.log("eighth")
    finally:
        if tokens is not None:
            tokens.bus.close()
        procs.stop_all()


@pytest.mark.parametrize("args, reason", [
    (["--id", "auto", "--drive", "ros2"], "--id auto with --drive ros2: hardware has fixed ids"),
    (["--id", "auto", "--secure", "fleet/"], "--id auto with --secure: the robot's certificate says its id"),
    (["--id", "3", "--claim-key", "h"], "--claim-key needs --id auto"),
    (["--id", "auto", "--claim-key", "a/b"], "--claim-key: a claim key must be 1-64 characters"),
])
def test_refusals(args, reason):
    out = subprocess.run([*ENTRY, "robot", *args, "--connect", "tcp/127.0.0.1:9"], capture_output=True, text=True,
                         timeout=60, cwd=ROOT, env=ENV)
    assert out.returncode == 2 and reason in out.stderr, out.stderr

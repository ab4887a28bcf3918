"""`swarm up` does its scheduled kills on the world's word, heard on a pipe from the world it started, never on
the network: forged world/progress (seq 10^6, or a flood of seq 0) and a forged world/clock epoch neither
bring a kill forward nor hold it back (bounded waits, processes killed by PID)."""

from __future__ import annotations

import json
import re
import subprocess
import threading
import time

import pytest

from swarm.net.bus import ZenohBus, zenoh_config
from swarm.proto import keys, protocol
from tests.integration.helpers import kill_all, up, wait_for_ticks

pytestmark = pytest.mark.integration

FLEET = "t"
KILL_AT_S = 8.0
DT = 0.02  # swarm up's default scenario (paper-50hz)
KILL_LINE = re.compile(r"^\d+\.\d+ (tick (\d+)|t = ([\d.]+) s): robot 2 killed", re.M)


def _forger(endpoint: str, mode: str, stop: threading.Event) -> None:
    """From the moment the router listens (before the world's first clock): forged progress far ahead and at 0,
    and (real time) forged clock epochs, until stopped."""
    bus = None
    deadline = time.monotonic() + 60.0
    while bus is None and not stop.is_set() and time.monotonic() < deadline:
        try:
            bus = ZenohBus(zenoh_config(connect=[endpoint]))
        except Exception:
            stop.wait(0.05)  # the router does not listen yet
    if bus is None:
        return
    try:
        k = 0
        while not stop.is_set():
            seq = 10**6 if k % 2 == 0 else 0
            bus.put(keys.world_progress(FLEET), protocol.encode(protocol.Progress(
                t=seq * DT, seq=seq, duration=20.0, robots=5, alive=5, converged=0, frozen=0, min_distance=-1.0,
                misses=0, bad=0)))
            if mode == "realtime":
                bus.put(keys.world_clock(FLEET), protocol.encode(protocol.Clock(
                    t=0.0, seq=0, epoch=1.0 if k % 2 == 0 else 1e11, speed=1.0)))
            k += 1
            stop.wait(0.002)  # outnumbers the world's own clocks (one a period)
    finally:
        bus.close()


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_forged_progress_and_clocks_neither_bring_a_kill_forward_nor_hold_it_back(tmp_path, mode):
    speed = ("--speed", "2") if mode == "realtime" else ()  # 7 wall s of real time
    cmd, metrics = up(tmp_path, "--mode", mode, "--robots", "5", "--duration", "14", "--kill", f"2@{KILL_AT_S:g}",
                      *speed, "--quiet", fleet=FLEET)
    endpoint = cmd[cmd.index("--listen") + 1]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    stop = threading.Event()
    forger = threading.Thread(target=_forger, args=(endpoint, mode, stop), daemon=True)
    forger.start()
    try:
        wait_for_ticks(cmd, FLEET, 5, proc)  # the run is under way, the forger at work
        out, err = proc.communicate(timeout=240)
    finally:
        stop.set()
        forger.join(timeout=10)
        if proc.poll() is None:
            kill_all([proc])
    m = json.loads(metrics.read_text())
    assert m["failure"] is None and proc.returncode == 0, (err, m.get("failure"))
    kills = KILL_LINE.findall((tmp_path / "logs" / "faults.log").read_text())
    assert len(kills) == 1, kills
    _, tick, t = kills[0]
    when = int(tick) * DT if mode == "lockstep" else float(t)
    assert KILL_AT_S <= when <= KILL_AT_S + 1.0, kills  # the world's tick, not the forger's 10^6 or 0
    assert m["faults"]["killed"] == 1

"""`swarm stop` during a running `swarm up`, lock-step and real time: the world logs the stop with its reason,
the metrics count it (`estops`), the summary says it, the recording holds it (and `swarm report` reads it),
and the release is not counted as bad messages (a halted robot's drive keeps its commands' window moving)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from swarm.net.bus import ZenohBus, zenoh_config
from swarm.proto import keys, protocol
from swarm.view import report
from tests.integration.helpers import up, wait_for_ticks

pytestmark = pytest.mark.integration

CLI = [sys.executable, "-m", "swarm.cli"]
REASON = "a person in the arena"


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_an_emergency_stop_mid_run_is_logged_counted_summarised_and_recorded(tmp_path, mode):
    mcap = tmp_path / "run.mcap"
    extra = ["--speed", "2"] if mode == "realtime" else []
    duration = 16.0 if mode == "realtime" else 30.0  # lock-step runs as fast as it can: room for the CLI to start
    cmd, metrics = up(tmp_path, "--robots", "3", "--duration", str(duration), "--mode", mode, "--record", str(mcap),
                      *extra)
    endpoint = cmd[cmd.index("--listen") + 1]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, process_group=0)
    stop = CLI + ["stop", "--fleet", "t", "--connect", endpoint, "--repeat-s", "0.5"]
    operator = None
    try:
        wait_for_ticks(endpoint, "t", 150, proc)
        said = subprocess.run(stop + ["--reason", REASON], capture_output=True, text=True, timeout=60, check=True)
        assert "the world logged it at t = " in said.stdout, said.stdout  # the operator knows it took
        # the release from a session already open, as `swarm stop --release` puts it: a second process's start
        # (a second or more on a loaded machine) could outlast a 3-robot lock-step run, which is over in seconds
        operator = ZenohBus(zenoh_config(connect=[endpoint]))
        wait_for_ticks(endpoint, "t", 350, proc)
        now = time.time()
        operator.put(keys.estop("t"), protocol.encode(protocol.Estop(t=now, seq=int(now * 1000), engaged=False,
                                                                      reason="")), reliable=True)
        out, _ = proc.communicate(timeout=240)
    finally:
        if operator is not None:
            operator.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
    assert proc.returncode in (0, 3), out[-3000:]
    m = json.loads(metrics.read_text())
    e = m["estops"]
    assert (e["engaged"], e["released"]) == (1, 1), e
    assert [ev["engaged"] for ev in e["events"]] == [True, False] and e["events"][0]["reason"] == REASON
    assert 3.0 <= e["events"][0]["t"] < e["events"][1]["t"] <= duration, e
    assert m["bad_messages"] == 0 and m["collisions"] == 0, out[-3000:]
    summary = [line for line in out.splitlines() if "emergency stop" in line and "engaged at t =" in line]
    assert summary and REASON in summary[0] and "released at t =" in summary[0], out[-3000:]
    world_log = (tmp_path / "logs" / "world.log").read_text()
    assert f"emergency stop ENGAGED at t = " in world_log and REASON in world_log and "emergency stop released" in world_log
    faults = [(f["event"], f["detail"]) for f in report.read_recording(mcap).faults]
    assert ("estop", REASON) in faults and ("estop_release", "") in faults, faults

"""`swarm campaign --cluster`: a campaign's runs on a Dask cluster of a scheduler and two worker processes this test
starts on loopback (each in its own process group, killed by PID), with a worker killed while it holds runs: every
run still completes on the other, and runs.csv equals the local campaign's row for row (a run is a pure function of
its row). Skipped without the cluster extra (pip install 'swarm[cluster]')."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from tests.integration.helpers import free_port, wait_until
from tests.integration.test_campaign import read_csv, swarm, without_wall_clock

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]
distributed = pytest.importorskip("distributed", reason="the cluster extra: pip install 'swarm[cluster]'")

GRID = ["--scenario", "paper-50hz", "--robots", "7", "--duration", "10", "--seeds", "0-9", "--drop", "0,0.2"]  # 20 runs
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}  # the workers import swarm as this test does


def _start(argv: list[str], log) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, process_group=0, env=ENV)


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(5)


def test_a_campaign_on_a_dask_cluster_survives_a_lost_worker_and_equals_the_local_one(tmp_path):
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    log = open(tmp_path / "dask.log", "wb")
    procs = [_start([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port),
                     "--no-dashboard"], log)]
    try:
        for k in range(2):  # no nanny: a killed worker stays dead, as a lost machine would
            procs.append(_start([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                                 "--no-nanny", "--no-dashboard", "--name", f"w{k}"], log))
        client = distributed.Client(address, timeout=60)
        try:
            wait_until(lambda: len(client.scheduler_info()["workers"]) == 2, 60, "two workers at the scheduler")
            out = tmp_path / "cluster"
            camp = subprocess.Popen([sys.executable, "-m", "swarm.cli", "campaign", *GRID, "--cluster", address,
                                     "-o", str(out), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, process_group=0)
            procs.append(camp)
            # a worker that holds runs of the campaign (its first one: the kernels load, seconds), then lose it
            wait_until(lambda: sum(1 for tasks in client.processing().values() if tasks) == 2, 120,
                       "both workers running the campaign's runs")
            doomed = procs[1]
            os.killpg(doomed.pid, signal.SIGKILL)
            doomed.wait(10)
            got_out, got_err = camp.communicate(timeout=240)
        finally:
            client.close()
        assert camp.returncode == 0, got_err[-3000:] + (tmp_path / "dask.log").read_text(errors="replace")[-3000:]
        local = tmp_path / "local"
        p = swarm("campaign", *GRID, "-j", "2", "-o", str(local), "--quiet", timeout=240)
        assert p.returncode == 0, p.stderr
        cols, rows = read_csv(out / "runs.csv")
        lcols, lrows = read_csv(local / "runs.csv")
        assert len(rows) == 20 and not any(r["failure"] for r in rows), rows
        assert cols == lcols and without_wall_clock(cols, rows) == without_wall_clock(lcols, lrows)
    finally:
        _stop(procs)
        log.close()

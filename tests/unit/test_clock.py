"""The step-free wall clock: a step of the system clock (NTP, a paused and resumed VM) does not move a
running swarm's time; a run's start takes it up; a run's end says it happened."""

from __future__ import annotations

import logging

import pytest

from swarm.core.clock import STEP_WARN_S, WallClock, said_step

pytestmark = pytest.mark.unit


class Sources:
    """A system clock and a monotonic clock a test moves: step() moves only the system clock."""

    def __init__(self) -> None:
        self.system, self.mono = 1_700_000_000.0, 50.0

    def run(self, dt: float) -> None:
        self.system += dt
        self.mono += dt

    def step(self, ds: float) -> None:
        self.system += ds


def clock_of(s: Sources) -> WallClock:
    return WallClock(system=lambda: s.system, mono=lambda: s.mono)


def test_time_follows_the_system_clock_but_not_its_steps():
    s = Sources()
    c = clock_of(s)
    assert c.time() == s.system and c.monotonic() == s.mono and c.step_s() == 0.0
    s.run(2.5)
    assert c.time() == pytest.approx(s.system, abs=1e-6) and c.step_s() == pytest.approx(0.0, abs=1e-6)
    s.step(30.0)  # a VM resumed after 30 s with its wall clock then set forward
    assert c.time() == pytest.approx(1_700_000_002.5, abs=1e-6) and c.step_s() == pytest.approx(30.0, abs=1e-6)
    s.run(1.0)
    assert c.time() == pytest.approx(1_700_000_003.5, abs=1e-6)  # time goes on at the monotonic clock's rate
    s.step(-45.0)  # and a step back (NTP correcting a clock that ran ahead) is not taken either
    assert c.time() == pytest.approx(1_700_000_003.5, abs=1e-6) and c.step_s() == pytest.approx(-15.0, abs=1e-6)


def test_anchor_takes_up_the_steps_made_since_the_last_anchor():
    s = Sources()
    c = clock_of(s)
    s.run(1.0)
    s.step(-3600.0)  # a robot that booted with its clock an hour ahead, corrected between runs
    assert c.anchor() == pytest.approx(-3600.0, abs=1e-6)
    assert c.time() == s.system and c.step_s() == 0.0
    assert c.anchor() == 0.0  # nothing stepped since: anchoring again moves nothing
    assert c.time() == s.system


def test_a_step_during_a_run_is_said_at_its_end(caplog):
    s = Sources()
    c = clock_of(s)
    log = logging.getLogger("swarm.test")
    with caplog.at_level(logging.WARNING, logger="swarm.test"):
        s.step(STEP_WARN_S / 2)
        assert said_step(c, log, "robot 3", "r1") == pytest.approx(STEP_WARN_S / 2, abs=1e-6)
        assert not caplog.records  # a small step (a clock slewed hard) is not news
        s.step(30.0)
        assert said_step(c, log, "robot 3", "r1") == pytest.approx(30.0 + STEP_WARN_S / 2, abs=1e-6)
    [rec] = caplog.records
    assert "robot 3, run r1: the system clock stepped by +30.050 s" in rec.getMessage()

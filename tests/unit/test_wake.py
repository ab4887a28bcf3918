"""swarm.core.wake.Wake: threading.Event's semantics, and no set() ever lost."""

from __future__ import annotations

import threading
import time

import pytest

from swarm.core.wake import Wake

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("cls", [Wake, threading.Event])
def test_set_stays_set_until_cleared(cls):
    w = cls()
    assert not w.is_set() and w.wait(0.0) is False
    w.set()
    w.set()  # twice: still one state
    assert w.is_set() and w.wait(0.0) is True and w.wait(1.0) is True  # a set stays set
    w.clear()
    assert not w.is_set()
    t0 = time.monotonic()
    assert w.wait(0.05) is False and time.monotonic() - t0 >= 0.04  # waits its timeout
    assert w.wait(-1.0) is False  # a negative timeout is no wait


@pytest.mark.timeout(30)
def test_a_set_from_another_thread_wakes_a_waiter():
    """The waiter may be blocked or about to block when the set comes: either way it returns, long
    before its timeout (a blocked waiter every round: test_no_set_is_lost_under_contention)."""
    w = Wake()
    woke = []
    ready = threading.Event()

    def waiter():
        ready.set()
        woke.append(w.wait(25.0))

    t = threading.Thread(target=waiter, daemon=True)
    t.start()
    assert ready.wait(10.0)
    w.set()
    t.join(10.0)
    assert not t.is_alive() and woke == [True]  # woken by the set, not by its timeout


@pytest.mark.timeout(60)
def test_no_set_is_lost_under_contention():
    """Two setters take turns with the loop: each bumps a counter, sets, and waits until the loop has
    seen its value; the loop waits, clears and reads the counter, as a run loop does. Every set must
    wake it: a lost one shows as a wait that ran out its timeout while the counter had moved."""
    w = Wake()
    lock = threading.Lock()
    state = {"n": 0, "seen": 0}
    seen_cond = threading.Condition(lock)
    rounds = 2000
    lost = 0

    def setter():
        for _ in range(rounds):
            with lock:
                state["n"] += 1
                mine = state["n"]
            w.set()
            with seen_cond:
                seen_cond.wait_for(lambda: state["seen"] >= mine, timeout=10)

    threads = [threading.Thread(target=setter, daemon=True) for _ in range(2)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 40
    while state["seen"] < 2 * rounds and time.monotonic() < deadline:
        t0 = time.monotonic()
        w.wait(1.0)
        waited = time.monotonic() - t0
        w.clear()
        with seen_cond:
            lost += waited >= 0.9 and state["n"] != state["seen"]
            state["seen"] = state["n"]
            seen_cond.notify_all()
    for t in threads:
        t.join(10.0)
    assert state["seen"] == 2 * rounds and lost == 0


wire = pytest.importorskip("swarm.proto._wire", reason="the compiled codec is not built here (no C compiler)")


@pytest.mark.timeout(30)
def test_a_deadline_waits_for_the_newest_armed_time_without_the_gil():
    """swarm.proto._wire.Deadline (a real-time robot's waker waits on it): wait(cap) returns True once the
    armed time passed, False after cap or stop(); a later arm while waiting is waited for, an earlier one
    ends the wait at once; another thread runs Python meanwhile (the GIL is released)."""
    d = wire.Deadline()
    assert d.due == float("inf")
    t0 = time.monotonic()
    assert d.wait(0.05) is False and 0.04 <= time.monotonic() - t0 < 5.0  # no deadline: the cap
    d.arm(time.monotonic() - 1.0)
    assert d.wait(5.0) is True  # already past
    d.arm(time.monotonic() + 0.05)
    pushed = threading.Event()
    counted = [0]

    def push_later():  # while the main thread waits: Python runs (no GIL held), then the deadline moves on
        while counted[0] < 1000:
            counted[0] += 1
        d.arm(time.monotonic() + 0.2)
        pushed.set()

    t0 = time.monotonic()
    threading.Thread(target=push_later, daemon=True).start()
    assert d.wait(5.0) is True
    assert pushed.is_set() and counted[0] == 1000 and time.monotonic() - t0 >= 0.2 and time.monotonic() >= d.due
    d.arm(time.monotonic() + 60.0)
    threading.Timer(0.05, lambda: d.arm(time.monotonic())).start()  # an earlier time wakes the waiter
    t0 = time.monotonic()
    assert d.wait(20.0) is True and time.monotonic() - t0 < 10.0
    d.arm(time.monotonic() + 60.0)
    threading.Timer(0.05, d.stop).start()
    t0 = time.monotonic()
    assert d.wait(20.0) is False and time.monotonic() - t0 < 10.0
    assert d.wait(20.0) is False  # stopped for good
    with pytest.raises(ValueError, match="NaN"):
        d.arm(float("nan"))
    with pytest.raises(TypeError):
        d.arm("soon")

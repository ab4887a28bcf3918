"""Windows, not "newest wins" (swarm.proto.window)."""

import pytest

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.proto import window
from swarm.proto.window import CONFIRM, DUPLICATE, JUMP, OK, STALE

pytestmark = pytest.mark.unit

# every test runs on the Python window and on the compiled one (swarm/proto/_wire_window.c) where it was built
KINDS = [window.Window] + ([window._compiled.Window] if window.COMPILED else [])


@pytest.fixture(params=KINDS, ids=lambda k: k.__module__)
def Window(request):
    return request.param


def test_spans_cover_twice_the_watchdog_and_at_least_two_seconds():
    assert window.spans(0.02, 0.5) == (2.0, 101)
    assert window.spans(0.1, 3.0) == (6.0, 61)


def test_forward_in_the_window_is_adopted_and_everything_else_is_not(Window):
    w = Window(2.0, 101)
    assert w.check(0.0, 0) == OK  # the first message anchors
    assert w.check(0.02, 1) == OK
    assert w.check(0.02, 1) == DUPLICATE
    assert w.check(0.0, 0) == STALE
    assert w.check(0.04, 2**53 - 1) == JUMP  # one crafted sequence number
    assert w.check(1e9, 3) == JUMP  # one crafted time
    assert (w.t, w.seq) == (0.02, 1)  # nothing refused was adopted
    assert w.check(0.04, 2) == OK  # the true sender goes on


def test_a_sender_that_truly_jumped_is_followed_after_confirm_messages(Window):
    w = Window(2.0, 101)
    w.check(0.0, 0)
    out = [w.check(10.0 + 0.02 * k, 500 + k) for k in range(CONFIRM)]  # a 10 s stall, then regular messages
    assert out == [JUMP] * (CONFIRM - 1) + [OK]
    assert w.check(10.0 + 0.02 * CONFIRM, 500 + CONFIRM) == OK


def test_a_window_anchored_by_a_crafted_message_recovers(Window):
    w = Window(2.0, 101)
    assert w.check(1e9, 2**53 - 1) == OK  # the attacker spoke first
    out = [w.check(0.02 * k, k) for k in range(CONFIRM + 2)]
    assert out == [STALE] * (CONFIRM - 1) + [OK, OK, OK]


def test_crafted_messages_interleaved_with_true_ones_never_take_over(Window):
    w = Window(2.0, 101)
    w.check(0.0, 0)
    for k in range(1, 200):
        assert w.check(0.02 * k, k) == OK
        assert w.check(1e9 + k, 2**50 + 7 * k) == JUMP  # never CONFIRM in a row: true messages come between


def test_reset_starts_afresh(Window):
    w = Window(2.0, 101)
    w.check(50.0, 2500)
    w.reset()
    assert w.check(0.0, 0) == OK  # a restarted sender counts from 0 again


def test_a_lockstep_window_refuses_a_t_that_is_not_its_seqs_tick_and_never_follows_it(Window):
    """With the tick dt (lock-step), t must be seq x dt within TICK_EPS: anything else is FORGED, first message
    or not, however often repeated (never a candidate to re-anchor), and the true messages go on."""
    from swarm.proto.window import FORGED, TICK_EPS
    w = Window(2.0, 101, dt=0.02)
    assert w.check(1e8, 1) == FORGED and w.t is None  # not even the first message anchors it
    assert w.check(0.0, 0) == OK
    for _ in range(CONFIRM + 2):
        assert w.check(1e8, 1) == FORGED
    assert w.check(0.02 + TICK_EPS / 2, 1) == OK  # a rounding of k x dt passes
    assert w.check(0.04 + 10 * TICK_EPS, 2) == FORGED
    assert w.check(float("nan"), 2) == FORGED
    assert w.check(0.04, 2) == OK and (w.t, w.seq) == (0.04, 2)
    assert w.check(0.02, 1) == STALE  # older and true: stale, as before
    assert Window(2.0, 101).check(1e8, 1) == OK  # real time: t and seq are not tied



_ts = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, 0.02, 0.04, 2.0, 2.02, 1e9]))
_seqs = st.one_of(st.integers(-5, 2**53), st.sampled_from([0, 1, 2, 100, 101, 102, 2**53]))


@pytest.mark.skipif(not window.COMPILED, reason="the compiled window is not built here (no C compiler)")
@settings(max_examples=300, deadline=None)
@given(st.sampled_from([(2.0, 101, 0.0), (2.0, 101, 0.02), (math.inf, 2**62, 0.0), (math.inf, 2**62, 0.02)]),
       st.lists(st.tuples(st.sampled_from(["check", "check", "check", "peek", "take", "reset"]), _ts, _seqs),
                max_size=40))
def test_the_compiled_window_says_and_keeps_what_the_python_one_does(spans, calls):
    """On random calls (times anywhere, NaN and inf too; sequence numbers up to 2^53), the compiled window
    answers every call as the Python one and keeps the same t, seq, candidate and run."""
    a, b = window.Window(*spans), window._compiled.Window(*spans)
    for name, t, seq in calls:
        args = () if name == "reset" else (t, seq)
        assert getattr(a, name)(*args) == getattr(b, name)(*args), (name, t, seq)
        assert repr((a.t, a.seq, a._cand, a._run)) == repr((b.t, b.seq, b._cand, b._run))  # a NaN as a NaN
    assert (b.t_span, b.seq_span, b.dt) == (a.t_span, a.seq_span, a.dt)


def test_outside_never_counts_toward_re_anchoring_and_by_seq_alone_says_a_counter_jump(Window):
    """window.outside: what the receiver's own clock puts ahead is a jump, and no run of such messages re-anchors
    the window; behind, an empty window takes nothing (stale), a full one only what it takes as it is.
    window.by_seq_alone: refused for the seq while the t is within the span forward."""
    w = Window(2.0, 101)
    assert window.outside(w, 1.0, 50, ahead=False) == STALE and w.t is None  # behind, nothing anchored
    assert w.check(10.0, 500) == OK
    for m in range(CONFIRM + 2):
        assert window.outside(w, 5e8 + m, 10**12 + m, ahead=True) == JUMP
        assert window.outside(w, 1.0 + m * 0.02, 50 + m, ahead=False) == STALE
    assert (w.t, w.seq) == (10.0, 500)
    assert window.outside(w, 10.02, 501, ahead=False) == OK and (w.t, w.seq) == (10.02, 501)  # behind now, yet next
    assert window.by_seq_alone(w, 10.04, 10**12) and window.by_seq_alone(w, 10.04, 7)
    assert not window.by_seq_alone(w, 10.04, 502)  # in the window
    assert not window.by_seq_alone(w, 50.0, 10**12)  # a jump in t too: a sender that stalled may do that
    assert not window.by_seq_alone(Window(2.0, 101), 10.0, 10**12)  # nothing anchored yet

"""The robots' own counts of bad messages (their statuses' `bad`), as the world and the referee add them up."""

import pytest

from swarm.proto.protocol import REFUSALS_PER_S_MAX, Claims

pytestmark = pytest.mark.unit


def test_a_claim_beyond_what_a_robot_can_have_seen_is_cut_to_the_bound():
    c = Claims()
    c.take(3, 12, 100.0)
    c.take(4, 2**53, 100.0)  # a lie on its own status, in its first one
    assert c.by_robot[4] == REFUSALS_PER_S_MAX and c.capped == 1
    c.take(4, 2**53, 100.5)  # and again half a second later: it grows by at most the rate over that time
    assert c.by_robot[4] == REFUSALS_PER_S_MAX + int(1.5 * REFUSALS_PER_S_MAX) and c.capped == 2
    assert c.total == 12 + c.by_robot[4] < 2**53


def test_true_counts_are_taken_as_they_are_and_a_restart_counts_from_zero():
    c = Claims()
    for k, bad in enumerate((0, 5, 40_000, 40_001)):
        c.take(1, bad, 10.0 + 0.5 * k)
    assert c.by_robot[1] == 40_001 and c.capped == 0
    c.take(1, 2, 20.0)  # a restarted robot process
    assert c.total == 2 and list(c.values()) == [2]

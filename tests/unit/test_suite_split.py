"""The whole suite's split over two workers (tests/conftest.py): the scheduler reads each test's tier from its
file's text, since xdist's controller collects nothing. It must read every test's tier as collection does: a
test it took for a unit test while it starts processes would run beside the other worker's processes."""

from __future__ import annotations

import pytest

from tests.conftest import TIERS, unit_test

pytestmark = pytest.mark.unit


def test_the_scheduler_reads_each_collected_tests_tier_as_its_markers_say(collected_tests):
    items = collected_tests  # before -m or -k deselected any: `pytest -m unit` checks them all
    wrong = [it.nodeid for it in items if unit_test(it.nodeid) != ({m.name for m in it.iter_markers()} & set(TIERS) == {"unit"})]
    assert items and not wrong, wrong[:20]


def test_a_test_whose_tier_the_text_does_not_tell_is_not_taken_for_a_unit_test(tmp_path):
    assert not unit_test("tests/no/such_file.py::test_x")
    assert not unit_test("tests/unit/test_law.py")  # a file, not a test
    # a file of unit tests with one integration test among them: that one is not, the others are
    assert not unit_test("tests/protocol/test_docs.py::test_no_tracked_file_cites_a_file_outside_the_repository")
    assert unit_test("tests/protocol/test_docs.py::test_protocol_doc_names_every_key")

"""bench/results_doc.py: docs/results.md as sections, each rewritten by its own bench, the others kept."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
import results_doc  # noqa: E402


def test_a_section_replaces_its_own_and_keeps_the_others_in_order(tmp_path):
    doc = tmp_path / "results.md"
    results_doc.write_section("numpy", "## numpy\n\nfirst", doc)
    results_doc.write_section("paper", "## paper\n\ntables", doc)
    results_doc.write_section("numpy", "## numpy\n\nsecond", doc)
    text = doc.read_text()
    assert text.startswith(results_doc.HEAD)
    assert "first" not in text and "second" in text and "tables" in text
    assert text.index("<!-- begin paper -->") < text.index("<!-- begin numpy -->")  # SECTIONS' order
    assert text.count("<!-- begin numpy -->") == 1
    with pytest.raises(ValueError, match="unknown section"):
        results_doc.write_section("nope", "x", doc)


def test_the_repository_results_carry_every_section():
    text = (Path(__file__).resolve().parents[2] / "docs" / "results.md").read_text()
    for key in results_doc.SECTIONS:
        assert f"<!-- begin {key} -->" in text and f"<!-- end {key} -->" in text
    assert "machine:" in text  # the benches name the machine they measured on

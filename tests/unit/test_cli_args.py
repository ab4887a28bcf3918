"""The command line's own parsing: values that start with a dash."""

from __future__ import annotations

from swarm.cli.main import _dash_values, main


def test_a_value_that_starts_with_a_dash_is_a_value():
    assert _dash_values(["sim", "--kill", "-1@3"]) == ["sim", "--kill=-1@3"]
    assert _dash_values(["robot", "--initial-pose", "-1.5,2,0", "--id", "1"]) == ["robot", "--initial-pose=-1.5,2,0",
                                                                                  "--id", "1"]
    assert _dash_values(["sim", "--dt", ".5", "--quiet"]) == ["sim", "--dt", ".5", "--quiet"]
    assert _dash_values(["sim", "--quiet", "--robots", "3"]) == ["sim", "--quiet", "--robots", "3"]


def test_kill_of_a_negative_id_names_the_id_not_argparse(capsys):
    """`--kill -1@3` said "argument --kill: expected one argument"."""
    assert main(["sim", "--kill", "-1@3", "--quiet"]) == 2
    assert "--kill '-1@3': robot -1 is not in the scenario" in capsys.readouterr().err

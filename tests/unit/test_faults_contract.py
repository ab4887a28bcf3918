"""The [faults] contract (docs/faults.md): the contract's example and the defaults, the refusals (each naming
the file, the key and the reason) and what is allowed at the edges, the dataclasses' own checks, --faults
files, the command-line shorthands (--drop, --kill) and repeated fault flags, the canonical text and its round
trip, the advisories that valid rules which never act get, and a scenario's [faults] table checked when a
--faults file replaces it. When faults act and how messages fare: test_faults_decisions.py."""

from __future__ import annotations

import math
import os
import tomllib

import numpy as np
import pytest

from swarm.core import faults as F
from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.faults import (
    DelayRule,
    DropRule,
    Faults,
    Hang,
    Kill,
    Partition,
)
from swarm.core.scenario import ScenarioError
from tests.unit.faults_helpers import CONTRACT, CONTRACT_FAULTS, DROP, DURATION, N, _random_faults, _rule, parse

pytestmark = pytest.mark.unit


def refusal(text: str, **kw) -> ScenarioError:
    with pytest.raises(ScenarioError) as info:
        parse(text, **kw)
    return info.value


# --------------------------------------------------------------------------- the contract


def test_the_contract_example_parses_to_its_rules():
    f = parse(CONTRACT)
    assert f == CONTRACT_FAULTS
    assert f and not Faults.empty(7)
    assert f.drops[0].senders == (0, 3) and f.delays[0].end == math.inf


def test_defaults_seed_burst_window_jitter():
    f = parse('[faults]\n[[faults.drop]]\nclass = "all"\np = 0.5\n[[faults.delay]]\nclass = "ref"\nticks = 0\n',
              seed=11)
    assert f.seed == 11  # run.seed
    d, y = f.drops[0], f.delays[0]
    assert (d.burst, d.senders, d.receivers, d.start, d.end) == (1.0, None, None, 0.0, math.inf)
    assert (y.jitter, y.start, y.end) == (0, 0.0, math.inf)
    assert parse("[faults]\n", seed=3) == Faults.empty(3) and not parse("[faults]\n")
    assert parse(f"[faults]\nseed = {2**63 - 1}\n").seed == 2**63 - 1  # the largest seed
    # a run seed beyond int64 still gives a seed (modulo 2^63)
    assert parse("[faults]\n", seed=2**63 + 5).seed == 5


def test_from_and_to_lists_are_kept_sorted_so_equal_rules_compare_equal():
    a = parse('[faults]\n[[faults.drop]]\nclass = "state"\np = 0.1\nfrom = [3, 0]\nto = [6, 2, 4]\n')
    assert a.drops[0] == DropRule("state", 0.1, senders=(0, 3), receivers=(2, 4, 6))
    assert F.to_toml(a) == F.to_toml(Faults(0, (DropRule("state", 0.1, 1.0, [0, 3], [6, 4, 2]),)))


# (id, [faults] text, expected key, a fragment of the expected reason)
REFUSALS = [
    ("unknown table key", "[faults]\ndorp = []\n", "faults.dorp", "unknown key"),
    ("seed negative", "[faults]\nseed = -1\n", "faults.seed", ">= 0"),
    ("seed not integer", "[faults]\nseed = 1.5\n", "faults.seed", "must be an integer"),
    ("seed too large", f"[faults]\nseed = {2**63}\n", "faults.seed", "below 2^63"),
    ("drop not tables", "[faults]\ndrop = 3\n", "faults.drop", "array of tables"),
    ("unknown rule key", _rule("drop", DROP + "prob = 0.1"), "faults.drop[0].prob", "unknown key"),
    ("missing p", _rule("drop", 'class = "state"'), "faults.drop[0].p", "missing required key"),
    ("missing class", _rule("drop", "p = 0.1"), "faults.drop[0].class", "missing required key"),
    ("unknown class", _rule("drop", 'class = "states"\np = 0.1'), "faults.drop[0].class", "must be one of"),
    ("class not a string", _rule("drop", "class = 3\np = 0.1"), "faults.drop[0].class", "must be one of"),
    ("class a list", _rule("drop", 'class = ["state"]\np = 0.1'), "faults.drop[0].class", "must be one of"),
    ("p above 1", _rule("drop", 'class = "state"\np = 1.5'), "faults.drop[0].p", "0 <= p <= 1"),
    ("p below 0", _rule("drop", 'class = "state"\np = -0.1'), "faults.drop[0].p", "0 <= p <= 1"),
    ("p nan", _rule("drop", 'class = "state"\np = nan'), "faults.drop[0].p", "finite"),
    ("p a string", _rule("drop", 'class = "state"\np = "0.1"'), "faults.drop[0].p", "must be a number"),
    ("burst below 1", _rule("drop", DROP + "burst = 0.5"), "faults.drop[0].burst", ">= 1"),
    ("from out of range", _rule("drop", DROP + "from = [0, 7]"), "faults.drop[0].from[1]", "not in the scenario"),
    ("to out of range", _rule("drop", DROP + "to = [-1]"), "faults.drop[0].to[0]", "not in the scenario"),
    ("from not ids", _rule("drop", DROP + 'from = "all"'), "faults.drop[0].from", "list of robot ids"),
    ("from a float", _rule("drop", DROP + "from = [1.0]"), "faults.drop[0].from[0]", "an integer"),
    ("from a boolean", _rule("drop", DROP + "from = [true]"), "faults.drop[0].from[0]", "an integer"),
    ("from empty", _rule("drop", DROP + "from = []"), "faults.drop[0].from", "lists no robot"),
    ("start negative", _rule("drop", DROP + "start = -1.0"), "faults.drop[0].start", ">= 0"),
    ("end before start", _rule("drop", DROP + "start = 10.0\nend = 5.0"), "faults.drop[0].end", "not be before start"),
    ("end infinite", _rule("drop", DROP + "end = inf"), "faults.drop[0].end", "finite"),
    ("delay ticks missing", _rule("delay", 'class = "state"'), "faults.delay[0].ticks", "missing required key"),
    ("delay ticks negative", _rule("delay", 'class = "state"\nticks = -1'), "faults.delay[0].ticks", ">= 0"),
    ("delay ticks float", _rule("delay", 'class = "state"\nticks = 2.0'), "faults.delay[0].ticks", "an integer"),
    ("delay jitter negative", _rule("delay", 'class = "state"\nticks = 1\njitter = -2'), "faults.delay[0].jitter",
     ">= 0"),
    ("delay jitter float", _rule("delay", 'class = "state"\nticks = 1\njitter = 0.5'), "faults.delay[0].jitter",
     "an integer"),
    ("delay too long", _rule("delay", 'class = "state"\nticks = 999999\njitter = 2'), "faults.delay[0].jitter",
     "at most 1000000"),
    ("delay to out of range", _rule("delay", 'class = "cmd"\nticks = 1\nfrom = [9]'), "faults.delay[0].from[0]",
     "not in the scenario"),
    ("groups missing", _rule("partition", "start = 1.0"), "faults.partition[0].groups", "missing required key"),
    ("groups not lists", _rule("partition", "groups = [1, 2]"), "faults.partition[0].groups[0]", "list of robot ids"),
    ("groups empty", _rule("partition", "groups = []"), "faults.partition[0].groups", "non-empty"),
    ("a group empty", _rule("partition", "groups = [[0], []]"), "faults.partition[0].groups[1]", "is empty"),
    ("robot in two groups", _rule("partition", "groups = [[0, 1, 2], [3, 1]]"), "faults.partition[0].groups[1][1]",
     "robot 1 is already in groups[0]"),
    ("robot twice in a group", _rule("partition", "groups = [[0, 1, 0]]"), "faults.partition[0].groups[0][2]",
     "already in this group"),
    ("group id out of range", _rule("partition", "groups = [[0, 7]]"), "faults.partition[0].groups[0][1]",
     "not in the scenario"),
    ("partition window", _rule("partition", "groups = [[0]]\nstart = 5.0\nend = 4.0"), "faults.partition[0].end",
     "not be before start"),
    ("partitions overlap", ("[faults]\n[[faults.partition]]\ngroups = [[0]]\nstart = 5.0\nend = 9.0\n"
     "[[faults.partition]]\ngroups = [[1]]\nstart = 8.0\nend = 10.0\n"), "faults.partition[1].start", "overlaps"),
    ("kill robot out of range", _rule("kill", "robot = 7\nat = 1.0"), "faults.kill[0].robot", "not in the scenario"),
    ("kill robot a boolean", _rule("kill", "robot = true\nat = 1.0"), "faults.kill[0].robot", "an integer"),
    ("kill at negative", _rule("kill", "robot = 1\nat = -0.5"), "faults.kill[0].at", ">= 0"),
    ("kill without at", _rule("kill", "robot = 1"), "faults.kill[0].at", "missing required key"),
    ("kill restart zero", _rule("kill", "robot = 1\nat = 1.0\nrestart = 0.0"), "faults.kill[0].restart", "> 0"),
    ("kill unknown key", _rule("kill", "robot = 1\nat = 1.0\nrespawn = 1.0"), "faults.kill[0].respawn", "unknown key"),
    ("hang robot out of range", _rule("hang", "robot = 70\nat = 1.0\nduration = 1.0"), "faults.hang[0].robot",
     "not in the scenario"),
    ("hang at negative", _rule("hang", "robot = 1\nat = -1.0\nduration = 1.0"), "faults.hang[0].at", ">= 0"),
    ("hang duration zero", _rule("hang", "robot = 1\nat = 1.0\nduration = 0.0"), "faults.hang[0].duration", "> 0"),
    ("hang duration missing", _rule("hang", "robot = 1\nat = 1.0"), "faults.hang[0].duration", "missing required"),
    ("hang of a dead robot", ("[faults]\n[[faults.kill]]\nrobot = 3\nat = 5.0\n[[faults.hang]]\nrobot = 3\nat = 10.0\n"
     "duration = 1.0\n"), "faults.hang[0].at", "robot 3 is dead for good"),
    ("second kill before the restart", ("[faults]\n[[faults.kill]]\nrobot = 3\nat = 5.0\nrestart = 2.0\n"
     "[[faults.kill]]\nrobot = 3\nat = 6.5\n"), "faults.kill[1].at", "robot 3 is dead until 7 s"),
    ("kill of a hung robot", ("[faults]\n[[faults.kill]]\nrobot = 2\nat = 6.0\n[[faults.hang]]\nrobot = 2\nat = 5.0\n"
     "duration = 3.0\n"), "faults.kill[0].at", "robot 2 is stopped until 8 s"),
    ("two hangs at once", ("[faults]\n[[faults.hang]]\nrobot = 2\nat = 5.0\nduration = 3.0\n[[faults.hang]]\n"
     "robot = 2\nat = 5.0\nduration = 1.0\n"), "faults.hang[1].at", "one process fault of a robot at a time"),
    ("too many drops", "[faults]\n" + "[[faults.drop]]\nclass = \"state\"\np = 0.1\n" * 65, "faults.drop",
     "at most 64"),
]


@pytest.mark.parametrize("text, key, reason", [c[1:] for c in REFUSALS], ids=[c[0] for c in REFUSALS])
def test_refusals_name_the_file_the_key_and_the_reason(text, key, reason):
    e = refusal(text)
    assert (e.where, e.key) == ("f.toml", key), str(e)
    assert reason in e.reason, str(e)
    assert str(e).startswith(f"f.toml: {key}: ")


ALLOWED = [
    ("a process fault right after a restart", ("[faults]\n[[faults.kill]]\nrobot = 3\nat = 5.0\nrestart = 2.0\n"
     "[[faults.hang]]\nrobot = 3\nat = 7.0\nduration = 1.0\n")),
    ("faults of different robots at once", ("[faults]\n[[faults.kill]]\nrobot = 3\nat = 5.0\n[[faults.hang]]\n"
     "robot = 4\nat = 5.0\nduration = 1.0\n")),
    ("partitions back to back", ("[faults]\n[[faults.partition]]\ngroups = [[0]]\nstart = 5.0\nend = 9.0\n"
     "[[faults.partition]]\ngroups = [[1]]\nstart = 9.0\nend = 10.0\n")),
    ("a window past the end", _rule("drop", DROP + "start = 59.0\nend = 1000.0")),
    ("p = 0 and p = 1 with bursts", ("[faults]\n[[faults.drop]]\nclass = \"state\"\np = 0\nburst = 3.0\n"
     "[[faults.drop]]\nclass = \"state\"\np = 1\nburst = 3.0\n")),
    ("the largest p a burst allows", _rule("drop", 'class = "state"\np = 0.75\nburst = 3.0')),
    ("a group of everyone but one", _rule("partition", "groups = [[0, 1, 2, 3, 4, 5]]")),
    ("all classes with robot lists", _rule("delay", 'class = "all"\nticks = 1\nfrom = [1]\nto = [2]')),
]


@pytest.mark.parametrize("text", [c[1] for c in ALLOWED], ids=[c[0] for c in ALLOWED])
def test_what_is_allowed_at_the_edges(text):
    f = parse(text)
    assert f and parse(F.to_toml(f)) == f


def test_the_partition_of_everyone_but_one_forms_two_groups():
    w = parse(_rule("partition", "groups = [[0, 1, 2, 3, 4, 5]]")).partitions[0]
    assert [w.group(i) for i in range(N)] == [0, 0, 0, 0, 0, 0, 1]


def test_dataclasses_validate_themselves():
    with pytest.raises(ValueError, match="p: must be a probability"):
        DropRule("state", 2.0)
    with pytest.raises(ValueError, match="ticks: must be a whole number"):
        DelayRule("state", 1.5)
    with pytest.raises(ValueError, match="end: must not be before start"):
        Partition(((0,),), 3.0, 2.0)
    with pytest.raises(ValueError, match="seed"):
        Faults(seed=-1)
    with pytest.raises(ValueError, match="kill\\[1\\].at: robot 0 is dead for good"):
        Faults(kills=(Kill(0, 1.0), Kill(0, 2.0)))


# --------------------------------------------------------------------------- --faults FILE


def test_a_faults_file_holds_only_a_faults_table(tmp_path):
    path = tmp_path / "faults.toml"
    path.write_text(CONTRACT)
    assert F.load_faults_file(str(path), N, DURATION, 0) == CONTRACT_FAULTS
    cases = [
        ("[run]\nduration = 3.0\n" + CONTRACT, "run", "only a [faults] table"),
        ("seed = 3\n", "seed", "only a [faults] table"),
        ("# nothing\n", "faults", "missing"),
        ("faults = 3\n", "faults", "must be a table"),
        ("[faults\n", "", "not valid TOML"),
        (_rule("kill", "robot = 9\nat = 1.0"), "faults.kill[0].robot", "not in the scenario"),
    ]
    for text, key, reason in cases:
        path.write_text(text)
        with pytest.raises(ScenarioError) as info:
            F.load_faults_file(str(path), N, DURATION, 0)
        assert (info.value.where, info.value.key) == (str(path), key) and reason in info.value.reason, str(info.value)
    with pytest.raises(ScenarioError, match="no such file"):
        F.load_faults_file(str(tmp_path / "none.toml"), N, DURATION, 0)
    path.write_bytes(b"[faults]\nseed = 1 # \xff\n")
    with pytest.raises(ScenarioError, match=r"not UTF-8 text \(byte 20, line 2\)"):
        F.load_faults_file(str(path), N, DURATION, 0)
    # a directory and a FIFO exist but are no file (a FIFO would block the read): said so, not "no such file"
    with pytest.raises(ScenarioError, match="is a directory"):
        F.load_faults_file(str(tmp_path), N, DURATION, 0)
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(ScenarioError, match="is not a regular file"):
        F.load_faults_file(str(fifo), N, DURATION, 0)


# --------------------------------------------------------------------------- shorthands


def test_drop_shorthand():
    assert F.drop_shorthand(0.2) == DropRule("all", 0.2, 1.0, None, None, 0.0, math.inf)
    for p in (-0.1, 1.5, math.nan, True):
        with pytest.raises(ScenarioError) as info:
            F.drop_shorthand(p)
        assert (info.value.where, info.value.key) == ("command line", "--drop")


def test_kill_shorthand():
    assert F.kill_shorthand("2@5,3@7.5", N, DURATION) == (Kill(2, 5.0), Kill(3, 7.5))
    assert F.kill_shorthand(" 0 @ 0 ", N, DURATION) == (Kill(0, 0.0),)
    cases = [
        ("2@x", "--kill '2@x'", "the time 'x' is not a number"),
        ("x@2", "--kill 'x@2'", "the robot 'x' is not an integer"),
        ("2", "--kill '2'", "give ID@T"),
        ("2@", "--kill '2@'", "give ID@T"),
        ("1@1,", "--kill ''", "give ID@T"),
        ("", "--kill ''", "give ID@T"),
        ("9@1", "--kill '9@1'", "robot 9 is not in the scenario"),
        ("2@-1", "--kill '2@-1'", ">= 0"),
        ("2@nan", "--kill '2@nan'", "finite"),
        ("2@60", "--kill '2@60'", "never happen"),
    ]
    for text, key, reason in cases:
        with pytest.raises(ScenarioError) as info:
            F.kill_shorthand(text, N, DURATION)
        e = info.value
        assert (e.where, e.key) == ("command line", key) and reason in e.reason, str(e)


def test_merged_adds_shorthand_rules_after_the_files():
    f = parse(CONTRACT)
    m = F.merged(f, drops=(F.drop_shorthand(0.1),), kills=F.kill_shorthand("1@4", N, DURATION))
    assert m.drops == f.drops + (DropRule("all", 0.1),) and m.kills == f.kills + (Kill(1, 4.0),)
    assert (m.seed, m.delays, m.partitions, m.hangs) == (f.seed, f.delays, f.partitions, f.hangs)
    assert F.merged(f) == f
    for kills in ("5@16", "3@11", "2@5,2@6"):  # robot 5 is dead 15..17 s, robot 3 hung 10..13 s; two kills of 2
        with pytest.raises(ScenarioError) as info:
            F.merged(f, kills=F.kill_shorthand(kills, N, DURATION))
        assert (info.value.where, info.value.key) == ("command line", "--kill")
        assert "overlaps" in info.value.reason
    with pytest.raises(ScenarioError) as info:
        F.merged(f, drops=[F.drop_shorthand(0.1)] * F.MAX_RULES)
    assert info.value.key == "--drop"


@pytest.mark.parametrize("command", ["sim", "up", "campaign"])
def test_a_repeated_fault_flag_is_joined_or_refused_never_silently_replaced(command, capsys):
    """`--kill 2@5 --kill 3@6` asks for two kills: both are kept; a second --drop or --faults would replace
    the first, so it is refused with the flag named."""
    from swarm.cli.parser import build_parser

    p = build_parser()
    args = p.parse_args([command, "--kill", "2@5", "--kill", "3@6,4@7"])
    assert args.kill == "2@5,3@6,4@7"
    assert F.kill_shorthand(args.kill, 7, 20.0)  # a list the shorthand takes
    drop = "0.3" if command != "campaign" else "0.1,0.3"
    assert p.parse_args([command, "--drop", drop]).drop is not None
    for flag, a, b in (("--drop", drop, "0"), ("--faults", "a.toml", "b.toml")):
        with pytest.raises(SystemExit) as info:
            p.parse_args([command, flag, a, flag, b])
        assert info.value.code == 2
        assert f"{flag} given twice" in capsys.readouterr().err


# --------------------------------------------------------------------------- canonical text


def test_to_toml_is_canonical_and_loads_back():
    f = parse(CONTRACT)
    text = F.to_toml(f)
    assert parse(text) == f
    assert text == F.to_toml(parse(text)) == F.to_toml(CONTRACT_FAULTS)
    assert text.startswith("[faults]\nseed = 7\n")
    assert "end = 30.0" in text and text.count("end =") == 2  # the open windows write no end
    assert F.to_toml(Faults.empty(3)) == ""
    # inside a scenario file's text the table reads the same
    assert tomllib.loads("[run]\nduration = 1.0\n" + text)["faults"] == tomllib.loads(text)["faults"]


def test_random_faults_round_trip_through_the_canonical_text():
    rng = np.random.default_rng(3)
    for _ in range(200):
        f = _random_faults(rng)
        text = F.to_toml(f)
        if not f:
            assert text == ""
            continue
        assert parse(text) == f, text
        assert F.to_toml(parse(text)) == text


# --------------------------------------------------------------------------- advisories


@pytest.mark.parametrize("name, text, said", [
    ("burst too short for p", _rule("drop", 'class = "state"\np = 0.9\nburst = 2.0'),
     "faults.drop[0] has burst = 2, shorter than p = 0.9 allows"),
    ("pose from robots", _rule("drop", 'class = "pose"\np = 0.1\nfrom = [1]'),
     "faults.drop[0] matches no message: a pose is sent by the world"),
    ("ref from robots", _rule("delay", 'class = "ref"\nticks = 1\nfrom = [1]'),
     "faults.delay[0] matches no message: a ref is sent by the leader"),
    ("cmd to robots", _rule("drop", 'class = "cmd"\np = 0.1\nto = [1]'),
     "faults.drop[0] matches no message: a cmd goes to the world"),
    ("end equals start", _rule("drop", DROP + "start = 10.0\nend = 10.0"), "faults.drop[0] has an empty window"),
    ("start after the run", _rule("drop", DROP + "start = 61.0"), "faults.drop[0] starts at 61 s, after the run's last"),
    ("partition after the run", _rule("partition", "groups = [[0]]\nstart = 70.0"), "faults.partition[0] starts at 70"),
    ("one group of everyone", _rule("partition", "groups = [[0, 1, 2, 3, 4, 5, 6]]"),
     "faults.partition[0] puts all 7 robots in one group"),
    ("kill after the end", _rule("kill", "robot = 1\nat = 60.5"), "faults.kill[0] is at 60.5 s, after the run's last"),
    ("hang after the end", _rule("hang", "robot = 1\nat = 61.0\nduration = 1.0"), "faults.hang[0] is at 61 s"),
])
def test_valid_rules_that_never_act_are_accepted_and_said(name, text, said):
    """The contract accepts these (section 8 refuses what section 6 refuses: unknown keys, wrong types,
    non-finite numbers...): they were refused (exit 2). They now run, and the run says what they do."""
    f = parse(text)
    assert any(said in a for a in F.advisories(f, DURATION, N)), F.advisories(f, DURATION, N)


def test_a_burst_too_short_for_p_keeps_p_and_the_shortest_bursts_that_lose_it():
    f = parse(_rule("drop", 'class = "state"\np = 0.9\nburst = 2.0'))
    assert f.drops[0].p == 0.9 and f.drops[0].burst == pytest.approx(9.0) and f.drops[0].burst_given == 2.0
    assert parse(F.to_toml(f)) == f  # the canonical text holds the bursts used: every process decides the same
    assert parse(_rule("drop", DROP + "from = [2, 1, 2]")).drops[0].senders == (1, 2)


def test_advisories():
    f = Faults(0, drops=(DropRule("state", 0.0),), delays=(DelayRule("ref", 0),),
               kills=(Kill(1, 50.0, 20.0),), hangs=(Hang(2, 59.0, 1.0),))
    adv = F.advisories(f, DURATION)
    assert len(adv) == 4 and "never loses" in adv[0] and "never delays" in adv[1]
    assert "stays dead" in adv[2] and "stays stopped" in adv[3]
    assert F.advisories(parse(CONTRACT), DURATION) == []


# --------------------------------------------------------------------------- from audits and reviews


def test_a_scenario_faults_table_is_checked_even_when_a_faults_file_replaces_it(tmp_path):
    """A scenario with p = 3.0 in its [faults] ran without a word when --faults replaced the table (from a
    contract audit): a broken file is refused whatever replaces a part of it."""
    scn = tmp_path / "s.toml"
    base = scenario_file.load("paper-50hz", Overrides(robots=7), progress=scenario_file.silent)
    scn.write_text(scenario_file.to_toml(base) + '\n[faults]\n[[faults.drop]]\nclass = "state"\np = 3.0\n')
    good = tmp_path / "f.toml"
    good.write_text(CONTRACT)
    with pytest.raises(ScenarioError, match=r"s\.toml: faults\.drop\[0\]\.p: must be a probability"):
        scenario_file.load(str(scn), Overrides(faults=str(good)), progress=scenario_file.silent)


def test_an_empty_partition_window_overlaps_nothing_in_any_order():
    for text in ("groups = [[0]]\nstart = 5.0\nend = 8.0\n[[faults.partition]]\ngroups = [[1]]\nstart = 5.0\nend = 5.0",
                 "groups = [[1]]\nstart = 5.0\nend = 5.0\n[[faults.partition]]\ngroups = [[0]]\nstart = 3.0\nend = 8.0"):
        assert len(parse(_rule("partition", text)).partitions) == 2


def test_a_replaced_faults_table_is_checked_against_the_files_own_robots(tmp_path):
    """--robots 5 with --faults: the replaced table's kill of robot 6 (of the file's 7) was refused (review)."""
    scn = tmp_path / "s.toml"
    scn.write_text("[run]\nduration = 5.0\ndt = 0.02\n[leader]\nstart = [0.0, 0.0, 0.0]\n"
                   "segments = [{duration = 5.0, v = 0.3, w = 0.0}]\n[formation]\nhex = {count = 7, spacing = 1.5}\n"
                   "[robots]\nrandom = {count = 7, region = [-12.0, -4.0, -4.0, 4.0]}\n"
                   "[faults]\n[[faults.kill]]\nrobot = 6\nat = 1.0\n")
    other = tmp_path / "f.toml"
    other.write_text('[faults]\n[[faults.drop]]\nclass = "state"\np = 0.1\n')
    got = scenario_file.load(str(scn), Overrides(robots=5, faults=str(other)), progress=scenario_file.silent)
    assert got.n == 5 and got.faults.drops and not got.faults.kills

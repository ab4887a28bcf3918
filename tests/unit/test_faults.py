"""The fault model (docs/faults.md): the [faults] contract and its refusals, shorthands, the canonical
text, the schedule queries, and faultgen's decisions (statistics, independence, purity, compiled ==
plain bit for bit)."""

from __future__ import annotations

import os

import math
import tomllib

import numpy as np
import pytest

from swarm.core import faultgen as fg
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
from swarm.core.faulttable import FaultTable, first_tick
from swarm.core.scenario import ScenarioError

pytestmark = pytest.mark.unit

N = 7  # robots of the scenario the faults are checked against
DURATION = 60.0  # s

# The example of the faults contract (docs/faults.md).
CONTRACT = """
[faults]
seed = 7                  # optional, default run.seed

[[faults.drop]]           # lose messages, each message on each link on its own
class = "state"           # "state" | "pose" | "cmd" | "ref" | "all"
p = 0.3                   # probability, 0 <= p <= 1
burst = 1.0               # optional mean burst length in messages (>= 1; 1 = independent losses)
from = [0, 3]             # optional sender robot ids (default: all)
to = [1, 2]               # optional receiver robot ids (default: all)
start = 10.0              # optional window [start, end) in simulated seconds (default: the whole run)
end = 30.0

[[faults.delay]]          # deliver late (same optional keys as drop)
class = "state"
ticks = 2                 # control periods late (lock-step: ticks; real time: ticks x dt)
jitter = 1                # optional: plus a uniform whole number 0..jitter (messages then reorder)

[[faults.partition]]      # nothing crosses between the groups during the window
groups = [[0, 1, 2], [3, 4]]   # robot ids; robots in no group form one more group
start = 20.0
end = 22.0

[[faults.kill]]           # the robot's process is killed (SIGKILL)
robot = 5
at = 15.0
restart = 2.0             # optional: seconds later a new process takes the robot over

[[faults.hang]]           # the robot's process is stopped (SIGSTOP), then resumed (SIGCONT)
robot = 3
at = 10.0
duration = 3.0
"""

CONTRACT_FAULTS = Faults(
    seed=7,
    drops=(DropRule("state", 0.3, 1.0, (0, 3), (1, 2), 10.0, 30.0),),
    delays=(DelayRule("state", 2, 1),),
    partitions=(Partition(((0, 1, 2), (3, 4)), 20.0, 22.0),),
    kills=(Kill(5, 15.0, 2.0),),
    hangs=(Hang(3, 10.0, 3.0),),
)


def parse(text: str, robots: int = N, duration: float = DURATION, seed: int = 0) -> Faults:
    return F.parse_faults(tomllib.loads(text)["faults"], "f.toml", robots, duration, seed)


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


def _rule(kind: str, body: str) -> str:
    return f"[faults]\n[[faults.{kind}]]\n{body}\n"


DROP = 'class = "state"\np = 0.3\n'
GOOD_KILL = "robot = 3\nat = 5.0\n"

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


def _random_faults(rng: np.random.Generator) -> Faults:
    def ids():
        return None if rng.random() < 0.5 else tuple(int(i) for i in rng.choice(N, rng.integers(1, N + 1), False))

    def window():
        start = float(rng.uniform(0, 50)) if rng.random() < 0.7 else 0.0
        return start, (start + float(rng.uniform(1e-6, 20)) if rng.random() < 0.7 else math.inf)

    def cls(robot_ends=True):
        return str(rng.choice(["state", "all"] if robot_ends else list(F.CLASSES)))

    drops = tuple(DropRule(cls(), float(rng.uniform(0, 0.5)), float(rng.choice([1.0, rng.uniform(1, 20)])),
                           ids(), ids(), *window()) for _ in range(rng.integers(0, 4)))
    delays = tuple(DelayRule(cls(), int(rng.integers(0, 5)), int(rng.integers(0, 3)), ids(), ids(), *window())
                   for _ in range(rng.integers(0, 3)))
    parts, t = [], 0.0
    for _ in range(rng.integers(0, 3)):
        start = t + float(rng.uniform(0, 5))
        t = start + float(rng.uniform(0.1, 5))
        split = int(rng.integers(1, N))
        perm = [int(i) for i in rng.permutation(N)]
        parts.append(Partition((tuple(perm[:split]),), start, t))
    kills, hangs, t = [], [], 0.0
    for robot in rng.choice(N, 3, False):
        at = float(rng.uniform(0, 50))
        if rng.random() < 0.5:
            kills.append(Kill(int(robot), at, float(rng.uniform(0.1, 5)) if rng.random() < 0.5 else None))
        else:
            hangs.append(Hang(int(robot), at, float(rng.uniform(0.1, 5))))
    return Faults(int(rng.integers(0, 2**63 - 1)), drops, delays, tuple(parts), tuple(kills), tuple(hangs))


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


# --------------------------------------------------------------------------- schedules


def test_partition_groups_and_cuts():
    f = parse(CONTRACT)  # groups [[0, 1, 2], [3, 4]] for [20, 22) s; robots 5, 6 form group 2
    assert [F.partition_group(f, i, 21.0) for i in range(N)] == [0, 0, 0, 1, 1, 2, 2]
    assert F.partition_group(f, F.WORLD, 21.0) == F.partition_group(f, F.LEADER, 21.0) == 0
    assert [F.partition_group(f, 4, t) for t in (19.999, 20.0, 21.999, 22.0)] == [0, 1, 1, 0]
    assert F.cut(f, 3, 4, 21.0) is False and F.cut(f, 0, 3, 21.0) is True and F.cut(f, 5, 3, 21.0) is True
    assert F.cut(f, F.LEADER, 3, 21.0) is True and F.cut(f, F.LEADER, 1, 21.0) is False  # the reference
    assert F.cut(f, F.WORLD, 3, 21.0) is False and F.cut(f, 3, F.WORLD, 21.0) is False  # pose and cmd: never
    assert F.cut(f, 0, 3, 22.0) is False


def test_process_states_and_events():
    f = parse(CONTRACT)  # robot 5 killed at 15 s, back at 17 s; robot 3 hung 10..13 s
    assert [F.process_state(f, 5, t) for t in (14.9, 15.0, 16.99, 17.0)] == ["alive", "dead", "dead", "alive"]
    assert [F.process_state(f, 3, t) for t in (9.9, 10.0, 12.99, 13.0)] == ["alive", "hung", "hung", "alive"]
    assert F.process_state(f, 0, 16.0) == "alive"
    assert F.events(f) == [(10.0, 3, "hang"), (13.0, 3, "resume"), (15.0, 5, "kill"), (17.0, 5, "restart")]
    g = parse("[faults]\n[[faults.kill]]\nrobot = 1\nat = 5.0\nrestart = 2.0\n[[faults.hang]]\nrobot = 1\nat = 7.0\n"
              "duration = 1.0\n[[faults.kill]]\nrobot = 0\nat = 7.0\n")
    assert F.events(g) == [(5.0, 1, "kill"), (7.0, 0, "kill"), (7.0, 1, "restart"), (7.0, 1, "hang"),
                           (8.0, 1, "resume")]


def test_a_tick_that_rounds_below_a_window_bound_is_in_it():
    dt = 0.03
    k = next(k for k in range(1, 1000) if k * dt < k * 3 / 100)  # k dt lands just below the decimal 0.03 k
    start = k * 3 / 100
    f = Faults(0, drops=(DropRule("state", 1.0, start=start, end=start + 1.0),),
               partitions=(Partition(((0,),), start, start + 1.0),), hangs=(Hang(0, start, 1.0),))
    t = k * dt
    assert t < start and F.partition_group(f, 1, t) == 1 and F.process_state(f, 0, t) == "hung"
    assert F.partition_group(f, 1, (k - 1) * dt) == 0
    table = FaultTable.of(f, 2, dt)
    assert table.decide(fg.CLS_STATE, 1, 0, k, t, table.new_chains()) == (True, 0)
    assert table.decide(fg.CLS_STATE, 1, 0, k - 1, (k - 1) * dt, table.new_chains()) == (False, 0)
    assert first_tick(start, dt) == k and table.event_ticks[0].tolist() == [k, 0, F.KINDS.index("hang")]


def test_first_tick():
    assert [first_tick(t, 0.02) for t in (0.0, 0.01, 0.02, 0.021, 15.0)] == [0, 1, 1, 2, 750]
    rng = np.random.default_rng(5)
    for _ in range(2000):
        dt = float(rng.choice([0.001, 0.01, 0.02, 0.1, 1 / 3]))
        t = float(rng.uniform(0, 100)) if rng.random() < 0.5 else round(float(rng.integers(0, 10000)) * dt, 6)
        k = first_tick(t, dt)
        assert k * dt >= t - fg.TIME_EPS and (k == 0 or (k - 1) * dt < t - fg.TIME_EPS)


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


# --------------------------------------------------------------------------- the numeric table


def test_fault_table_layout():
    f = parse(CONTRACT)
    t = FaultTable.of(f, N, 0.02)
    assert t.drop.shape == (1, fg.D_SIZE) and t.drop_from.shape == (1, N + 2) and t.delay.shape == (1, fg.Y_SIZE)
    assert t.drop[0, fg.D_CLS] == fg.CLS_STATE and t.drop[0, fg.D_P] == 0.3
    assert t.drop[0, fg.D_START] == 10.0 - fg.TIME_EPS and t.drop[0, fg.D_END] == 30.0 - fg.TIME_EPS
    # a from list names robots only: never the world (column 1) or the leader (column 0)
    assert np.flatnonzero(t.drop_from[0]).tolist() == [0 + fg.ID_OFFSET, 3 + fg.ID_OFFSET]
    assert np.flatnonzero(t.drop_to[0]).tolist() == [1 + fg.ID_OFFSET, 2 + fg.ID_OFFSET]
    assert t.delay_from.all() and t.delay_to.all() and t.delay[0, fg.Y_END] == math.inf
    assert t.part_group.tolist() == [[0, 0, 0, 1, 1, 2, 2]] and t.part_win.tolist() == [[20 - 1e-9, 22 - 1e-9]]
    assert t.proc.tolist() == [[5, fg.PROC_DEAD, 15 - 1e-9, 17 - 1e-9], [3, fg.PROC_HUNG, 10 - 1e-9, 13 - 1e-9]]
    assert t.event_ticks.tolist() == [[500, 3, 2], [650, 3, 3], [750, 5, 0], [850, 5, 1]]
    assert t.new_chains().tolist() == [[-1, 0]]
    b = FaultTable.of(Faults(0, (DropRule("all", 0.4, 5.0),)), 3, 0.1)
    assert (b.drop[0, fg.D_STAY], b.drop[0, fg.D_ENTER]) == fg.burst_params(0.4, 5.0)
    e = FaultTable.of(Faults.empty(), 3, 0.1)
    assert e.drop.shape == (0, fg.D_SIZE) and e.part_group.shape == (0, 3) and e.proc.shape == (0, fg.F_SIZE)
    assert e.decide(fg.CLS_STATE, 0, 1, 5, 0.5, e.new_chains()) == (False, 0)
    with pytest.raises(ValueError, match="robot 5"):
        FaultTable.of(f, 5, 0.02)  # robot 5 is killed: not in a scenario of 5 robots
    with pytest.raises(ValueError, match="dt"):
        FaultTable.of(f, N, 0.0)


def test_schedule_queries_equal_faultgens_on_the_table():
    rng = np.random.default_rng(8)
    for _ in range(30):
        f = _random_faults(rng)
        t = FaultTable.of(f, N, 0.05)
        for _ in range(200):
            time = float(rng.uniform(0, 60))
            i, j = (int(x) for x in rng.integers(-2, N, 2))
            assert fg.group_of(t.part_win, t.part_group, i, time) == F.partition_group(f, i, time)
            assert fg.is_cut(t.part_win, t.part_group, i, j, time) == F.cut(f, i, j, time)
            if i >= 0:
                assert F.PROCESS_STATES[fg.process_code(t.proc, i, time)] == F.process_state(f, i, time)


# --------------------------------------------------------------------------- decisions


def _table(*rules, robots=N, partitions=()) -> FaultTable:
    drops = tuple(r for r in rules if isinstance(r, DropRule))
    delays = tuple(r for r in rules if isinstance(r, DelayRule))
    return FaultTable.of(Faults(5, drops, delays, tuple(partitions)), robots, 0.1)


def _decide(table: FaultTable, cls: str, sender: int, receiver: int, k: int, t: float | None = None):
    return table.decide(F.CLASSES[cls], sender, receiver, k, k * 0.1 if t is None else t, table.new_chains())


def test_drop_rules_select_class_links_and_window():
    state = _table(DropRule("state", 1.0))
    assert _decide(state, "state", 0, 1, 3) == (True, 0)
    assert all(_decide(state, c, s, r, 3) == (False, 0) for c, s, r in (("pose", -1, 1), ("cmd", 1, -1), ("ref", -2, 1)))
    every = _table(DropRule("all", 1.0))
    assert all(_decide(every, c, s, r, 3)[0] for c, s, r in (("state", 0, 1), ("pose", -1, 1), ("cmd", 1, -1),
                                                             ("ref", -2, 1)))
    # robot lists never match the world or the leader
    listed = _table(DropRule("all", 1.0, senders=(0, 1), receivers=(2,)))
    assert _decide(listed, "state", 1, 2, 3)[0] and not _decide(listed, "state", 2, 1, 3)[0]
    assert _decide(listed, "cmd", 1, -1, 3) == (False, 0) and _decide(listed, "ref", -2, 2, 3) == (False, 0)
    assert _decide(_table(DropRule("all", 1.0, receivers=(2,))), "pose", -1, 2, 3)[0]
    window = _table(DropRule("state", 1.0, start=1.0, end=2.0))
    assert [_decide(window, "state", 0, 1, 0, t)[0] for t in (0.99, 1.0, 1.5, 1.99, 2.0)] == \
        [False, True, True, True, False]
    never = _table(DropRule("state", 0.0, 5.0))
    assert not any(_decide(never, "state", 0, 1, k)[0] for k in range(200))
    always = _table(DropRule("state", 1.0, 5.0))
    assert all(_decide(always, "state", 0, 1, k)[0] for k in range(200))


def test_delays_take_the_largest_and_losses_win():
    two = _table(DelayRule("state", 2), DelayRule("all", 3, senders=(0,)))
    assert _decide(two, "state", 0, 1, 4) == (False, 3) and _decide(two, "state", 1, 0, 4) == (False, 2)
    assert _decide(two, "pose", -1, 1, 4) == (False, 0)  # the "all" rule lists robot senders only
    jit = _table(DelayRule("state", 2, 3))
    seen = [_decide(jit, "state", 0, 1, k)[1] for k in range(4000)]
    assert set(seen) == {2, 3, 4, 5}
    counts = np.bincount(seen)[2:]
    assert np.all(np.abs(counts - 1000) < 120), counts  # uniform over 0..jitter (4 sigma of a binomial)
    both = _table(DropRule("state", 1.0), DelayRule("state", 2))
    assert _decide(both, "state", 0, 1, 4) == (True, 0)
    assert fg.delay_ticks(5, fg.DELAY_RULE, 0, 0, 1, 9, 4, 0) == 4


def test_partitions_cut_state_and_reference_links_only():
    t = _table(partitions=[Partition(((0, 1), (2,)), 1.0, 2.0)])
    assert _decide(t, "state", 0, 2, 0, 1.5) == (True, 0) and _decide(t, "state", 0, 1, 0, 1.5) == (False, 0)
    assert _decide(t, "state", 3, 4, 0, 1.5) == (False, 0)  # both in the leftover group
    assert _decide(t, "ref", -2, 2, 0, 1.5) == (True, 0) and _decide(t, "ref", -2, 1, 0, 1.5) == (False, 0)
    assert _decide(t, "pose", -1, 2, 0, 1.5) == (False, 0) and _decide(t, "cmd", 2, -1, 0, 1.5) == (False, 0)
    assert _decide(t, "state", 0, 2, 0, 2.0) == (False, 0)


def test_mix_is_splitmix64():
    """absorb(key, k) is SplitMix64's k-th output from state key: checked against a plain unsigned
    implementation; and pinned values, so that a change of the generator (which would change every
    recorded run's faults) cannot pass unnoticed."""
    M = (1 << 64) - 1

    def splitmix64(state, count):
        out = []
        for _ in range(count):
            state = (state + 0x9E3779B97F4A7C15) & M
            z = state
            z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M
            z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M
            out.append(z ^ (z >> 31))
        return out

    for key in (0, 1, 12345, -1, fg.INT64_MIN, fg.stream(7, 0, 0, 1, 2)):
        assert [fg.absorb(key, k) & M for k in range(1, 9)] == splitmix64(key & M, 8)
    assert fg.mix(0, 0, 0, 0, 0, 0) == -4218232233894148571
    assert fg.mix(7, 1, 0, -2, 3, 10**8) == -6316732363600753609
    assert fg.uniform(7, 0, 0, 1, 2, 5) == 0.019726186316991967
    assert -2**63 <= fg.mix(2**63 - 1, -1, -2, 2**62, -2**63, 99) < 2**63


def _losses(p: float, burst: float, n: int, link=(0, 1), cls=fg.CLS_STATE, rule=0, seed=1) -> np.ndarray:
    """Message 0..n-1's losses under one drop rule, asked in order through the chain cache."""
    key = fg.stream(seed, rule, cls, *link)
    stay, enter = fg.burst_params(p, burst) if burst > 1 else (0.0, 0.0)
    chains = np.full((1, fg.C_SIZE), -1, np.int64)
    return np.array([fg.lost_at(key, k, p, burst, stay, enter, chains, 0) for k in range(n)])


def _mean_burst(lost: np.ndarray) -> float:
    edges = np.diff(np.concatenate(([0], lost.astype(int), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return float(np.mean(ends - starts))


@pytest.mark.parametrize("p", [0.1, 0.3, 0.5])
def test_loss_rate_of_independent_losses(p):
    """Within 4 standard deviations of p (0.0027 at p = 0.1, 0.0041 at p = 0.3, 0.0045 at p = 0.5): 1 % of p
    itself would be 1.5 sigma at p = 0.1, which a perfect generator misses for one seed in seven (the
    z-scores of 400 seeds have mean 0.00 and deviation 1.02 there)."""
    n = 200_000
    rate = _losses(p, 1.0, n).mean()
    assert abs(rate - p) < 4 * math.sqrt(p * (1 - p) / n), rate
    assert abs(_mean_burst(_losses(p, 1.0, n)) - 1 / (1 - p)) < 0.02 / (1 - p)  # runs of independent losses


@pytest.mark.parametrize("p", [0.1, 0.3, 0.5])
def test_bursts_keep_the_loss_rate_and_have_the_mean_length(p):
    lost = _losses(p, 10.0, 200_000, seed=2)
    assert abs(lost.mean() - p) < 0.01, lost.mean()  # absolute: bursts of 10 make the rate 20x noisier
    assert abs(_mean_burst(lost) - 10.0) < 0.5, _mean_burst(lost)


def test_links_classes_rules_and_seeds_draw_independent_streams():
    n = 20_000
    base = _losses(0.5, 1.0, n)
    others = [_losses(0.5, 1.0, n, link=(1, 0)), _losses(0.5, 1.0, n, link=(0, 2)),
              _losses(0.5, 1.0, n, link=(fg.WORLD, 1)), _losses(0.5, 1.0, n, cls=fg.CLS_REF),
              _losses(0.5, 1.0, n, rule=1), _losses(0.5, 1.0, n, seed=2)]
    for other in others:
        agree = np.mean(base == other)
        assert abs(agree - 0.5) < 0.02, agree  # 5.6 sigma
    u = np.array([[fg.uniform(3, r, c, s, 1, k) for k in range(5000)] for r, c, s in
                  ((0, 0, 0), (0, 1, 0), (0, 0, 2), (1, 0, 0))])
    corr = np.corrcoef(u)
    assert np.all(np.abs(corr[np.triu_indices(4, 1)]) < 0.06), corr  # 4 sigma at n = 5000
    assert np.all(np.abs(np.corrcoef(u[0, :-1], u[0, 1:])[0, 1]) < 0.06)  # successive counters too


def test_a_chains_answers_do_not_depend_on_the_order_of_asking():
    p, burst = 0.3, 6.0
    key = fg.stream(9, 2, fg.CLS_STATE, 4, 1)
    stay, enter = fg.burst_params(p, burst)
    ordered = _losses(p, burst, 1500, link=(4, 1), rule=2, seed=9)
    rng = np.random.default_rng(4)
    chains = np.full((1, fg.C_SIZE), -1, np.int64)
    for k in rng.permutation(1500)[:600].tolist() + list(range(700, 760)) + [5, 5, 1499, 0]:
        assert fg.lost_at(key, k, p, burst, stay, enter, chains, 0) == ordered[k]
    for k in rng.permutation(1500)[:50].tolist():
        assert fg.lost_plain(9, 2, fg.CLS_STATE, 4, 1, k, p, burst) == ordered[k]
    # decide: a process asking its links in a different interleaving gets the simulator's answers
    table = _table(DropRule("state", p, burst), DropRule("all", 0.2, 3.0), DelayRule("state", 1, 2))
    links = [(0, 1), (1, 0), (2, 1)]
    caches = {link: table.new_chains() for link in links}
    first = {(link, k): table.decide(fg.CLS_STATE, *link, k, 0.1 * k, caches[link]) for link in links for k in range(300)}
    caches = {link: table.new_chains() for link in links}
    for k, link in zip(rng.integers(0, 300, 900).tolist(), [links[i] for i in rng.integers(0, 3, 900)]):
        assert table.decide(fg.CLS_STATE, *link, k, 0.1 * k, caches[link]) == first[(link, k)]


@pytest.mark.timeout(300)
def test_compiled_decisions_equal_the_plain_ones_bit_for_bit():
    from swarm.core import jit

    cg = jit.compiled("swarm.core.faultgen")
    rng = np.random.default_rng(21)
    words = rng.integers(-2**63, 2**63 - 1, (5000, 6), dtype=np.int64, endpoint=True).tolist()
    words += [[0] * 6, [-1] * 6, [2**63 - 1] * 6, [-2**63] * 6, [-2**63, 2**63 - 1, -2, -1, 0, 10**8]]
    for w in words:
        assert cg.mix(*w) == fg.mix(*w), w
    for w in words[:2000]:
        assert cg.uniform(*w) == fg.uniform(*w), w
        assert cg.delay_ticks(*w, 3, w[5] % 50) == fg.delay_ticks(*w, 3, w[5] % 50), w
    for _ in range(300):
        s, r, c, a, b, k = (int(x) for x in rng.integers(0, 100, 6))
        p, burst = float(rng.uniform(0, 0.5)), float(rng.choice([1.0, rng.uniform(1, 30)]))
        assert cg.lost_plain(s, r, c, a, b, k, p, burst) == fg.lost_plain(s, r, c, a, b, k, p, burst)
    for _ in range(12):
        f = _random_faults(rng)
        t = FaultTable.of(f, N, 0.05)
        plain = {}
        compiled = {}
        for _ in range(500):
            cls = int(rng.integers(0, fg.N_CLASSES))
            sender = fg.WORLD if cls == fg.CLS_POSE else fg.LEADER if cls == fg.CLS_REF else int(rng.integers(0, N))
            receiver = fg.WORLD if cls == fg.CLS_CMD else int(rng.integers(0, N))
            k = int(rng.integers(0, 1200))
            time = k * 0.05
            link = (cls, sender, receiver)
            cp = plain.setdefault(link, t.new_chains())
            cc = compiled.setdefault(link, t.new_chains())
            a = fg.decide(*t.arrays(), cls, sender, receiver, k, time, cp)
            b = cg.decide(*t.arrays(), cls, sender, receiver, k, time, cc)
            assert (bool(a[0]), int(a[1])) == (bool(b[0]), int(b[1])), (f, link, k)
            assert np.array_equal(cp, cc)
            assert cg.group_of(t.part_win, t.part_group, receiver, time) == fg.group_of(t.part_win, t.part_group,
                                                                                      receiver, time)
            if sender >= 0:
                assert cg.process_code(t.proc, sender, time) == fg.process_code(t.proc, sender, time)


def test_a_link_decides_as_decide_over_the_table():
    rng = np.random.default_rng(13)
    for _ in range(25):
        f = _random_faults(rng)
        t = FaultTable.of(f, N, 0.05)
        for _ in range(6):
            cls = int(rng.integers(0, fg.N_CLASSES))
            sender = fg.WORLD if cls == fg.CLS_POSE else fg.LEADER if cls == fg.CLS_REF else int(rng.integers(0, N))
            receiver = fg.WORLD if cls == fg.CLS_CMD else int(rng.integers(0, N))
            link, chains = t.link(cls, sender, receiver), t.new_chains()
            ks = list(range(400)) + rng.integers(0, 1200, 200).tolist()  # in order, then anywhere
            for k in ks:
                time = k * 0.05
                assert link.decide(k, time) == t.decide(cls, sender, receiver, k, time, chains), (f, cls, sender, k)
    t = FaultTable.of(parse(CONTRACT), N, 0.02)
    for bad in ((4, 0, 1), (0, 7, 1), (0, 0, -3)):
        with pytest.raises(ValueError):
            t.link(*bad)


def test_real_time_process_faults_restart_and_resume_before_kill_and_hang_at_one_time():
    """A hang at a robot's restart time stopped the old (dead) process and left the new one running; a
    resume and a kill at one time were sent kill first (from a contract audit)."""
    from swarm.launch.process_faults import ProcessFaults

    f = Faults(0, kills=(Kill(2, 5.0, 2.0), Kill(3, 8.0)), hangs=(Hang(2, 7.0, 1.0), Hang(4, 7.0, 1.0)))
    rt = ProcessFaults(f, 0.02, lockstep=False)
    at7 = [(r, a) for t, _, r, a in rt.todo if t == 7.0]
    assert at7.index((2, "start")) < at7.index((2, "stop"))
    at8 = [(r, a) for t, _, r, a in rt.todo if t == 8.0]
    assert at8.index((2, "cont")) < at8.index((3, "kill")) and at8.index((4, "cont")) < at8.index((3, "kill"))
    ls = ProcessFaults(f, 0.02, lockstep=True).todo  # lock-step: the new process right after the kill, at its tick
    assert ls.index((250, 0, 2, "kill")) < ls.index((250, 1, 2, "start"))


def test_a_delay_longer_than_the_run_costs_the_run_not_the_delay():
    """A delay rule of 10^6 ticks made the simulator's rings robots x robots x 10^6 (11.7 GB at 37 robots,
    1.16 TiB at 400) whatever the run's length (from a contract audit): a message later than the run is
    never delivered, so they reach its last tick only."""
    from swarm.core.faultsim import FaultState

    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=1.0), progress=scenario_file.silent)
    f = parse('[faults]\n[[faults.delay]]\nclass = "state"\nticks = 1000000\n', robots=7, duration=1.0)
    state = FaultState(scn.replace(faults=f))
    assert state.ring_state.shape == (7, 7, scn.steps + 3) and state.dmax == scn.steps + 1


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


def test_a_lock_step_hang_between_two_ticks_sends_no_signal():
    """A hang at 1.005 s for 0.01 s (dt 0.02) holds at no tick: its SIGCONT came at tick 50, before its
    SIGSTOP at tick 51, and the robot stayed stopped until the world gave up (from a review)."""
    from swarm.launch.process_faults import ProcessFaults

    f = Faults(0, hangs=(Hang(1, 1.005, 0.01), Hang(2, 1.0, 0.5)))
    assert [(r, a) for _, _, r, a in ProcessFaults(f, 0.02, lockstep=True).todo] == [(2, "stop"), (2, "cont")]
    assert {r for _, _, r, _ in ProcessFaults(f, 0.02, lockstep=False).todo} == {1, 2}  # real time: on time


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

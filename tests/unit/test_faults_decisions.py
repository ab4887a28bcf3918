"""When faults act and how each message fares (docs/faults.md): the schedule queries (partition groups and
cuts, process states and events, first ticks, window bounds), the numeric FaultTable, faultgen's decisions
(drops, delays and partitions by class, link and window; statistics, independence, purity, compiled == plain
bit for bit; a Link deciding as decide over the table), and what the launcher and the simulator build from
them (the process faults' signal schedule, the delay rings). The [faults] contract itself:
test_faults_contract.py."""

from __future__ import annotations

import math

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
from tests.unit.faults_helpers import CONTRACT, N, _random_faults, parse

pytestmark = pytest.mark.unit


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


# --------------------------------------------------------------------------- from audits and reviews


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


def test_a_lock_step_hang_between_two_ticks_sends_no_signal():
    """A hang at 1.005 s for 0.01 s (dt 0.02) holds at no tick: its SIGCONT came at tick 50, before its
    SIGSTOP at tick 51, and the robot stayed stopped until the world gave up (from a review)."""
    from swarm.launch.process_faults import ProcessFaults

    f = Faults(0, hangs=(Hang(1, 1.005, 0.01), Hang(2, 1.0, 0.5)))
    assert [(r, a) for _, _, r, a in ProcessFaults(f, 0.02, lockstep=True).todo] == [(2, "stop"), (2, "cont")]
    assert {r for _, _, r, _ in ProcessFaults(f, 0.02, lockstep=False).todo} == {1, 2}  # real time: on time

"""Fault decisions (docs/faults.md): whether one message is lost or late, as a pure function.

Scalar style on purpose, like swarm.core.law: this exact source runs as plain Python in every
process (the fault-injecting bus decides alone for each message it carries) and, compiled by
numba through `swarm.core.jit.compiled("swarm.core.faultgen")`, inside the simulator. Keep to what
numba compiles: `math`, ints, floats, 1-D/2-D numpy arrays indexed by ints, tuples. No imports of
other swarm modules. swarm.core.faulttable builds the arrays (FaultTable) and documents them.

The generator. Every decision reads uniform(seed, rule, cls, sender, receiver, k), a hash of six
integers and nothing else: no generator state, so any process can ask any message in any order and
get what the simulator gets. The hash is a sponge of the SplitMix64 step: the state absorbs each
integer v as fmix64(state + v * GAMMA), fmix64 being SplitMix64's finaliser (Stafford's "mix13"),
a bijection of 64-bit words with full avalanche. For a fixed link the last step is exactly
SplitMix64's output function over the counter k, whose streams pass BigCrush.

64 bits in both worlds. numba computes in int64 and wraps on overflow; plain Python's ints do not
wrap. So every value here is a signed 64-bit word: constants above 2^63 are written as their
negative two's complement, every sum and product goes through _wrap (exact in Python, a no-op
under numba), and right shifts are logical (_srl masks off the bits an arithmetic shift copies
from the sign). Both executions give the same words bit for bit (tests/unit/test_faults_decisions.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from swarm.core.jit import Jit

    _Floats = npt.NDArray[np.float64]
    _Ints = npt.NDArray[np.int64]
    _Mask = npt.NDArray[np.bool_]

_jit: Jit = globals().get("__swarm_jit__", lambda f: f)

# 64-bit words as signed int64 (numba types an integer literal above 2^63 - 1 as uint64, and mixed
# int64/uint64 arithmetic goes through float64: never write one).
LOW63 = 0x7FFFFFFFFFFFFFFF
INT64_MIN = -0x8000000000000000
GAMMA = 0x9E3779B97F4A7C15 - (1 << 64)  # 2^64 / golden ratio, odd: SplitMix64's increment
MUL1 = 0xBF58476D1CE4E5B9 - (1 << 64)  # fmix64 multipliers (Stafford's mix13)
MUL2 = 0x94D049BB133111EB - (1 << 64)
INIT = 0x6A09E667F3BCC909  # the sponge's starting word (first 64 bits of frac(sqrt 2), made odd)
MASK53 = (1 << 53) - 1
TWO_M53 = 1.0 / 9007199254740992.0  # 2^-53

# Message classes (the `cls` of a message; a rule's class may also be CLS_ALL).
CLS_STATE = 0  # robot j's state to robot i: link (j, i)
CLS_POSE = 1  # the world's pose of robot i: link (WORLD, i)
CLS_CMD = 2  # robot i's command: link (i, WORLD)
CLS_REF = 3  # the leader's reference to robot i: link (LEADER, i)
CLS_ALL = 4  # rules only: every class
N_CLASSES = 4

# The world and the leader as senders and receivers of links; a robot is its id 0..N-1.
WORLD = -1
LEADER = -2
ID_OFFSET = 2  # column of id x in a sender/receiver mask is x + ID_OFFSET (LEADER 0, WORLD 1, robot i 2 + i)

# The `rule` input of the generator: drop rule r draws with rule = r, delay rule r with DELAY_RULE + r.
DELAY_RULE = 1 << 20
START_K = -1  # the counter of a burst chain's starting state (no message has it)

# A time within TIME_EPS of a window's bound counts as the bound itself: t = k dt of the tick meant
# to be the first one in (or out) may round either way.
TIME_EPS = 1e-9  # s

# Layout of a drop rule row (float64): swarm.core.faulttable.FaultTable.drop
D_CLS = 0  # class code (CLS_*)
D_P = 1  # stationary loss probability
D_BURST = 2  # mean burst length in messages (1: independent losses)
D_START = 3  # s, window start, already lowered by TIME_EPS
D_END = 4  # s, window end (inf: open), already lowered by TIME_EPS
D_STAY = 5  # burst chain: P(lost at k+1 | lost at k) = 1 - 1 / burst
D_ENTER = 6  # burst chain: P(lost at k+1 | delivered at k) = p / (burst (1 - p))
D_SIZE = 7

# Layout of a delay rule row (float64): FaultTable.delay
Y_CLS = 0
Y_TICKS = 1  # control periods late
Y_JITTER = 2  # plus a whole number uniform in 0..jitter
Y_START = 3
Y_END = 4
Y_SIZE = 5

# Partitions: FaultTable.part_win (P, 2) start, end (lowered by TIME_EPS); part_group (P, N) int64.
W_START = 0
W_END = 1

# Process faults, one row each (float64): FaultTable.proc
F_ROBOT = 0
F_KIND = 1  # PROC_DEAD (kill) or PROC_HUNG (hang)
F_START = 2  # s, lowered by TIME_EPS
F_END = 3  # s, restart or resume (inf: a kill without restart), lowered by TIME_EPS
F_SIZE = 4

PROC_ALIVE = 0
PROC_DEAD = 1
PROC_HUNG = 2

# Burst chain cache, one row per drop rule for one link and class: (k, state), k = -1 for none.
C_K = 0
C_STATE = 1
C_SIZE = 2


@_jit
def _wrap(x: int) -> int:
    """The signed 64-bit word of integer x (x mod 2^64 in [-2^63, 2^63)); the identity under numba."""
    return (x & LOW63) + ((x >> 63) & 1) * INT64_MIN


@_jit
def _fmix(z: int) -> int:
    """SplitMix64's finaliser on a 64-bit word: a bijection with full avalanche."""
    z = _wrap((z ^ ((z >> 30) & 0x3FFFFFFFF)) * MUL1)
    z = _wrap((z ^ ((z >> 27) & 0x1FFFFFFFFF)) * MUL2)
    return z ^ ((z >> 31) & 0x1FFFFFFFF)


@_jit
def absorb(h: int, v: int) -> int:
    """The sponge step: the word after word h takes in integer v (any v in the int64 range)."""
    return _fmix(_wrap(int(h) + _wrap(int(v) * GAMMA)))


@_jit
def stream(seed: int, rule: int, cls: int, sender: int, receiver: int) -> int:
    """The key of one stream: mix(...) without its counter. draw(stream(s, a, b, c, d), k) == uniform(s, a, b, c, d, k)."""
    h = absorb(INIT, seed)
    h = absorb(h, rule)
    h = absorb(h, cls)
    h = absorb(h, sender)
    return absorb(h, receiver)


@_jit
def mix(seed: int, a: int, b: int, c: int, d: int, e: int) -> int:
    """A 64-bit hash of six integers, as a signed int64 (the same word compiled and plain)."""
    return absorb(stream(seed, a, b, c, d), e)


@_jit
def draw(key: int, k: int) -> float:
    """Counter k of the stream with key `key`: a float in [0, 1) with 53 random bits."""
    return ((absorb(key, k) >> 11) & MASK53) * TWO_M53


@_jit
def uniform(seed: int, rule: int, cls: int, sender: int, receiver: int, k: int) -> float:
    """The uniform number in [0, 1) of message k on link (sender, receiver) of class cls, for one rule."""
    return draw(stream(seed, rule, cls, sender, receiver), k)


# --------------------------------------------------------------------------- losses


@_jit
def chain_next(key: int, k: int, state: int, stay: float, enter: float) -> int:
    """The burst chain's state at k (1 lost, 0 delivered) after `state` at k - 1."""
    u = draw(key, k)
    if state == 1:
        return 1 if u < stay else 0
    return 1 if u < enter else 0


@_jit
def chain_state(key: int, k: int, p: float, stay: float, enter: float) -> int:
    """The burst chain's state at k >= 0, from scratch (O(k)): state 0 is drawn from the stationary
    distribution with counter START_K, then each step reads counter k."""
    state = 1 if draw(key, START_K) < p else 0
    for j in range(1, k + 1):
        state = chain_next(key, j, state, stay, enter)
    return state


@_jit
def burst_params(p: float, burst: float) -> tuple[float, float]:
    """(stay, enter) of the Gilbert chain with stationary loss p and mean burst length burst > 1.

    A run of losses ends with probability 1 / burst each message (mean length burst); a delivered
    message is followed by a loss with probability enter, chosen so that the chain spends a share p
    of the messages lost: enter / (enter + 1 / burst) = p. enter <= 1 needs p <= burst / (burst + 1)
    (runs of mean length burst need at least one delivered message between them).
    """
    return 1.0 - 1.0 / burst, p / (burst * (1.0 - p))


@_jit
def lost_at(key: int, k: int, p: float, burst: float, stay: float, enter: float, chains: _Ints, row: int) -> bool:
    """Whether message k is lost under one drop rule (stream `key`), with the chain cache chains[row].

    p == 0 never loses, p == 1 always; burst == 1: independent losses, draw(key, k) < p. Otherwise
    the burst chain's state at k: advanced from the cached (k', state) when k' <= k, computed from
    scratch when k is older than the cache (or the cache is empty). The answer never depends on the
    cache, only the work does.
    """
    if p <= 0.0:
        return False
    if p >= 1.0:
        return True
    if burst <= 1.0:
        return draw(key, k) < p
    ck = chains[row, C_K]
    if ck < 0 or ck > k:
        state = chain_state(key, k, p, stay, enter)
    else:
        state = chains[row, C_STATE]
        for j in range(ck + 1, k + 1):
            state = chain_next(key, j, state, stay, enter)
    chains[row, C_K] = k
    chains[row, C_STATE] = state
    return state == 1


@_jit
def lost_plain(seed: int, rule: int, cls: int, sender: int, receiver: int, k: int, p: float,
               burst: float) -> bool:
    """lost_at for one message from scratch (no cache): the pure function itself."""
    if p <= 0.0:
        return False
    if p >= 1.0:
        return True
    key = stream(seed, rule, cls, sender, receiver)
    if burst <= 1.0:
        return draw(key, k) < p
    stay, enter = burst_params(p, burst)
    return chain_state(key, k, p, stay, enter) == 1


@_jit
def jittered(key: int, k: int, ticks: int, jitter: int) -> int:
    """ticks plus a whole number uniform in 0..jitter drawn at counter k of stream `key`."""
    if jitter <= 0:
        return ticks
    extra = int(draw(key, k) * (jitter + 1))
    # u <= 1 - 2^-53 and (1 - 2^-53)(j + 1) rounds below j + 1 for every j < 2^52: the min is only a guard
    return ticks + min(extra, jitter)


@_jit
def delay_ticks(seed: int, rule: int, cls: int, sender: int, receiver: int, k: int, ticks: int,
                jitter: int) -> int:
    """ticks plus a whole number uniform in 0..jitter, for message k under delay rule `rule`."""
    if jitter <= 0:
        return ticks
    return jittered(stream(seed, rule, cls, sender, receiver), k, ticks, jitter)


# --------------------------------------------------------------------------- schedules


@_jit
def group_of(part_win: _Floats, part_group: _Ints, robot: int, t: float) -> int:
    """The partition group of `robot` at time t [s] (0: the first group, the world's and the
    leader's); 0 outside every partition's window. Windows never overlap (faults.py refuses it)."""
    if robot < 0:
        return 0
    for w in range(part_win.shape[0]):
        if part_win[w, W_START] <= t < part_win[w, W_END]:
            group: int = part_group[w, robot]
            return group
    return 0


@_jit
def is_cut(part_win: _Floats, part_group: _Ints, sender: int, receiver: int, t: float) -> bool:
    """Whether a partition separates sender from receiver at time t: state links (j, i) and reference
    links (LEADER, i); a link with the world (a pose or a command) is a robot's own body: never."""
    if sender == WORLD or receiver == WORLD:
        return False
    for w in range(part_win.shape[0]):
        if part_win[w, W_START] <= t < part_win[w, W_END]:
            gs = 0 if sender < 0 else part_group[w, sender]
            gr = 0 if receiver < 0 else part_group[w, receiver]
            return gs != gr
    return False


@_jit
def process_code(proc: _Floats, robot: int, t: float) -> int:
    """PROC_ALIVE, PROC_DEAD or PROC_HUNG: robot's process at time t [s]."""
    for f in range(proc.shape[0]):
        if int(proc[f, F_ROBOT]) == robot and proc[f, F_START] <= t < proc[f, F_END]:
            return int(proc[f, F_KIND])
    return PROC_ALIVE


# --------------------------------------------------------------------------- one message


@_jit
def decide(seed: int, drop: _Floats, drop_from: _Mask, drop_to: _Mask, delay: _Floats, delay_from: _Mask,
           delay_to: _Mask, part_win: _Floats, part_group: _Ints,
           cls: int, sender: int, receiver: int, k: int, t: float, chains: _Ints) -> tuple[bool, int]:
    """(lost, delay_ticks) of message k of class cls on link (sender, receiver), sent at t [s].

    Lost when a partition cuts the link at t, or when any drop rule that matches it (its class or
    CLS_ALL, sender and receiver in its masks, t in its window) loses it. Otherwise late by the
    largest delay of the delay rules that match it (0 when none does). chains: (D, C_SIZE) int64,
    this link's and class's burst chain cache (rows start as (-1, 0)); updated.
    Array layouts: swarm.core.faulttable.FaultTable. Ids: robots 0..N-1, WORLD, LEADER.
    """
    if is_cut(part_win, part_group, sender, receiver, t):
        return True, 0
    cs = sender + ID_OFFSET
    cr = receiver + ID_OFFSET
    for r in range(drop.shape[0]):
        rc = int(drop[r, D_CLS])
        if (rc != cls and rc != CLS_ALL) or not drop_from[r, cs] or not drop_to[r, cr]:
            continue
        if not (drop[r, D_START] <= t < drop[r, D_END]):
            continue
        p = drop[r, D_P]
        if p <= 0.0:
            continue
        key = stream(seed, r, cls, sender, receiver)
        if lost_at(key, k, p, drop[r, D_BURST], drop[r, D_STAY], drop[r, D_ENTER], chains, r):
            return True, 0
    late = 0
    for r in range(delay.shape[0]):
        rc = int(delay[r, Y_CLS])
        if (rc != cls and rc != CLS_ALL) or not delay_from[r, cs] or not delay_to[r, cr]:
            continue
        if not (delay[r, Y_START] <= t < delay[r, Y_END]):
            continue
        d = delay_ticks(seed, DELAY_RULE + r, cls, sender, receiver, k, int(delay[r, Y_TICKS]),
                        int(delay[r, Y_JITTER]))
        late = max(late, d)
    return False, late

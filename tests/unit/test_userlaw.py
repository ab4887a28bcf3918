"""A law of one's own (docs/control.md): naming it, loading it, checking it, and its filters."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from swarm.core import law, metrics, userlaw
from swarm.core.toml_reader import Reader
from swarm.core.scenario import ScenarioError
from swarm.proto import protocol

pytestmark = pytest.mark.unit

LAWS = textwrap.dedent('''
    import math
    import numpy as np

    def good(me, ref, bodies, params, *, t, mem, kinds):
        mem[0] += 1.0
        v = params[0] * (ref[0] - me[0])
        for i in range(bodies.shape[0]):
            v += 0.01 * kinds[i] * bodies[i, 3]
        return v, params[1] * math.sin(ref[2] - me[2]) + 0.0 * t

    def nan(me, ref, bodies, params):
        return float("nan"), 0.0

    def three(me, ref, bodies):
        return 0.0, 0.0

    def extra(me, ref, bodies, params, *, speed):
        return 0.0, 0.0

    def raises(me, ref, bodies, params):
        return 1.0 / bodies.shape[0], 0.0

    def unordered(me, ref, bodies, params):
        return float(np.sum(bodies[:, 0] * 0.1)), 0.0

    def single(me, ref, bodies, params):
        return 1.0

    def typo(me, ref, bodies, params):
        v = 0.1
        return v + nosuch, 0.0

    def past(me, ref, bodies, params):
        return params[5], 0.0

    def slow(me, ref, bodies, params):
        x = me[0]
        for i in range(20000):
            x = x * 0.999999 + 1e-7
        return 0.0 * x, 0.0

    NOT_A_FUNCTION = 3
''')


@pytest.fixture
def laws(tmp_path: Path) -> Path:
    (tmp_path / "laws.py").write_text(LAWS)
    return tmp_path


def spec(base: Path, name: str, params=(0.5, 1.0), memory: int = 2) -> userlaw.LawSpec:
    got = userlaw.parse_control(Reader("s.toml"), {"law": f"laws.py:{name}", "params": list(params),
                                                   "memory": memory}, base)
    assert got is not None
    return got


def test_the_paper_is_none_and_takes_no_params():
    rd = Reader("s.toml")
    assert userlaw.parse_control(rd, {}, None) is None
    with pytest.raises(ScenarioError, match="control.params.*law of your own"):
        userlaw.parse_control(rd, {"params": [1.0]}, None)


@pytest.mark.parametrize("text, reason", [
    ("laws.py", "must be \"paper\""), ("nofile.py:go", "no file"), ("laws.py:1go", "not a Python name"),
    ("no_such_pkg_xyz.mod:go", "cannot find module|no module"), ("a-b:go", "neither a file"),
])
def test_a_bad_name_is_refused_naming_control_law(laws, text, reason):
    with pytest.raises(ScenarioError, match=f"control.law.*({reason})"):
        userlaw.parse_control(Reader("s.toml"), {"law": text}, laws)


def test_a_good_law_passes_the_check_compiled_equal_to_python(laws):
    s = spec(laws, "good")
    assert s.ref == f"{laws / 'laws.py'}:good" and len(s.sha256) == 64
    loaded = userlaw.load(s)
    assert loaded.extras == ("t", "mem", "kinds")
    assert userlaw.check(loaded, samples=50) == []


@pytest.mark.parametrize("name, said", [
    ("nan", "non-finite command"), ("three", "takes 3 positional"), ("extra", "'speed' is none of"),
    ("raises", "raised ZeroDivisionError"), ("unordered", "compiled and Python differ"),
    ("single", "returned 1.0; it must return \\(v, w\\), two numbers"), ("missing", "defines no 'missing'"),
    ("typo", "name 'nosuch' is not defined \\(\\S+laws.py, line \\d+\\); define it"),
    ("past", "raised IndexError"),
    ("NOT_A_FUNCTION", "not a function"),
])
def test_every_bad_law_is_caught_and_named(laws, name, said):
    s = spec(laws, name, memory=0)
    try:
        problems = userlaw.check(userlaw.load(s), samples=50)
    except userlaw.LawError as e:
        problems = [str(e)]
    assert problems and f"laws.py:{name}" in problems[0]
    assert any(__import__("re").search(said, p) for p in problems), problems


def test_a_robots_copy_must_have_the_runs_sha256(laws, tmp_path_factory):
    s = spec(laws, "good")
    other = tmp_path_factory.mktemp("elsewhere") / "laws.py"
    other.write_text(LAWS)
    assert userlaw.load(s, str(other)).spec.sha256 == s.sha256  # the same file elsewhere: --law-file
    other.write_text(LAWS + "\n# edited\n")
    with pytest.raises(userlaw.LawError, match="differs from the one the run uses"):
        userlaw.load(s, str(other))


def test_the_plugin_command_compiled_equals_python_and_filters_like_the_paper(laws):
    loaded = userlaw.load(spec(laws, "good", params=(50.0, 1.0)))
    py, jit = loaded.command(False), loaded.command(True)
    rng = np.random.default_rng(4)
    p = np.concatenate((np.array([0.5, 0.5, 1.0, 1.0, 0.05, 1.0, 1.0, 0.02, 1.5, 1.2, 0.3, 0.8, 2.0]),
                        loaded.spec.params))
    assert len(p) == law.P_SIZE + 2
    for _ in range(100):
        n = int(rng.integers(0, 6))
        nx, ny = rng.uniform(-1.4, 1.4, n), rng.uniform(-1.4, 1.4, n)
        nr, nR = np.full(n, 0.3), np.full(n, 1.2)
        nk = rng.integers(0, 3, n).astype(np.int64)
        na = np.zeros(n)
        args = (0.0, 0.0, rng.uniform(-3, 3), 0.5, 0.0, 0.3, 1.0, 2.0, 0.0, 0.0, 0.5, 0.1, nx, ny, nr, nR, nk, na, n)
        m0, m1 = np.zeros(law.M_SIZE + 2), np.zeros(law.M_SIZE + 2)
        v0, w0 = py(*args, m0, p)
        v1, w1 = jit(*args, m1, p)
        assert (v0, w0) == (v1, w1) and np.array_equal(m0, m1)
        assert abs(v0) <= 0.8 and abs(w0) <= 2.0  # the speed bound (v_max, w_max) holds a law of one's own too
        assert m0[law.M_FROZEN] == 0.0 and m0[law.M_SNAP_X] == 0.0 and m0[law.M_SIZE] == 1.0  # mem[0] += 1


def test_the_config_carries_the_law_all_four_fields_or_none(laws):
    from swarm.core import scenario_file

    s = spec(laws, "good")
    doc = (Path(__file__).parents[2] / "examples" / "goto_slot.toml").read_text()
    f = laws / "s.toml"
    f.write_text(doc.replace('law = "laws/goto_slot.py:goto_slot"', 'law = "laws.py:good"')
                 .replace("params = [0.5, 2.0, 1.0, 0.8, 1.0]", "params = [0.5, 1.0]\nmemory = 2"))
    scn = scenario_file.load(str(f), scenario_file.Overrides(robots=3), progress=scenario_file.silent)
    assert scn.control.law == s and scn.control.mem_size == law.M_SIZE + 2
    c = scn.robot_config(0)
    assert protocol.decode(protocol.encode(c), "config") == c and c.law_sha256 == s.sha256
    from swarm.proto.protocol import replace

    with pytest.raises(protocol.ProtocolError, match="all four or none"):
        protocol.decode(protocol.encode(replace(c, law_memory=None)), "config")
    with pytest.raises(protocol.ProtocolError, match="law_sha256"):
        protocol.decode(protocol.encode(replace(c, law_sha256="x" * 64)), "config")
    paper = scenario_file.load("paper", progress=scenario_file.silent).robot_config(0)
    assert b"law" not in protocol.encode(paper)  # the paper's config: the bytes it always had


def test_final_spread_is_the_largest_pairwise_distance():
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 3, 10, 200):
        xy = rng.normal(size=(n, 2)) * rng.uniform(0.1, 10)
        brute = max((math.dist(a, b) for a in xy for b in xy), default=None) if n >= 2 else None
        got = metrics.spread(xy)
        assert (got is None) if brute is None else got == pytest.approx(brute, rel=1e-12)
    assert metrics.spread(np.array([[1.0, 1.0], [1.0, 1.0]])) == 0.0
    assert metrics.spread(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])) == 2.0  # collinear


def test_the_launcher_reads_why_a_process_refused_from_its_log(tmp_path):
    from swarm.launch.supervisor import last_error

    log = tmp_path / "robot-3.log"
    log.write_text("2026-12-05 INFO robot 3: connected\nswarm robot: error: robot 3: the law 'x.py:f' raised "
                   "ValueError: no at step 5 (t = 0.1 s)\n")
    assert last_error(log) == "robot 3: the law 'x.py:f' raised ValueError: no at step 5 (t = 0.1 s)"
    log.write_text("nothing said\n")
    assert last_error(log) == "" and last_error(tmp_path / "missing.log") == ""


def test_two_laws_of_one_file_compile_apart_and_a_nan_is_never_filtered_into_a_number(laws):
    (laws / "two.py").write_text("def a(me, ref, bodies, params):\n    return 0.25, 0.0\n\n"
                                 "def b(me, ref, bodies, params):\n    return float('nan'), 0.0\n")
    la = userlaw.load(userlaw.parse_control(Reader("s.toml"), {"law": "two.py:a"}, laws))
    lb = userlaw.load(userlaw.parse_control(Reader("s.toml"), {"law": "two.py:b"}, laws))
    assert la.spec.sha256 == lb.spec.sha256 and la.key != lb.key and la.cache_dir() != lb.cache_dir()
    p = np.zeros(law.P_SIZE)
    p[law.P_GOVERNOR], p[law.P_DT], p[law.P_SENSE], p[law.P_REACH] = 1.0, 0.02, 1.5, 1.2
    # a robot touching an obstacle ahead: the governor would stop a finite command; a NaN stays NaN
    args = (0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 1.0, 0.0, 0.0, 0.5, 0.0, np.array([0.3]), np.array([0.0]),
            np.array([0.3]), np.array([1.2]), np.array([law.KIND_OBSTACLE]), np.zeros(1), 1)
    for compiled in (False, True):
        assert la.command(compiled)(*args, np.zeros(law.M_SIZE), p)[0] == 0.0  # touching, heading in: held
        assert math.isnan(lb.command(compiled)(*args, np.zeros(law.M_SIZE), p)[0])


@pytest.mark.parametrize("bad", [".x:f", "a-b:f", "pkg.:f", ":f", "x.py:1f", "x.py"])
def test_a_config_naming_no_file_or_module_is_refused(bad):
    from swarm.core import scenario_file
    from swarm.proto.protocol import replace

    c = replace(scenario_file.load("paper", progress=scenario_file.silent).robot_config(0), law=bad,
                law_sha256="0" * 64, law_params=(), law_memory=0)
    with pytest.raises(protocol.ProtocolError, match="law"):
        protocol.decode(protocol.encode(c), "config")


def test_a_module_law_is_found_without_importing_its_package():
    import sys

    assert userlaw.module_source("json.decoder") == Path(__import__("json.decoder").decoder.__file__)
    assert userlaw.module_source("no_such_package_xyz.mod") is None and userlaw.module_source("a..b") is None
    before = set(sys.modules)
    userlaw.module_source("email.mime.text")
    assert "email.mime.text" not in set(sys.modules) - before


def test_scenario_check_times_the_law_and_says_when_it_is_slow_for_the_period(laws, capsys):
    """A law over a quarter of the control period a call is said to be slow (a warning, not a refusal)."""
    from swarm.cli.sim import _check_law

    for name, slow in (("good", False), ("slow", True)):
        _check_law("s.toml", spec(laws, name), False, dt=4e-5)
        out = capsys.readouterr().out
        assert "us a call (median)" in out
        assert ("warning: the law takes" in out) == slow, out

"""The docs stand alone and keep up with the code.

- No tracked file cites a file outside the repository (a user never sees them): the forbidden
  strings are built from parts, so this file does not match itself.
- docs/protocol.md names every key builder of swarm.proto.keys, every message kind with every field
  of it, and its worked example is what the codec writes.
- docs/metrics.md names every metric key the simulator, the referee, the world and `swarm up` write.
- docs/cli.md is what swarm.cli.reference generates from the parsers, and names every command and flag.
- `swarm --version` prints the installed distribution's version (pyproject.toml's when not installed).
"""

from __future__ import annotations

import ast
import inspect
import re
import subprocess
from pathlib import Path

import pytest

from swarm.proto import keys, protocol

ROOT = Path(__file__).resolve().parents[2]
PROTOCOL = ROOT / "docs" / "protocol.md"
METRICS = ROOT / "docs" / "metrics.md"

# Files outside the repository that the project was written from: never to be cited (built from parts
# so that this file does not cite them itself).
_OUTSIDE = [
    re.escape("DESIGN" + ".md"),
    re.escape("STYLE" + ".md"),
    re.escape(".." + "/shared"),
    re.escape("shared" + "/"),
    r"(?i:\b" + "reci" + r"pes\b)",
    re.escape("formation" + "-paper"),
]
OUTSIDE = re.compile("|".join(_OUTSIDE))  # case matters: docs/design.md is the project's own


def _tracked() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [ROOT / p for p in out.decode().split("\0") if p]


def _text(path: Path) -> str | None:
    """A tracked file's text, or None for a binary one (or one that is gone from the work tree)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


@pytest.mark.integration
def test_no_tracked_file_cites_a_file_outside_the_repository():
    found = []
    for path in _tracked():
        text = _text(path)
        if text is None:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            m = OUTSIDE.search(line)
            if m:
                found.append(f"{path.relative_to(ROOT)}:{n}: {m.group(0)!r} in {line.strip()[:120]!r}")
    assert not found, ("files outside the repository are cited (write what the user needs, or point to the "
                       "project's own docs):\n" + "\n".join(found))


@pytest.mark.unit
def test_the_outside_pattern_finds_what_it_must_and_not_more():
    assert OUTSIDE.search("see " + "DESIGN" + ".md section 5")
    assert OUTSIDE.search("../" + "sha" + "red/x") and OUTSIDE.search("Reci" + "pes section 8")
    assert not OUTSIDE.search("docs/design.md, docs/protocol.md, a shared router, zenoh's recipe book")


# --------------------------------------------------------------------------- docs/protocol.md


def _builders() -> list[str]:
    """Every key builder of swarm.proto.keys: the public functions whose first parameter is the fleet
    (base() gives the prefix only)."""
    out = []
    for name, fn in inspect.getmembers(keys, inspect.isfunction):
        if fn.__module__ != keys.__name__ or name.startswith("_") or name in ("check_fleet", "base"):
            continue
        params = list(inspect.signature(fn).parameters)
        if params and params[0] == "fleet":
            out.append(name)
    return out


_SAMPLES = {"role": keys.ROLES[:2], "claim": ("a", "b"), "what": ("pose", "cmd")}


def _expression(builder: str) -> list[str]:
    """The chunks of the keys `builder` makes after swarm/<fleet>/, a varying chunk as '*'."""
    fn = getattr(keys, builder)
    params = list(inspect.signature(fn).parameters)[1:]
    values = [_SAMPLES.get(p, (0, 1))[0] for p in params]
    chunks = fn("f", *values).split("/")
    for k, p in enumerate(params):
        other = fn("f", *values[:k], _SAMPLES.get(p, (0, 1))[1], *values[k + 1:]).split("/")
        assert len(other) == len(chunks), f"{builder}: parameter {p!r} changes the number of chunks"
        chunks = ["*" if a != b else a for a, b in zip(chunks, other)]
    assert chunks[:2] == [keys.PREFIX, "f"], builder
    return chunks[2:]


def _doc_keys(text: str) -> list[list[str]]:
    """The keys the doc writes in backticks, after the prefix, with every <placeholder> as '*'."""
    out = []
    for span in re.findall(r"`([^`\n]+)`", text):
        span = re.sub(r"^(swarm/<fleet>/|swarm/[A-Za-z0-9_-]+/)", "", span.strip())
        span = re.sub(r"<[^>/]+>", "*", span)
        if re.fullmatch(r"[A-Za-z0-9_*-]+(/[A-Za-z0-9_*-]+)*", span):
            out.append(span.split("/"))
    return out


@pytest.mark.unit
def test_protocol_doc_names_every_key():
    text = PROTOCOL.read_text()
    assert "swarm/<fleet>" in text
    documented = _doc_keys(text)
    builders = _builders()
    assert {"leader_ref", "cell", "world_run", "estop", "alive", "world_claim"} <= set(builders)
    missing = []
    for b in builders:
        e = _expression(b)
        if not any(len(d) == len(e) and all(x == "*" or x == y for x, y in zip(e, d)) for d in documented):
            missing.append(f"{b}: {'/'.join(e)}")
    assert not missing, "docs/protocol.md does not name these keys: " + ", ".join(missing)


def _sections(text: str) -> dict[str, str]:
    """docs/protocol.md's text under each "### `kind`..." heading, by kind."""
    parts = re.split(r"^### `([a-z]+)`.*$", text, flags=re.MULTILINE)
    return dict(zip(parts[1::2], parts[2::2]))


@pytest.mark.unit
def test_protocol_doc_names_every_kind_and_field():
    text = PROTOCOL.read_text()
    sections = _sections(text)
    missing = [k for k in protocol.KINDS if k not in sections]
    assert not missing, f"docs/protocol.md has no section for the kinds {missing}"
    nested = {"obstacles": ("obstacles", "x", "y", "r", "R"), "snapshot": ("t", "seq", "robots") + protocol._SNAP_FIELDS,
              "bodies": ("t", "seq", "bodies", "returning", "id", "x", "y", "r", "R"),
              "event": ("t", "seq", "event", "robots", "detail")}
    for kind in protocol.KINDS:
        names = nested.get(kind) or tuple(n for n, _ in protocol._SPEC[kind])
        absent = [n for n in names if not re.search(rf"(?<![A-Za-z_]){re.escape(n)}(?![A-Za-z_])", sections[kind])]
        assert not absent, f"docs/protocol.md, `{kind}`: fields not described: {absent}"


@pytest.mark.unit
def test_protocol_doc_worked_example_is_what_the_codec_writes():
    flat = re.sub(r"\s+", "", PROTOCOL.read_text())
    cmd = protocol.encode(protocol.Cmd(t=1.0, seq=50, v=0.4, w=-0.1))
    state = protocol.encode(protocol.State(id=3, t=1.0, seq=50, x=-2.5, y=1.25, theta=0.5, r=0.3, R=1.2,
                                           frozen=False))
    for msg in (cmd, state):
        assert msg.hex() in flat, f"docs/protocol.md's example bytes differ from the codec's: {msg.hex()}"
        assert f"{len(msg)}bytes" in flat
    assert keys.cell_of(-2.5, 1.25, 1.5) == (-2, 0)
    assert keys.cell("default", -2, 0, 3) in PROTOCOL.read_text()


@pytest.mark.unit
def test_protocol_doc_states_the_codec_bounds():
    text = PROTOCOL.read_text()
    for figure in ("MAX_COORD = 1e6", "MAX_TIME = 1e9", "MAX_SPEED = 100", "MAX_TURN = 100"):
        assert figure in text
    assert protocol.MAX_COORD == 1e6 and protocol.MAX_TIME == 1e9 and protocol.MAX_SPEED == 100.0
    assert protocol.MAX_TURN == 100.0 and protocol.MAX_PAYLOAD == 64 << 10 and protocol.MAX_LARGE_PAYLOAD == 16 << 20
    assert protocol.MAX_ROBOTS == 100_000 and "99 999" in text
    from swarm.proto import window

    assert window.spans(0.02, 0.5) == (2.0, 101) and window.spans(0.001, 0.5) == (2.0, 2001)
    assert window.CONFIRM == 3 and "CONFIRM = 3" in text


# --------------------------------------------------------------------------- docs/metrics.md


def _documented(text: str) -> set[str]:
    return set(re.findall(r"`([a-z_0-9]+)`", text))


def _world_keys() -> set[str]:
    """The keys World.run hands the referee (keyword arguments and literal dicts), and _latency's."""
    tree = ast.parse((ROOT / "world" / "world.py").read_text())
    out: set[str] = set()
    for cls in (n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "World"):
        for fn in (n for n in cls.body if isinstance(n, ast.FunctionDef) and n.name in ("run", "_latency")):
            for node in ast.walk(fn):
                if isinstance(node, ast.Call) and (getattr(node.func, "attr", None) == "metrics" or
                                                   getattr(node.func, "id", None) == "dict"):
                    out |= {k.arg for k in node.keywords if k.arg is not None}
                if isinstance(node, ast.Dict):
                    out |= {k.value for k in node.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
    return out


def _up_keys() -> set[str]:
    """The keys `swarm up` sets on the metrics it writes."""
    text = (ROOT / "swarm" / "cli" / "up.py").read_text()
    return set(re.findall(r"metrics\[\"([a-z_0-9]+)\"\]\s*=", text)) | set(
        re.findall(r"metrics\.setdefault\(\"([a-z_0-9]+)\"", text))


@pytest.mark.unit
@pytest.mark.timeout(300)
def test_metrics_doc_names_every_key_the_code_writes():
    from swarm.core import scenario_file
    from swarm.core.scenario_file import Overrides
    from swarm.core.sim import Simulation
    from world.referee import Referee

    scn = scenario_file.load("paper-50hz", Overrides(robots=3, duration=0.2), progress=scenario_file.silent)
    sim = Simulation(scn).run().metrics
    referee = Referee(scn).metrics(0.0, False, "lockstep")
    written = set(sim) | set(referee) | _world_keys() | _up_keys()
    assert {"converged_at_s", "governed_robot_steps", "samples", "stale_messages", "run_id", "launch_s",
            "round_trip_ms_p99"} <= written  # the sources were read
    missing = sorted(written - _documented(METRICS.read_text()))
    assert not missing, f"docs/metrics.md does not document the metric keys {missing}"


@pytest.mark.unit
def test_metrics_doc_keeps_its_sections():
    text = METRICS.read_text()
    assert "## Exit codes" in text and "## Under faults" in text
    for code in ("| 0 |", "| 1 |", "| 2 |", "| 3 |", "| 130 |"):
        assert code in text


# --------------------------------------------------------------------------- docs/cli.md and swarm --version

CLI = ROOT / "docs" / "cli.md"
REGENERATE = "python -m swarm.cli.reference > docs/cli.md"


@pytest.mark.unit
def test_cli_doc_is_what_the_parsers_generate():
    from swarm.cli import reference

    assert reference.REGENERATE == REGENERATE
    text = CLI.read_text(encoding="utf-8")
    assert REGENERATE in text.split("\n## ", 1)[0], "docs/cli.md must say how it is regenerated, at its top"
    assert text == reference.render(), f"docs/cli.md is out of date: run {REGENERATE}"


def _cli_sections(text: str) -> dict[str, str]:
    """docs/cli.md's text under each "## swarm ..." heading, by command (its prog: "swarm secure init")."""
    parts = re.split(r"^## (swarm(?: [a-z0-9-]+)*)\s*$", text, flags=re.MULTILINE)
    return dict(zip(parts[1::2], parts[2::2]))


@pytest.mark.unit
def test_cli_doc_names_every_command_and_flag():
    import argparse

    from swarm.cli.parser import all_parsers, build_parser

    text = CLI.read_text(encoding="utf-8")
    sections = _cli_sections(text)
    parsers = list(all_parsers(build_parser()))
    assert {"swarm", "swarm up", "swarm secure init", "swarm scenario show"} <= {p.prog for p in parsers}
    missing = sorted({p.prog for p in parsers} - set(sections))
    assert not missing, f"docs/cli.md has no section for the commands {missing}: run {REGENERATE}"
    absent = []
    for p in parsers:
        for action in p._actions:
            if action.help == argparse.SUPPRESS:
                continue
            # -h/--help, every command's, is said once at the top; any other flag in its command's section
            where = text if isinstance(action, argparse._HelpAction) else sections[p.prog]
            for flag in action.option_strings:
                if not re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", where):
                    absent.append(f"{p.prog} {flag}")
    assert not absent, f"docs/cli.md does not document the flags {absent}: run {REGENERATE}"


@pytest.mark.unit
def test_swarm_version_prints_the_version_and_exits_0(capsys):
    from swarm.cli import parser
    from swarm.cli.main import main

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code in (0, None)
    out = capsys.readouterr().out
    assert out == f"swarm {parser.version()}\n"
    assert re.fullmatch(r"swarm \d+(\.\d+)*\S*\n", out), out


@pytest.mark.unit
def test_swarm_version_without_an_installed_distribution_is_pyproject_s(monkeypatch, tmp_path):
    import tomllib
    from importlib import metadata

    from swarm.cli import flags as parser

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["name"] == parser.DISTRIBUTION and parser.PYPROJECT == ROOT / "pyproject.toml"

    def not_installed(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    assert parser.version() == project["version"]
    other = tmp_path / "pyproject.toml"
    other.write_text('[project]\nname = "another"\nversion = "9.9"\n')
    assert parser.pyproject_version(other) == "unknown"
    assert parser.pyproject_version(tmp_path / "absent.toml") == "unknown"

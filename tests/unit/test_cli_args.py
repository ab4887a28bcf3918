"""The command line's own parsing: values that start with a dash."""

from __future__ import annotations

import pytest

from swarm.cli.main import _dash_values, main

pytestmark = pytest.mark.unit


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


def test_a_dash_value_is_joined_only_to_an_option_that_takes_a_value():
    from swarm.cli.parser import build_parser, value_options

    opts = value_options(build_parser())
    assert {"--kill", "--initial-pose", "--robots"} <= opts and "--force" not in opts and "--quiet" not in opts
    # `--force -1`: a flag, then a folder named -1 (not --force=-1)
    assert _dash_values(["secure", "init", "--force", "-1", "--robots", "3"], opts) == \
        ["secure", "init", "--force", "-1", "--robots", "3"]
    assert _dash_values(["sim", "--kill", "-1@3"], opts) == ["sim", "--kill=-1@3"]


def test_flags_of_another_drive_are_refused_not_dropped(capsys):
    """swarm up without --inventory dropped --initial-pose and --no-preflight; swarm up and swarm robot with
    the simulated drive dropped --ros-flavor, --twist and --domain (from a review)."""
    for argv, said in [(["up", "--initial-pose", "1:0,0,0", "--dry-run"], "--initial-pose needs --inventory"),
                       (["up", "--no-preflight", "--dry-run"], "--no-preflight needs --inventory"),
                       (["up", "--twist", "plain", "--dry-run"], "--twist needs --drive ros2"),
                       (["up", "--ros-flavor", "bridge", "--dry-run"], "--ros-flavor needs --drive ros2"),
                       (["robot", "--id", "1", "--domain", "3"], "--domain needs --drive ros2"),
                       (["robot", "--id", "1", "--robot-model", "burger"], "--robot-model needs --drive ros2"),
                       (["robot", "--id", "1", "--drive", "ros2", "--distro", "humble"], "--distro sets only"),
                       (["robot", "--id", "1", "--drive", "ros2", "--ros-flavor", "bridge", "--twist", "plain",
                         "--distro", "humble"], "--distro sets only")]:
        assert main(argv) == 2, argv
        assert said in capsys.readouterr().err, argv


def test_a_robot_model_tightens_the_runs_limits_through_its_drive():
    """--robot-model burger: the ROS 2 drive carries ROBOTIS's limits, and the agent's configuration is tightened to
    them (never loosened; a limit of 0, none, takes the model's)."""
    from swarm.proto.protocol import replace

    from agents.robot import within_limits
    from swarm.cli.parser import build_parser
    from swarm.cli.robot import _ros2_drive
    from swarm.core import runid, scenario_file
    from swarm.net.bus import MemoryBus, MemoryNet

    args = build_parser().parse_args(["robot", "--id", "2", "--drive", "ros2", "--robot-model", "burger"])
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=7), progress=scenario_file.silent)
    cfg = runid.robot_config(scn, 2, False, "r1", "d")
    drive = _ros2_drive(args)(MemoryBus(MemoryNet()))(cfg, lambda: None)
    assert drive.speed_limits == (0.22, 2.84)
    tight = within_limits(replace(cfg, v_max=0.0, w_max=3.5), drive.speed_limits)
    assert (tight.v_max, tight.w_max) == (0.22, 2.84)
    slow = within_limits(replace(cfg, v_max=0.1, w_max=1.0), drive.speed_limits)
    assert (slow.v_max, slow.w_max) == (0.1, 1.0)
    assert within_limits(cfg, None) is cfg


@pytest.mark.parametrize("argv", [["sim", "--seed", "1", "--seed", "2"], ["sim", "--robots", "5", "--robots=6"],
                                  ["campaign", "--seeds", "0-1", "--seeds", "2", "-o", "x"],
                                  ["scenario", "show", "paper", "--robots", "7", "--robots", "9"]])
def test_a_flag_with_a_value_given_twice_is_refused_in_two_lines(argv, capsys):
    """argparse keeps the last; the first would be dropped without a word. The error is the reason and where
    the flags are listed, not the whole usage."""
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert "given twice (the second would replace the first)" in err and "usage:" not in err
    assert len(err.strip().splitlines()) == 2 and "--help lists its flags" in err


@pytest.mark.parametrize("argv, who", [(["sim", "extra"], "swarm sim"), (["up", "--threads", "1"], "swarm up"),
                                       (["scenario", "check", "paper", "--bogus"], "swarm scenario check"),
                                       (["--bogus"], "swarm")])
def test_a_word_left_over_is_the_subcommand_s_error(argv, who, capsys):
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{who}: error: unrecognized arguments: ") and argv[-1] in err and f"({who} --help" in err


def test_a_repeatable_flag_may_still_be_repeated():
    from swarm.cli.parser import build_parser, given_flags

    args = build_parser().parse_args(["sim", "--kill", "1@2", "--kill", "2@3", "--quiet"])
    assert args.kill == "1@2,2@3" and "_given_once" not in vars(args)
    assert given_flags(["sim", "--seed", "3"]) == {"seed"}


def test_the_status_line_shows_the_final_state_it_held_back():
    import io

    from swarm.cli.console import StatusLine

    out = io.StringIO()
    line = StatusLine(stream=out, log_every=60.0)
    line.update("t 1/20")
    line.update("t 20/20")  # within log_every of the first: held back
    assert out.getvalue() == "t 1/20\n"
    line.close()
    assert out.getvalue() == "t 1/20\nt 20/20\n"
    # a line of its own after clear() (a campaign row's result) is not followed by the state before it
    out = io.StringIO()
    line = StatusLine(stream=out, log_every=60.0)
    line.update("up 2/2: swarm up running, 1 s")
    line.update("up 2/2: swarm up running, 6 s")  # held back
    line.clear()
    out.write("up 2/2: OK, identical to swarm sim\n")
    line.close()
    assert out.getvalue().splitlines()[-1] == "up 2/2: OK, identical to swarm sim"


def test_the_compile_note_asks_the_cache_for_the_loop_the_run_takes(tmp_path, monkeypatch):
    """numba's index of a loop is CACHE/[parallel/]core_HASH/MODULE.FUNCTION-LINE.pyXY.nbi, HASH of the source's
    folder; a law of one's own has its own directory (law-HASH), and another checkout of the same sources its own
    core_HASH: neither says anything of this checkout's loops."""
    from numba.core.caching import _CacheLocator

    from swarm.core.sim import kernel_cached

    monkeypatch.setenv("SWARM_CACHE_DIR", str(tmp_path))
    from swarm.core import jit

    cache = jit.cache_dir()
    core = _CacheLocator.get_suitable_cache_subpath(str(jit._source_path("swarm.core.kernel")))
    assert core.startswith("core_")
    index = {(False, False): f"{core}/kernel.run_steps-370.py311.nbi",
             (True, False): f"parallel/{core}/kernel.run_steps-370.py311.nbi",
             (False, True): f"{core}/faultkernel.run_fault_steps-116.py311.nbi"}
    for other in (cache / "law-2f98/core_1", cache / "core_1", cache / "parallel/core_1"):  # a law; another checkout
        other.mkdir(parents=True)
        for name in index.values():
            (other / name.split("/")[-1]).write_text("")
    for (parallel, faults), name in index.items():
        assert not kernel_cached(parallel, faults)
        (cache / name).parent.mkdir(parents=True, exist_ok=True)
        (cache / name).write_text("")
        assert kernel_cached(parallel, faults)
    assert kernel_cached(True, True)  # a run under faults is serial: the fault kernel's index


def test_a_console_stream_outlives_a_terminal_that_hung_up(tmp_path):
    """After a hang-up a terminal's writes fail with EIO (not a broken pipe): the stream goes on to /dev/null,
    so the run still writes its metrics and recording; another error is still raised."""
    import errno
    import os

    from swarm.cli.main import _PipeSafe

    class HungUp:
        def __init__(self, fd: int, err: int) -> None:
            self.fd, self.err, self.gone = fd, err, False

        def write(self, text: str) -> int:
            if not self.gone:
                raise OSError(self.err, os.strerror(self.err))
            return len(text)

        def flush(self) -> None:
            pass

        def fileno(self) -> int:
            self.gone = True
            return self.fd

    fd = os.open(tmp_path / "tty", os.O_WRONLY | os.O_CREAT)
    try:
        assert _PipeSafe(HungUp(fd, errno.EIO)).write("summary\n") == len("summary\n")
        assert os.path.samestat(os.fstat(fd), os.stat(os.devnull))  # the fd now goes to /dev/null
        with pytest.raises(OSError):
            _PipeSafe(HungUp(fd, errno.ENOSPC)).write("summary\n")
    finally:
        os.close(fd)


def test_sighup_stops_a_run_unless_nohup_ignored_it():
    import signal

    from swarm.cli.common import StopEvent

    before = signal.getsignal(signal.SIGHUP)
    try:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        with StopEvent():
            assert signal.getsignal(signal.SIGHUP) not in (signal.SIG_DFL, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)  # nohup
        with StopEvent():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)


def test_log_lines_escape_the_control_characters_of_network_text():
    import logging

    from swarm.cli.common import _Printable

    fmt = _Printable("%(levelname)s: %(message)s")
    rec = logging.LogRecord("swarm.world", logging.WARNING, __file__, 1, "emergency stop ENGAGED: %s", ("\x1b]0;pwned\x07",),
                            None)
    line = fmt.format(rec)
    assert line == "WARNING: emergency stop ENGAGED: \\x1b]0;pwned\\x07" and line.isprintable()

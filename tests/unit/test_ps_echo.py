"""`swarm ps` and `swarm echo` on an in-memory bus: a process's presence (token and proc queryable), the
listing of every fleet, and a message decoded to one line (or refused, with the reason)."""

from __future__ import annotations

import json
import os

import pytest

from swarm.cli import echo, ps
from swarm.cli.common import BadInput
from swarm.net import presence
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Proc, ProtocolError, State

pytestmark = pytest.mark.unit


def test_a_process_announces_its_token_and_says_who_it_is_until_it_withdraws():
    net = MemoryNet()
    bus, asker = MemoryBus(net), MemoryBus(net)
    run = ["r1"]
    handle = presence.announce(bus, "lab", "robot", 3, run=lambda: run[0])
    seen = []
    asker.watch_alive(keys.alive_any("lab"), lambda k, up: seen.append((k, up)))
    assert seen == [(keys.alive("lab", "robot", 3), True)]
    (key, payload), = asker.query(keys.proc_any("lab"))
    p = protocol.decode(payload, "proc")
    assert key == keys.proc("lab", "robot", 3) and (p.role, p.id, p.pid, p.run) == ("robot", 3, os.getpid(), "r1")
    run[0] = "r2"  # the run it is in now, at each question
    assert protocol.decode(asker.query(keys.proc("lab", "robot", 3))[0][1], "proc").run == "r2"
    handle.close()
    assert seen[-1] == (keys.alive("lab", "robot", 3), False) and asker.query(keys.proc_any("lab")) == []


@pytest.mark.parametrize("bad, why", [({"role": "pilot"}, "role"), ({"pid": 0}, "pid"),
                                      ({"started": float("nan")}, "started")])
def test_a_proc_reply_out_of_bounds_is_refused(bad, why):
    good = dict(role="world", id=0, host="h", pid=12, started=1.7e9, run="", version="1.0")
    assert protocol.decode(protocol.encode(Proc(**good)), "proc") == Proc(**good)
    with pytest.raises(ProtocolError, match=why):
        protocol.decode(protocol.encode(Proc(**{**good, **bad})), "proc")


def test_ps_lists_every_fleet_in_order_with_what_each_process_says():
    net = MemoryNet()
    procs = [MemoryBus(net) for _ in range(5)]
    presence.announce(procs[0], "b", "robot", 1)
    presence.serve(procs[4], "b", "robot", 2)  # a robot's process waiting for a run: no token yet
    presence.announce(procs[1], "a", "robot", 0, run=lambda: "run-a")
    presence.announce(procs[2], "a", "world", run=lambda: "run-a")
    procs[3].token(keys.alive("a", "leader"))  # a process that says nothing of itself (an older swarm)
    rows = presence.collect(MemoryBus(net), None, wait_s=1.0)
    assert [(r["fleet"], r["role"], r["id"], r["alive"]) for r in rows] == [
        ("a", "world", 0, True), ("a", "leader", 0, True), ("a", "robot", 0, True), ("b", "robot", 1, True),
        ("b", "robot", 2, False)]
    assert rows[0]["pid"] == os.getpid() and rows[0]["run"] == "run-a" and rows[1]["pid"] is None
    assert [r["id"] for r in presence.collect(MemoryBus(net), "b", wait_s=1.0)] == [1, 2]
    text = ps.table(rows, now=rows[0]["started"] + 90)
    head, world, leader = text.splitlines()[:3]
    assert head.split() == ["FLEET", "ROLE", "ID", "HOST", "PID", "AGE", "RUN"]
    assert world.split()[-2:] == ["90s", "run-a"] and leader.split()[3:] == ["-", "-", "-", "-"]
    assert text.splitlines()[-1].endswith("(waiting for a run)")
    json.dumps(rows)  # --json prints them as they are


def test_echo_prints_a_message_as_key_kind_and_fields_and_a_bad_one_with_its_reason():
    key = keys.cell("lab", 1, -2, 5)
    s = State(id=5, t=1.5, seq=75, x=1.6, y=-2.5, theta=0.1, r=0.3, R=1.2, frozen=False)
    text, ok = echo.line(key, protocol.encode(s))
    assert ok and text.startswith(f"{key} state {{")
    assert json.loads(text.split(" state ", 1)[1])["seq"] == 75
    text, ok = echo.line(key, b"\xc1junk")
    assert not ok and text.startswith(f"{key} ! not a state message:")
    text, ok = echo.line(keys.robot_pose("lab", 5), protocol.encode(s))  # a state where a pose goes
    assert not ok and "not a pose message" in text


def test_echo_takes_a_key_under_the_fleet_or_a_full_one_and_refuses_a_malformed_one():
    assert echo.key_expr("lab", "robot/3/pose") == "swarm/lab/robot/3/pose"
    assert echo.key_expr("lab", "swarm/other/cell/**") == "swarm/other/cell/**"
    for bad in ("", "/robot/3", "robot//3", "robot/3/"):
        with pytest.raises(BadInput, match="KEY"):
            echo.key_expr("lab", bad)


def test_the_world_logs_each_change_of_the_emergency_stop_once_and_tells_it_on_its_events(caplog):
    """Repeats of an engage count once; a release older than the engage in force is ignored; a newer one counts;
    each change goes on world/events; a message that does not decode is counted bad, not obeyed."""
    from world.estop import EstopLog

    net = MemoryNet()
    told = []
    MemoryBus(net).subscribe(keys.world_events("lab"), lambda k, b: told.append(protocol.decode(b, "event")))
    clock = [(1.0, 50)]
    log = EstopLog(MemoryBus(net), "lab", now=lambda: clock[0])
    log.start()
    op = MemoryBus(net)

    def say(engaged, seq, reason=""):
        op.put(keys.estop("lab"), protocol.encode(protocol.Estop(t=seq / 1000, seq=seq, engaged=engaged, reason=reason)))

    with caplog.at_level("WARNING", logger="swarm.world"):
        for seq in (1000, 1100, 1200):
            say(True, seq, "a person in the arena")
        say(False, 900)  # older than the engage: the stop holds
        clock[0] = (2.5, 125)
        say(False, 1300)
        say(False, 1400)
        op.put(keys.estop("lab"), b"\x93junk")
    assert log.metrics() == {"estops": {"engaged": 1, "released": 1, "events": [
        {"t": 1.0, "engaged": True, "reason": "a person in the arena"}, {"t": 2.5, "engaged": False, "reason": ""}]}}
    assert [(e.event, e.t, e.detail) for e in told] == [("estop", 1.0, "a person in the arena"),
                                                        ("estop_release", 2.5, "")]
    assert log.bad.count == 1
    said = [r.getMessage() for r in caplog.records if "emergency stop" in r.getMessage()]
    assert said == ["emergency stop ENGAGED at t = 1.000 s: a person in the arena", "emergency stop released at t = 2.500 s"]
    log.close()


def test_a_forged_engage_far_ahead_does_not_keep_the_world_from_logging_the_operators_release():
    """The world judges the stop on its own clock, as the robots do: an engage with t 1e11 and seq 2^53 is logged
    (and counted bad), but marks the order only up to its clock's now + span; the operator's release after that
    is logged. Before, every later release looked older, and the summary said "still ENGAGED"."""
    from world.estop import EstopLog

    net = MemoryNet()
    wall = [1.8e9]
    log = EstopLog(MemoryBus(net), "lab", now=lambda: (1.0, 50), span=2.0, wall=lambda: wall[0])
    log.start()
    op = MemoryBus(net)
    op.put(keys.estop("lab"), protocol.encode(protocol.Estop(t=1e11, seq=2**53, engaged=True, reason="forged")))
    wall[0] += 1.0
    op.put(keys.estop("lab"), protocol.encode(protocol.Estop(t=wall[0], seq=int(wall[0] * 1000), engaged=False,
                                                             reason="")))
    assert log.engaged == "forged" and log.bad.count == 1  # within the span it marks: the stop holds
    wall[0] += 2.0
    op.put(keys.estop("lab"), protocol.encode(protocol.Estop(t=wall[0], seq=int(wall[0] * 1000), engaged=False,
                                                             reason="")))
    assert log.engaged is None and log.metrics()["estops"]["released"] == 1
    op.put(keys.estop("lab"), protocol.encode(protocol.Estop(t=wall[0] + 10, seq=0, engaged=False, reason="")))
    assert log.bad.count == 2  # a release ahead of the world's clock: refused, counted
    log.close()


def test_the_summary_says_when_the_emergency_stop_was_engaged_and_released():
    from swarm.cli.console import estop_text

    assert estop_text({"estops": {"engaged": 0, "released": 0, "events": []}}) is None and estop_text({}) is None
    e = {"engaged": 1, "released": 0, "events": [{"t": 3.25, "engaged": True, "reason": "tests"}]}
    assert estop_text({"estops": e}) == "engaged at t = 3.25 s (tests); still ENGAGED at the end"


def test_swarm_up_says_the_emergency_stop_once_and_its_status_line_shows_it_while_engaged():
    from swarm.cli.console import EstopFollower, progress_line

    net = MemoryNet()
    said: list[str] = []
    follow = EstopFollower(MemoryBus(net), "lab", said.append)
    world = MemoryBus(net)
    p = protocol.Progress(t=3.0, seq=150, duration=10.0, robots=3, alive=3, converged=0, frozen=0, min_distance=1.0,
                          misses=0, bad=0, collisions=0, overruns=0, min_obstacle=-1.0, position_error=0.5,
                          orientation_error=0.1, converged_at=-1.0, last_freeze=-1.0, dropped=0, hung=0, held=-1.0,
                          stranded=0)
    assert "E-STOP" not in progress_line(p, follow.engaged)
    world.put(keys.world_events("lab"), protocol.encode(protocol.Event(t=3.0, seq=150, event="estop", robots=(),
                                                                       detail="tests")))
    assert progress_line(p, follow.engaged).endswith("  E-STOP (tests)")
    world.put(keys.world_events("lab"), protocol.encode(protocol.Event(t=5.5, seq=275, event="estop_release",
                                                                       robots=(), detail="")))
    assert follow.engaged is None and said == ["emergency stop ENGAGED at t = 3.00 s: tests",
                                               "emergency stop released at t = 5.50 s"]


def test_a_process_waiting_for_a_world_says_what_is_on_the_router_instead(monkeypatch, caplog):
    """A robot of fleet 'lab' with no world: after SAY_S it says which fleets are there (a typo in --fleet), or
    what of its own fleet is (no world started), and the NoAnswer at the end says the same."""
    from agents import follow

    net = MemoryNet()
    other, mine, me = MemoryBus(net), MemoryBus(net), MemoryBus(net)
    presence.announce(other, "default", "world")
    presence.announce(other, "default", "leader")
    presence.serve(other, "default", "robot", 0)
    presence.announce(other, "default", "router")  # a router serves every fleet: never named as one
    assert presence.why_no_world(me, "lab", me=("robot", 3), wait_s=0.3) == \
        "no world of fleet 'lab' on this router; fleets there: default (world, leader, 1 robot) (--fleet NAME joins one)"
    presence.serve(mine, "lab", "robot", 5)
    presence.serve(me, "lab", "robot", 3)  # itself: left out
    assert presence.why_no_world(me, "lab", me=("robot", 3), wait_s=0.3).startswith(
        "fleet 'lab' has no world on this router (there: 1 robot); fleets there: default")
    world = MemoryBus(net)
    presence.announce(world, "lab", "world")  # there, but not answering
    assert presence.why_no_world(me, "lab", me=("robot", 3), wait_s=0.3).startswith(
        "fleet 'lab' has a world on this router that did not answer")
    world.close()
    monkeypatch.setattr(follow, "SAY_S", 0.1)
    runs = follow.RunFollower(me, "lab")
    with caplog.at_level("WARNING", logger="swarm.follow"), pytest.raises(follow.NoAnswer) as e:
        runs.current(0.8, me=("robot", 3))
    assert "fleet 'lab' has no world on this router (there: 1 robot)" in str(e.value)
    assert any("no answer for the current run after 0.1 s: fleet 'lab' has no world" in r.getMessage()
               for r in caplog.records)


def test_the_leader_says_its_run_to_swarm_ps():
    import numpy as np

    from agents.leader import Leader

    net = MemoryNet()
    lead = Leader(MemoryBus(net), np.array([[0.0, 0.0, 0.0, 0.0, 0.5, 0.0]]), 0.02, "lr", run_id="run-7")
    lead.start()
    try:
        (row,) = presence.collect(MemoryBus(net), "lr", wait_s=1.0)
        assert (row["role"], row["run"], row["alive"]) == ("leader", "run-7", True)
    finally:
        lead.close()


def test_text_from_the_network_reaches_the_terminal_with_its_controls_escaped():
    """A process's own word (ps), an estop reason (status line, summary) or a key (echo) with ESC, BEL, a line
    break or a bidirectional override cannot retitle the terminal, erase a line or fake a row."""
    from swarm.cli.console import EstopFollower, estop_text, printable

    evil = "\x1b]0;pwned\x07\x1b[2K\r\nrobot 9 fake\u202e"
    assert printable("plain text, 3.5 m") == "plain text, 3.5 m"
    shown = printable(evil)
    assert shown.isprintable() and "\\x1b" in shown and "\\n" in shown and "\\u202e" in shown
    row = {"fleet": "a", "role": "robot", "id": 1, "host": evil, "pid": 5, "started": 0.0, "run": evil, "alive": True}
    assert all(line.isprintable() for line in ps.table([row], now=10.0).splitlines())
    assert len(ps.table([row], now=10.0).splitlines()) == 2
    said = []
    net = MemoryNet()
    follower = EstopFollower(MemoryBus(net), "lab", said.append)
    MemoryBus(net).put(keys.world_events("lab"), protocol.encode(protocol.Event(
        t=1.0, seq=50, event="estop", robots=(), detail=evil)))
    assert said and all(s.isprintable() for s in said) and follower.engaged is not None and follower.engaged.isprintable()
    text = estop_text({"estops": {"engaged": 1, "released": 0, "events": [{"t": 1.0, "engaged": True, "reason": evil}]}})
    assert text is not None and text.isprintable()
    line, ok = echo.line(keys.estop("lab") + "\x1b[2K", b"\x93junk")
    assert not ok and line.isprintable()

"""Whether a machine holds a real-time swarm's control period (swarm.launch.capacity): what swarm up --mode
realtime says before it starts."""

from __future__ import annotations

import pytest

from swarm.launch import capacity

pytestmark = pytest.mark.unit


def test_the_demand_grows_with_robots_and_speed_and_a_warning_says_what_this_machine_holds():
    step = 32.0  # us: the 2-core development machine's
    assert capacity.demand(38, 0.02, 1.0, step) == 2 * capacity.demand(19, 0.02, 1.0, step)
    assert capacity.demand(19, 0.02, 2.0, step) == capacity.demand(19, 0.01, 1.0, step)
    assert capacity.verdict(19, 0.02, 2.0, cores=2, step=step) is None  # held the period in the stress bench
    note = capacity.verdict(37, 0.02, 2.0, cores=2, step=step)  # did not
    assert note is not None and "about 20 robots at --speed 2, not 37" in note and "never a collision" in note
    assert capacity.verdict(37, 0.02, 2.0, cores=4, step=step) is None


def test_a_robots_step_is_measured_here():
    assert 1.0 < capacity.step_us(rounds=3, steps=50) < 10_000.0


def test_the_memory_check_refuses_a_swarm_that_does_not_fit_and_says_how_many_do(monkeypatch):
    """2000 robot processes at about 17 MiB each do not fit in 23 GiB: refused with the figure and how many fit;
    one that fits is not refused, and a warning comes past MEMORY_SHARE of the memory or ROBOTS_PER_CORE."""
    from swarm.launch.capacity import ROBOTS_PER_CORE, Resources

    big = Resources(2000, available=23 * 1024.0, cores=2)
    why = big.refusal()
    assert why is not None and "2000 robot processes need about 34.0 GiB" in why and "23.0 GiB available" in why
    fits = int(why.split("about ")[2].split(" robots fit")[0])
    assert Resources(fits, available=23 * 1024.0).refusal() is None
    assert Resources(fits + 1, available=23 * 1024.0).refusal() is not None
    assert Resources(37, available=23 * 1024.0, cores=2).warning() is None
    assert "memory available" in Resources(fits, available=23 * 1024.0, cores=64).warning()
    crowded = Resources(ROBOTS_PER_CORE * 2 + 1, available=23 * 1024.0, cores=2).warning()
    assert crowded is not None and "more than 50 a core" in crowded
    monkeypatch.setattr(capacity, "available_mib", lambda: None)  # not known (off Linux): nothing refused
    assert Resources(5000).refusal() is None and "of memory," in Resources(5000, cores=2).text()
    assert "about 289 MiB of memory of 23.0 GiB available, 2 cores" in Resources(5, available=23 * 1024.0,
                                                                                 cores=2).text()
    assert Resources(5, router=False, viewer=False).need_mib < Resources(5).need_mib


def test_robots_start_in_waves_of_eight_a_core():
    from swarm.launch.capacity import launch_wave

    assert launch_wave(1) == 8 and launch_wave(2) == 16 and launch_wave(16) == 128 and launch_wave() >= 8


def test_waves_start_robots_as_earlier_ones_come_alive_and_time_out_only_without_progress():
    from swarm.launch.capacity import Waves

    now = [0.0]
    started: list[int] = []
    waves = Waves(started.append, range(10), timeout_s=5.0, wave=3, clock=lambda: now[0])
    assert not waves.step(0, 0) and started == [0, 1, 2]  # a wave: 3 starting at once
    assert not waves.step(2, 0) and started == [0, 1, 2]  # the world and the leader came up, no robot yet
    assert not waves.step(4, 2) and started == [0, 1, 2, 3, 4]  # 2 robots up: 2 more start
    now[0] = 4.9
    assert not waves.step(4, 2)  # no new process for 4.9 s: still waiting
    assert not waves.step(5, 3) and started == [0, 1, 2, 3, 4, 5]
    now[0] = 9.8
    assert not waves.step(5, 3)  # 4.9 s after the last progress
    now[0] = 10.0
    assert waves.step(5, 3)  # 5.1 s without a new process: timed out


def test_the_world_waits_timeout_s_after_the_last_process_that_came_alive():
    """world.ready.wait_ready: a swarm that keeps coming up (robots started in waves) is waited for; one that stops
    coming is refused timeout_s after the last arrival, naming who is missing; stop interrupts."""
    import threading

    from world.ready import NotReady, wait_ready

    now = [0.0]
    missing = [f"robot {i}" for i in range(6)]

    def wake(s: float) -> None:  # 2 s pass; every 2 s one robot comes, until robot 2
        now[0] += 2.0
        if len(missing) > 3:
            missing.pop(0)
    with pytest.raises(NotReady, match=r"not alive after 5 s: robot 3, robot 4, robot 5") as e:
        wait_ready(lambda: list(missing), wake, lambda: now[0], 5.0)
    assert now[0] == pytest.approx(12.0)  # the last one came at 6 s: refused at 12 s (> 6 + 5), not at 5 s
    assert e.value.missing == ["robot 3", "robot 4", "robot 5"]
    missing[:] = []
    wait_ready(lambda: list(missing), wake, lambda: now[0], 5.0)  # all there: at once
    stop = threading.Event()
    stop.set()
    with pytest.raises(InterruptedError):
        wait_ready(lambda: ["leader"], wake, lambda: now[0], 5.0, stop)

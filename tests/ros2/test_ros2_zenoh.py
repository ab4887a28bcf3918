"""The ROS 2 drive against the simulated ROS 2 fleet through a real zenoh router on loopback, in each
flavour and each twist kind: discovery from liveliness tokens (the twist type too: the drive runs --twist auto), commands that move the fleet's robot,
odometry reported back in the swarm's frame, rmw_zenoh's rule that a sample without attachment is dropped."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.core import kinematics
from swarm.drives.ros2 import HALT_REPEATS, Ros2Drive
from swarm.proto import ros2
from swarm.proto.protocol import Cmd
from tests.ros2.helpers import wait_until
from world.ros2_fleet import Ros2Fleet

pytestmark = pytest.mark.integration

START = (1.0, -2.0, 0.5)
CASES = [("rmw_zenoh", "plain", 10), ("rmw_zenoh", "stamped", 11), ("bridge", "plain", 12), ("bridge", "stamped", 13)]


def _commands(fleet: Ros2Fleet, got: list, n: int, what: str, poke=None) -> None:
    wait_until(lambda: (got.extend(fleet.take_commands()), len(got) >= n)[1], 10, what, poke=poke)


def _poses(drive: Ros2Drive, want, what: str, poke) -> list:
    seen: list = []

    def arrived():
        seen.extend(drive.drain())
        return seen and want(seen[-1])

    wait_until(arrived, 10, what, poke=poke)
    return seen


@pytest.mark.timeout(90)
@pytest.mark.parametrize("flavor, twist, domain", CASES)
def test_the_drive_moves_a_simulated_ros2_robot_through_a_router(client, flavor, twist, domain):
    ns = f"tb3_{flavor}_{twist}"
    fleet = Ros2Fleet(client(), [START], flavor, twist, domain=domain, namespace=lambda i: ns)
    fleet.start()
    clock = {"t": 0.0}
    drive_bus = client()
    drive = Ros2Drive(drive_bus, namespace=ns, flavor=flavor, twist="auto", domain=domain, initial_pose=START,
                      now=lambda: clock["t"], discover_timeout_s=10, bridge_look_s=10)
    drive.start()  # discovery over the router: rmw_zenoh's tokens, or the bridge's route (its twist type)
    assert (drive.cmd_key, drive.odom_key) == (fleet.cmd_keys[0], fleet.odom_keys[0])
    assert drive.twist == twist
    if flavor == "rmw_zenoh":
        assert drive.cmd_key.split("/")[-1] == ros2.type_hash(ros2.twist_type(twist))

    # odometry at the start (zero in the robot's own frame) is the scenario's start in the swarm's frame
    seen = _poses(drive, lambda p: True, "the first pose", lambda: fleet.publish_odom(0, 0.0, *START, 0.0, 0.0))
    np.testing.assert_allclose((seen[0].x, seen[0].y, seen[0].theta), START, atol=1e-12)

    # a command reaches the robot (repeated until the drive's publisher knows of the fleet's subscriber)
    got: list = []
    _commands(fleet, got, 1, "the first command", poke=lambda: drive.send(Cmd(t=0.0, seq=0, v=0.3, w=0.2)))
    assert set(got) == {(0, 0.3, 0.2)}
    assert fleet.dropped_no_attachment == 0 and fleet.bad.count == 0

    # the robot moves 1.5 s with it (exact arc); its odometry, anchored, is the moved pose in the swarm frame
    q, comp = list(START), [0.0, 0.0, 0.0]
    kinematics.step_pose(q, comp, 0.3, 0.2, 1.5)
    clock["t"] = 1.5
    seen = _poses(drive, lambda p: abs(p.x - q[0]) < 1e-9, "the moved pose",
                  lambda: fleet.publish_odom(0, 1.5, q[0], q[1], q[2], 0.3, 0.2))
    last = seen[-1]
    np.testing.assert_allclose((last.x, last.y, last.theta), q, atol=1e-9)
    assert last.t == 1.5 and drive.bad.count == 0

    # a sample without attachment: rmw_zenoh drops it, the bridge takes it
    drive_bus.put(drive.cmd_key, ros2.encode_twist(0.9, 0.9) if twist == "plain"
                  else ros2.encode_twist_stamped(0.9, 0.9, 1), reliable=True)
    drive.send(Cmd(t=1.5, seq=1, v=0.1, w=-0.1))  # same publisher, same order: after the bare sample
    got.clear()
    wait_until(lambda: (got.extend(fleet.take_commands()), got and got[-1] == (0, 0.1, -0.1))[1], 10,
               "the command after the bare sample")
    got = [c for c in got if c != (0, 0.3, 0.2)]  # repeats of the first command still on their way
    if flavor == "rmw_zenoh":
        assert got == [(0, 0.1, -0.1)] and fleet.dropped_no_attachment == 1
    else:
        assert got == [(0, 0.9, 0.9), (0, 0.1, -0.1)] and fleet.dropped_no_attachment == 0

    # closing the drive stops the robot
    drive.close()
    got.clear()
    _commands(fleet, got, HALT_REPEATS, "the halt")
    assert got == [(0, 0.0, 0.0)] * HALT_REPEATS
    fleet.close()


@pytest.mark.timeout(60)
def test_discovery_of_humble_keys_through_a_router(client):
    """Humble's rmw_zenoh writes TypeHashNotSupported: the drive takes the key the robot announces."""
    fleet = Ros2Fleet(client(), [(0.0, 0.0, 0.0)] * 2, "rmw_zenoh", "plain", domain=21, distro="humble")
    fleet.start()
    drive = Ros2Drive(client(), namespace="robot1", flavor="rmw_zenoh", twist="plain", domain=21,
                      now=lambda: 0.0, discover_timeout_s=10)
    drive.start()
    assert drive.cmd_key == "21/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported"
    assert drive.odom_key == "21/robot1/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
    got: list = []
    _commands(fleet, got, 1, "a command on the Humble key", poke=lambda: drive.send(Cmd(t=0.0, seq=0, v=0.05, w=0.0)))
    assert set(got) == {(1, 0.05, 0.0)}
    seen = _poses(drive, lambda p: True, "a pose", lambda: fleet.publish_odom(1, 0.0, 0.0, 0.0, math.pi / 4, 0.0, 0.0))
    assert seen[0].x == 0.0 and seen[0].theta == 0.0  # anchored: the drive's initial pose is the origin
    drive.close()
    fleet.close()

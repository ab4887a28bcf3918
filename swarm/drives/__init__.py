"""Robot drives: where an agent meets its robot's body (poses in, commands out). One module per kind
behind the small interface of swarm.drives.base: `sim` (the simulated world's keys), `ros2` (a ROS 2
robot over zenoh, rmw_zenoh or zenoh-bridge-ros2dds)."""

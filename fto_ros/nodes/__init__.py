"""ROS 2 executables: the live observer node and the bag player.

These are the only modules (with replay/ and cli/) that import rclpy; they
convert messages to (t, y, u) samples and hand them to the ROS-free runner.
"""

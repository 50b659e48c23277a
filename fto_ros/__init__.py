"""fto_ros: finite-, fixed-, prescribed-time and global state observers for ROS 2.

Layers (dependencies point down only): ``nodes``/``replay``/``cli``/``bag`` (ROS and
file I/O) -> ``runner`` (one adapter for node and replay) -> ``observers`` -> ``core``
and ``models`` (ROS-free numerics).
"""
__version__ = "0.1.0"

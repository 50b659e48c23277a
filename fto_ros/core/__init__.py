"""ROS-free numerics: exact discretisation, delay buffers, compiled model expressions."""

"""fto_ros: finite-, fixed-, prescribed-time and global state observers for ROS 2.

Layers (dependencies point down only): ``nodes``/``replay``/``cli``/``bag`` (ROS and
file I/O) -> ``runner`` (one adapter for node and replay) -> ``observers`` -> ``core``
and ``models`` (ROS-free numerics).
"""
import os

__version__ = "0.1.0"

# The observers work on matrices of a few rows, where a BLAS thread pool only adds hand-off
# cost, and on a loaded machine a lot of it: scipy's expm of a 7x7 matrix (one EKF
# prediction) measured 208 us with OpenBLAS's default threads on a busy 2-core machine,
# 21 us with one.  So one BLAS thread, unless the user chose otherwise; this takes effect
# when fto_ros is imported before numpy (every fto_ros command and node), else it is a no-op.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

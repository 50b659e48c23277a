"""fto_ros: finite-, fixed-, prescribed-time and global state observers for ROS 2.

Layers (dependencies point down only): ``nodes``/``replay``/``cli``/``bag`` (ROS and
file I/O) -> ``runner`` (one adapter for node and replay) -> ``observers`` -> ``core``
and ``models`` (ROS-free numerics).
"""
import os

__version__ = "0.1.0"

# One BLAS thread per process, unless the user chose otherwise.  The observers work on
# matrices of a few rows, where OpenBLAS's spin-waiting thread pool only costs: a whole
# core at 1 kHz in the node on a 2-core machine, 40-60 % more CPU than a replay itself in
# the sweep workers (which inherit it), and scipy's expm of a 7x7 matrix (one EKF
# prediction) 208 us instead of 21 us on a busy machine.  It takes effect when fto_ros is
# imported before numpy (every fto_ros command and node: this runs first); else a no-op.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

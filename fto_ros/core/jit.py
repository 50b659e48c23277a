"""Compiled per-sample code: numba when it is there, the same functions as numpy otherwise.

Every per-sample function of the package (an observer's kernel, the runner's checks, the
block loop) is written once, in the subset of Python and numpy that numba compiles, and
decorated here:

- ``@jit`` for helpers and loops: ``numba.njit`` (compiled at the first call for the
  argument types it sees, ``nogil``, numpy's error model: a division by zero gives inf or
  nan, which the callers check, instead of raising); the plain function when numba is
  off.  ``@jit(pure=other)`` gives the numpy path a vectorised twin of a scalar loop
  (same result up to the order of a sum).
- ``kernel(fn, SIGNATURE)``: a per-sample kernel the block loop calls through a function
  pointer (numba's first-class function type), so ONE compiled loop serves every observer
  family and its compiled code is cached on disk: a loop specialised per callee could not be
  cached (numba caches no function that takes a dispatcher or a closure).

Compiled code is cached on disk, in a folder per version of the package's sources inside
the private cache folder (core/private_cache.py: ``$FTO_ROS_CACHE``, else
``$XDG_CACHE_HOME/fto_ros``, else ``~/.cache/fto_ros``; ``NUMBA_CACHE_DIR`` when the user set
it), checked on every use and trusted only there (core/compile_cache.py); where there is no
usable folder, everything still works and compiles at every start (the log line says so).
``FTO_ROS_NUMBA=0`` in the environment turns numba off: the
pure numpy path, which the tests run against the compiled one.

ROS-free; imports numba lazily, only here.
"""
from __future__ import annotations

import functools
import hashlib
import logging
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np

LOG = logging.getLogger("fto_ros.jit")

#: numba is used: installed and not turned off with FTO_ROS_NUMBA=0
ENABLED = False
numba = None
if os.environ.get("FTO_ROS_NUMBA", "1").strip().lower() not in ("0", "false", "off", "no"):
    try:
        import numba  # noqa: F811
        ENABLED = True
    except ImportError:          # pragma: no cover - exercised by the FTO_ROS_NUMBA=0 runs
        numba = None


@functools.lru_cache(maxsize=None)
def sources_digest() -> str:
    """A hash of the package's sources: compiled code is kept per version of them (numba
    checks only a function's own file for changes, not the constants it took from other
    modules, so a cache shared across versions could run stale code)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _prune_old_versions() -> None:
    """Keep the three most recent versions' caches (inside the checked folder only)."""
    from . import private_cache as PC
    if os.environ.get("NUMBA_CACHE_DIR") or not PC.writable():
        return
    here = PC.folder("numba", sources_digest())
    if here is None:
        return
    try:
        others = sorted((p for p in here.parent.iterdir()
                         if p.is_dir() and not p.is_symlink() and p != here),
                        key=lambda p: p.stat().st_mtime)
        for old in others[:-2]:
            shutil.rmtree(old, ignore_errors=True)
    except OSError:
        pass


if ENABLED:
    from . import compile_cache as _cc
    _prune_old_versions()


def caching() -> bool:
    """Whether compiled code is cached on disk now (a usable private folder; a full or
    read-only disk turns the writes off)."""
    from . import private_cache as PC
    return ENABLED and PC.writable() and _cc.numba_folder() is not None


_OPTIONS = dict(nogil=True, error_model="numpy", boundscheck=False)
_lock = threading.Lock()


def _njit(fn, signature=None, nogil=True):
    """``numba.njit`` with the private disk cache (core/compile_cache.py), compiled now for
    ``signature`` when one is given (as ``numba.njit(signature)`` does), else lazily."""
    disp = numba.njit(**dict(_OPTIONS, nogil=nogil))(fn)
    _cc.attach(disp)
    if signature is not None:
        from numba.core import typeinfer
        with typeinfer.register_dispatcher(disp):
            disp.compile(signature)
        disp.disable_compile()
    return disp


def jit(fn=None, *, pure=None, gil=False):
    """Compile ``fn`` with numba (lazily, per argument types); without numba, ``pure`` (a
    numpy twin with the same contract) or ``fn`` itself.  ``gil=True`` for a function that
    calls back into Python (numba's object mode)."""
    def wrap(f):
        if not ENABLED:
            return pure if pure is not None else f
        return _njit(f, nogil=not gil)
    return wrap if fn is None else wrap(fn)


# ---------------------------------------------------------------------------------------
# the signatures of the functions the block loop calls through pointers
# ---------------------------------------------------------------------------------------
#: kernel operations (the ``op`` argument of a family's kernel)
RESTART, FIRST, STEP, ADVANCE = 0, 1, 2, 3

if ENABLED:
    from numba import types as _t
    from numba.typed import List as _List
    A = _t.float64[::1]
    I = _t.int64[::1]
    #: a model term compiled from the plant block: out <- g(x, y, u); 0, or 1 if not finite
    MODEL = _t.int64(A, A, A, A)
    #: the model terms an observer uses, in the slots its family documents
    MODELS = _t.ListType(_t.FunctionType(MODEL))
    #: kernel(op, state, new, consts, iconsts, work, a, b, y, u, models): see observers/kernel.py
    KERNEL = _t.int64(_t.int64, A, A, A, I, A, _t.float64, _t.float64, A, A, MODELS)
    KERNELS = _t.ListType(_t.FunctionType(KERNEL))
    #: every joint's model terms (joints share a kernel; their constants, so their model
    #: terms, may differ)
    MODELS_BY_JOINT = _t.ListType(MODELS)
    _MODEL_FT, _KERNEL_FT = MODELS.item_type, KERNELS.item_type
else:
    A = I = MODEL = MODELS = KERNEL = KERNELS = MODELS_BY_JOINT = None


#: model slots every kernel gets (unused ones hold the none model)
MODEL_SLOTS = 4


def _models_list(m0, m1, m2, m3):
    out = _List.empty_list(_MODEL_FT)
    out.append(m0)
    out.append(m1)
    out.append(m2)
    out.append(m3)
    return out


def _kernels_list(k0):
    out = _List.empty_list(_KERNEL_FT)
    out.append(k0)
    return out


def _models_extend(out, m0, m1, m2, m3):
    out.append(m0)
    out.append(m1)
    out.append(m2)
    out.append(m3)


def _kernels_extend(out, k0):
    out.append(k0)


_makers = {}


def _by_joint(lists):
    """A typed list of the joints' model lists (built in Python: the list of lists cannot be
    a compiled function's argument tuple of variable length)."""
    maker = _makers.get("by_joint")
    if maker is None:
        maker = _makers["by_joint"] = _njit(_append_models, _t.void(MODELS_BY_JOINT, MODELS))
        _makers["by_joint_new"] = _njit(_new_by_joint, MODELS_BY_JOINT())
    out = _makers["by_joint_new"]()
    for m in lists:
        maker(out, m)
    return out


def _new_by_joint():
    return _List.empty_list(MODELS)


def _append_models(out, m):
    out.append(m)


def function_list(fns, kind):
    """The functions ``fns`` as what compiled code takes: a typed list of function pointers
    (``kind``: MODELS, MODEL_SLOTS of them or a multiple (a composition's), KERNELS, one or
    more, or MODELS_BY_JOINT, model lists), passed from Python at the cost of one object (a function object per argument
    costs tens of microseconds per call).  The list is built by compiled, cached functions:
    a typed list built from Python compiles its methods afresh in every process.  A plain
    list without numba."""
    if not ENABLED:
        return list(fns)
    if kind is MODELS_BY_JOINT:
        return _by_joint(fns)
    makers = _makers.get(id(kind))
    if makers is None:
        item = kind.item_type
        if kind is MODELS:
            makers = (_njit(_models_list, kind(item, item, item, item)),
                      _njit(_models_extend, numba.types.void(kind, item, item, item, item)))
        else:
            makers = (_njit(_kernels_list, kind(item)),
                      _njit(_kernels_extend, numba.types.void(kind, item)))
        _makers[id(kind)] = makers
    fns = list(fns)
    width = MODEL_SLOTS if kind is MODELS else 1
    out = makers[0](*fns[:width])
    for i in range(width, len(fns), width):
        makers[1](out, *fns[i:i + width])
    return out


class _Compiled:
    """What was compiled, and how long it took (for the one start-up log line)."""

    def __init__(self):
        self.names: list[str] = []
        self.seconds = 0.0

    def note(self, name: str, seconds: float) -> None:
        if ENABLED:
            self.names.append(name)
            self.seconds += seconds


COMPILED = _Compiled()


def kernel(fn, signature):
    """``fn`` compiled for ``signature`` (a first-class function the block loop calls), at the
    first request: ``kernel(fn, STEP)`` returns the same object every time.  Without numba,
    ``fn`` itself."""
    if not ENABLED:
        return fn
    key = "_fto_kernel"
    with _lock:
        done = getattr(fn, key, None)
        if done is None:
            t0 = time.perf_counter()
            done = _njit(fn, signature)
            COMPILED.seconds += time.perf_counter() - t0
            COMPILED.names.append(fn.__module__.rsplit(".", 1)[-1] + "." + fn.__name__)
            setattr(fn, key, done)
    return done


def compile_report() -> str:
    """One line: what was compiled (or loaded from the cache) in this process, and how long
    it took; empty when nothing was."""
    if not ENABLED:
        return "numba off (FTO_ROS_NUMBA=0 or not installed): per-sample kernels run as numpy code"
    if not COMPILED.names:
        return ""
    from . import private_cache as PC
    where = ("read from the read-only cache" if PC.mode() == PC.READONLY else "cached on disk") \
        if caching() or PC.mode() == PC.READONLY else "not cached (no usable private cache folder)"
    return (f"compiled {len(COMPILED.names)} kernel(s) in {COMPILED.seconds:.2f} s ({where}): "
            + ", ".join(COMPILED.names))


def empty(n: int = 0) -> np.ndarray:
    """A float64 array of n zeros (the placeholder for an unused argument)."""
    return np.zeros(n)

"""Powers from compiled code exactly as numpy and Python compute them.

Two ways compiled code would compute a power differently from the Python and numpy code the
kernels replaced (each shows in the last bit of some results, and some kernels amplify it):

- ``pow_(x, y)``: Python's ``x ** y`` for floats is the C library's ``pow``; numba's
  ``x ** y`` is LLVM's pow, which LLVM rewrites for constant exponents (x ** 2.0 becomes
  x * x, x ** 3 a product: different in ~0.1 % and ~25 % of the results).  ``pow_`` calls
  libm's pow under a name LLVM does not know, so nothing is rewritten.  Model terms
  (core/model_code.py) print their powers with it.
- ``power(a, a_step, b, out)``: numpy's ``np.power`` on float64 arrays runs SIMD code of
  its own (SVML on AVX-512 machines), which differs from libm's pow in the last bit of ~5 %
  of the results.  A kernel that reproduces numpy code where such a bit is amplified
  (prescribed_time: the scalings of its transition near the end of a window) calls numpy's
  inner loop itself.  The loop's address is read from the ufunc object
  (``PyUFuncObject.functions``, the public struct of numpy's C API: the first float64 loop
  is the one numpy runs) and checked against ``np.power`` on probe values at import; where
  the check fails, a loop over libm's pow (compiled here) stands in, and ``NATIVE`` says
  which one runs.

Both are registered with LLVM by name at import, so compiled code that calls them stays
cacheable across processes (the addresses change).  Without numba, ``pow_`` is Python's
``**`` and ``power`` numpy's own call.  ROS-free.
"""
from __future__ import annotations

import ctypes
import logging

import numpy as np

from . import jit as J
from .jit import jit

LOG = logging.getLogger("fto_ros.jit")
_SYMBOL = "fto_ros_numpy_power_float64"
_POW = "fto_ros_libm_pow"
#: whether compiled code calls numpy's own power loop (False: libm's pow, or numba off)
NATIVE = False


class _UFunc(ctypes.Structure):
    """The head of numpy's PyUFuncObject (numpy/ufuncobject.h)."""
    _fields_ = [("ob_refcnt", ctypes.c_ssize_t), ("ob_type", ctypes.c_void_p),
                ("nin", ctypes.c_int), ("nout", ctypes.c_int), ("nargs", ctypes.c_int),
                ("identity", ctypes.c_int), ("functions", ctypes.POINTER(ctypes.c_void_p)),
                ("data", ctypes.POINTER(ctypes.c_void_p)), ("ntypes", ctypes.c_int),
                ("reserved1", ctypes.c_int), ("name", ctypes.c_char_p),
                ("types", ctypes.POINTER(ctypes.c_char))]


_LOOP = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)


def _call(fn, a, sa, b, out):
    """fn (a ufunc loop) on out[i] = f(a[i * sa], b[i]) from Python (the import check)."""
    args = np.array([a.ctypes.data, b.ctypes.data, out.ctypes.data], dtype=np.uintp)
    dims = np.array([out.size], dtype=np.intp)
    steps = np.array([8 * sa, 8, 8], dtype=np.intp)
    fn(args.ctypes.data, dims.ctypes.data, steps.ctypes.data, None)


def _numpy_loop() -> int | None:
    """The address of np.power's float64 loop, if it reproduces np.power on the probes."""
    try:
        uf = _UFunc.from_address(id(np.power))
        if (uf.nin, uf.nout, uf.name) != (2, 1, b"power") or not 0 < uf.ntypes < 64:
            return None
        d = np.dtype(np.float64).num
        addr = None
        for i in range(uf.ntypes):
            if all(ord(uf.types[3 * i + j]) == d for j in range(3)):
                addr = uf.functions[i]
                if uf.data[i]:                  # a generic loop that needs its data: not it
                    return None
                break
        if not addr:
            return None
        fn = _LOOP(addr)
        rng = np.random.default_rng(0)
        for n in (1, 3, 8, 11, 17):
            e = np.arange(n, dtype=float) - 1.0
            for base in (rng.uniform(1e-3, 2.0, n), rng.uniform(1.0, 1e4, n)):
                out = np.empty(n)
                _call(fn, base, 1, e, out)
                if not np.array_equal(out, np.power(base, e)):
                    return None
                _call(fn, base[:1], 0, e, out)
                if not np.array_equal(out, np.power(base[0], e)):
                    return None
        return addr
    except (ValueError, TypeError, OverflowError, AttributeError):
        return None


def _power_np(a, a_step, b, out):
    np.power(a[0] if a_step == 0 else a[:out.shape[0]], b[:out.shape[0]], out=out)


def _pow_py(x, y):
    return x ** y


if J.ENABLED:
    import llvmlite.binding as _ll
    from llvmlite import ir as _ir
    from numba import types as _t
    from numba.core import cgutils as _cg
    from numba.extending import intrinsic as _intrinsic

    _address = _numpy_loop()
    if _address is not None:
        NATIVE = True
    else:
        @J.numba.cfunc(_t.void(_t.CPointer(_t.CPointer(_t.float64)), _t.CPointer(_t.intp),
                               _t.CPointer(_t.intp), _t.voidptr))  # rare fallback: not cached
        def _libm_loop(args, dims, steps, data):
            a, b, o = args[0], args[1], args[2]
            sa, sb, so = steps[0] // 8, steps[1] // 8, steps[2] // 8
            for i in range(dims[0]):
                o[i * so] = a[i * sa] ** b[i * sb]

        _address = _libm_loop.address
        LOG.warning("numpy's power loop not found or not reproducible: compiled kernels use "
                    "libm's pow (last-bit differences from the numpy path)")
    _ll.add_symbol(_SYMBOL, _address)
    _ll.add_symbol(_POW, ctypes.cast(ctypes.CDLL(None).pow, ctypes.c_void_p).value)

    @_intrinsic
    def _pow_call(typingctx, x, y):
        """libm's pow(x, y), called by a name LLVM does not rewrite."""
        if not (isinstance(x, _t.Number) and isinstance(y, _t.Number)):
            return None
        sig = _t.float64(x, y)

        def codegen(context, builder, signature, args):
            d = _ir.DoubleType()
            a = context.cast(builder, args[0], signature.args[0], _t.float64)
            b = context.cast(builder, args[1], signature.args[1], _t.float64)
            fn = _cg.get_or_insert_function(builder.module, _ir.FunctionType(d, [d, d]), _POW)
            return builder.call(fn, [a, b])
        return sig, codegen

    @jit
    def pow_(x, y):
        """x ** y as Python computes it for floats (libm's pow)."""
        return _pow_call(x, y)

    @_intrinsic
    def _loop(typingctx, a, sa, b, sb, o, so, n):
        """numpy's loop call: args (a, b, o) pointers, dims (n,), steps in bytes."""
        sig = _t.void(_t.intp, _t.intp, _t.intp, _t.intp, _t.intp, _t.intp, _t.intp)

        def codegen(context, builder, signature, args):
            a, sa, b, sb, o, so, n = args
            i64 = _ir.IntType(64)
            p8 = _ir.IntType(8).as_pointer()
            argv = _cg.alloca_once(builder, p8, size=3)
            for k, v in enumerate((a, b, o)):
                builder.store(builder.inttoptr(v, p8), builder.gep(argv, [_ir.Constant(i64, k)]))
            dims = _cg.alloca_once(builder, i64, size=1)
            builder.store(n, dims)
            steps = _cg.alloca_once(builder, i64, size=3)
            for k, v in enumerate((sa, sb, so)):
                builder.store(v, builder.gep(steps, [_ir.Constant(i64, k)]))
            fnty = _ir.FunctionType(_ir.VoidType(), [p8.as_pointer(), i64.as_pointer(),
                                                     i64.as_pointer(), p8])
            fn = _cg.get_or_insert_function(builder.module, fnty, _SYMBOL)
            builder.call(fn, [argv, dims, steps, _ir.Constant(p8, None)])
            return context.get_dummy_value()
        return sig, codegen

    @jit
    def power(a, a_step, b, out):
        """out[i] = np.power(a[i * a_step], b[i]) for i < len(out) (a_step 0: a scalar base
        broadcast, as numpy does for ``np.power(scalar, array)``); a, b, out contiguous."""
        _loop(a.ctypes.data, a_step * 8, b.ctypes.data, 8, out.ctypes.data, 8, out.shape[0])
else:
    power = _power_np
    pow_ = _pow_py

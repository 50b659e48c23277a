"""Model terms as compiled kernels: sympy expressions -> generated source -> numba.

A model term of the plant block (``-a1*sin(q)``, an EKF's f(x, u) and its Jacobian, ...)
reaches an observer as a :class:`ModelFunction`: the sympy expressions it came from, and
one function with the kernels' model signature (core/jit.py ``MODEL``)

    fn(x, y, u, out) -> 0, or 1 when a value is not finite

that writes the terms (or a matrix, row-major) into ``out``.  Its source is printed by
sympy's Python code printer (math functions, common subexpressions eliminated) into a
module named by the hash of that source.  The module is kept in the private cache folder
(core/private_cache.py: ``<cache root>/models``, owner and mode checked on every use), so that
numba caches its compiled code and a plant seen before starts without compiling.  It is
loaded by reading the file, comparing its bytes with the text generated here (from
expressions the expression parser accepted: a closed vocabulary) and executing the code
compiled from *that* text, never through the import system: no bytecode file (``.pyc``,
planted or stale) is ever run.  A file that differs (damaged, foreign) is discarded and
written again with one WARN line naming it; without a usable cache folder (refused, a full
or read-only disk, ``FTO_ROS_CACHE_MODE=off``) the module lives in memory only.

ROS-free.
"""
from __future__ import annotations

import hashlib
import math
import sys
import types
from pathlib import Path
from typing import Sequence

import sympy
from sympy import S
from sympy.printing.pycode import PythonCodePrinter

from . import jit as J
from . import private_cache as PC
from .errors import CacheError

_GROUPS = ("x", "y", "u")
#: the sub-folder of the cache root that holds the generated modules
MODELS = "models"


class _Printer(PythonCodePrinter):
    """Python with ``math``; numba compiles the same text (sign, min/max, floor as floats)."""

    def _print_sign(self, e):
        a = self._print(e.args[0])
        return f"(0.0 if {a} == 0 else math.copysign(1.0, {a}))"

    def _print_floor(self, e):
        return f"float(math.floor({self._print(e.args[0])}))"

    def _print_ceiling(self, e):
        return f"float(math.ceil({self._print(e.args[0])}))"

    def _print_Pow(self, e, rational=False):
        # libm's pow, as Python's ** on floats: numba's ** is rewritten by LLVM for constant
        # exponents (x**2 as x*x, x**3 as products), which differs in the last bit
        # (core/powers.py); square roots and 1/x print as before, in both paths
        if e.exp in (S.Half, -S.Half, S.NegativeOne):
            return super()._print_Pow(e, rational=rational)
        exp = f"{float(e.exp)!r}" if e.exp.is_Number else self._print(e.exp)
        return f"pow_({self._print(e.base)}, {exp})"


def cache_dir() -> Path | None:
    """Where generated model modules are kept (checked now), or None: in memory only."""
    return PC.folder(MODELS)


class _ArrayPrinter(_Printer):
    """Prints each model symbol as its array element (``x[0]``) but orders the terms of a
    sum or product by the symbols' own names, as sympy.lambdify does: the same text as
    core/expressions.py's compile_exprs up to the names, so the same floating-point sums
    in the same order (renaming the symbols before printing would reorder them)."""

    def __init__(self, names: dict, settings: dict):
        super().__init__(settings)
        self._names = names

    def _print_Symbol(self, e):
        name = self._names.get(e)
        return name if name is not None else super()._print_Symbol(e)

    def _print_Dummy(self, e):           # the plant layer's dummies (newton's u_d1) too
        name = self._names.get(e)
        return name if name is not None else super()._print_Dummy(e)


def _source(exprs: Sequence[sympy.Expr], groups: Sequence[Sequence[sympy.Symbol]]) -> str:
    names = {}
    for name, syms in zip(_GROUPS, groups):
        for i, s in enumerate(syms):
            names[s] = f"{name}[{i}]"
    printer = _ArrayPrinter(names, {"fully_qualified_modules": True, "inline": True,
                                    "allow_unknown_functions": False})
    # the common subexpressions as compile_exprs (lambdify, cse=True) finds them: its names
    # (x0, x1, ... skipping the model's own) order the terms that use them
    reps, reduced = sympy.cse(tuple(sympy.sympify(e) for e in exprs), list=False)
    reduced = list(reduced)
    lines = ["import math", "", "from fto_ros.core.powers import pow_", "", "",
             "def fn(x, y, u, out):"]
    lines += [f"    {printer.doprint(v)} = {printer.doprint(e)}" for v, e in reps]
    for i, e in enumerate(reduced):
        lines.append(f"    out[{i}] = {printer.doprint(e)}")
    lines += ["    acc = 0.0", f"    for i in range({len(reduced)}):", "        acc += out[i] * 0.0",
              "    return 0 if acc == 0.0 else 1", ""]
    return "\n".join(lines)


def _stored(name: str, source: str) -> Path | None:
    """The cache file holding exactly ``source`` (written now if missing or different), or
    None when there is no usable cache."""
    folder = cache_dir()
    if folder is None:
        return None
    path = folder / f"{name}.py"
    data = source.encode()
    try:
        held = PC.read_file(path)
    except CacheError as err:
        PC.discard(path, str(err))
        held = None
    if held is not None and held != data:
        PC.discard(path, "not the text generated for this model")
        held = None
    if held is None and not PC.write_file(path, data):
        return None
    return path


def _load(source: str):
    digest = hashlib.sha256(source.encode()).hexdigest()[:20]
    name = f"fto_model_{digest}"
    module = sys.modules.get(name)
    if module is not None and getattr(module, "__fto_source__", None) == source:
        return module.fn
    path = _stored(name, source)
    filename = str(path) if path is not None else f"<generated {name}>"
    module = types.ModuleType(name)
    module.__file__ = filename
    module.__fto_source__ = source
    # the code of the generated text itself (never a bytecode file); numba caches it beside
    # the cached file's text, which it hashes
    exec(compile(source, filename, "exec"), module.__dict__)
    sys.modules[name] = module
    return module.fn


class ModelFunction:
    """Compiled model terms: ``fn(x, y, u, out)`` (see the module doc), ``size`` values.

    ``groups`` are the symbols that the expressions may use, read from x, y and u in that
    order (``[states, outputs, inputs]``; an empty group for an unused argument).
    ``is_zero``: every term is identically zero (callers may skip the call)."""

    def __init__(self, exprs: Sequence[sympy.Expr], groups: Sequence[Sequence[sympy.Symbol]]):
        self.exprs = [sympy.sympify(e) for e in exprs]
        self.groups = [list(g) for g in groups] + [[] for _ in range(3 - len(groups))]
        self.size = len(self.exprs)
        self.is_zero = all(e == 0 for e in self.exprs)
        self.source = _source(self.exprs, self.groups)
        self._py = _load(self.source)
        self._kernel = None

    def pure(self, x, y, u, out) -> int:
        """The numpy path's call: as the compiled one, math's exceptions -> 1 (non-finite;
        TypeError: a complex power of a negative base)."""
        try:
            return self._py(x, y, u, out)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError):
            out[:self.size] = math.nan
            return 1

    @property
    def kernel(self):
        """The function the block loop calls (compiled on first request)."""
        if self._kernel is None:
            self._kernel = J.kernel(self._py, J.MODEL) if J.ENABLED else self.pure
        return self._kernel


def _nothing(x, y, u, out):
    return 0


def none_kernel():
    """The model function of an unused slot."""
    return J.kernel(_nothing, J.MODEL) if J.ENABLED else _nothing

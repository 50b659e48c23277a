"""Building an observer from parameters: every failure becomes one ConfigError.

The runner builds every observer here (at start-up, at each run-time change, for
``fto-design``), so a value an observer's design cannot cope with (scipy's LinAlgError,
"SVD did not converge", an overflow, a FloatingPointError under ``np.seterr(all='raise')``
or a numpy warning turned into an error) is refused like any other bad parameter: a
ConfigError naming the parameters and what went wrong, and a live node keeps its old
observer.  An observer's own checks name the parameter more precisely; this is the net
under them.

Warnings raised while building are caught: scipy's and numpy's (an overflow the design
saturates on purpose, a convergence note) are part of the refusal's reason when the build
fails and are dropped when it succeeds; the package's own notes to the user
(:class:`~fto_ros.core.errors.ConfigNote`) are passed on when it succeeds.  The build runs
under numpy's default error handling whatever the caller set, so a design that saturates
an exponential on purpose behaves the same everywhere.  ROS-free.
"""
from __future__ import annotations

import warnings
from contextlib import contextmanager
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from ..core.errors import ConfigError, ConfigNote, short


def blamed(flat: Mapping[str, Any], changed: Iterable[str] | None = None) -> str:
    """The parameters a failed build is blamed on: the ones a run-time change changed, or
    at start-up the chosen observer's own section as given (``<type>.*`` when empty)."""
    names = sorted(changed or ())
    if names:
        return ", ".join(names)
    type_name = str(flat.get("observer.type"))
    names = sorted(k for k in flat if k.startswith(type_name + "."))
    return ", ".join(names) if names else f"{type_name}.*"


def changed_names(old: Mapping[str, Any], new: Mapping[str, Any]) -> list[str]:
    """The names whose value differs between two flat parameter sets (added, removed or
    changed; NaN counts as changed)."""
    missing = object()
    return [k for k in sorted(set(old) | set(new))
            if not _same(old.get(k, missing), new.get(k, missing))]


def _same(a, b) -> bool:
    try:
        return type(a) is type(b) and bool(a == b)
    except Exception:  # noqa: BLE001  (numpy arrays and the like: compare their lists)
        return repr(a) == repr(b)


@contextmanager
def design_guard(flat: Mapping[str, Any], changed: Iterable[str] | None = None) -> Iterator[None]:
    """Run the body (parameter resolution, plant expansion, the observer's constructor);
    see the module doc.  ConfigError passes through as it is; any other exception becomes
    ConfigError(:func:`blamed`, what failed, plus the first numerical warning)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with np.errstate(all="warn"):
                yield
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001  any failure to build is a bad configuration
            numeric = [str(w.message) for w in caught if not issubclass(w.category, ConfigNote)]
            why = f"{type(exc).__name__}: {short(exc)}" if str(exc) else type(exc).__name__
            if numeric:
                why += f" ({short(numeric[0])})"
            type_name = flat.get("observer.type")
            raise ConfigError(blamed(flat, changed), f"the {type_name} observer cannot be built "
                              f"with these values: {why}") from None
    for w in caught:
        if issubclass(w.category, ConfigNote):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)

"""The compiled acquire-then-track composition: its arrays, built from its children's.

A composition in the sense of observers/kernel.py: the kernels list is [this kernel, the
acquirer's, the tracker's]; each child's state and clock are slices of this observer's
state, its candidate, work, constants and integer constants slices of this observer's
arrays (kernel.py has the layout), its model terms after this observer's (empty) model
slots.  The children stay Python objects whose arrays are views into those slices, so their
properties and diagnostics read the running composition.  ROS-free.
"""
from __future__ import annotations

import numpy as np

from ...core import jit as J
from ...core.model_code import none_kernel
from .. import kernel as K
from ..base import KernelObserver
from . import kernel
from .design import Make, TrackDesign


class TrackObserver(TrackDesign, KernelObserver):
    """``observer.type: track``: the design (design.py) run by the composition's kernel."""

    KERNEL = kernel
    _SHARED = KernelObserver._SHARED + ("_model_fns",)

    def __init__(self, cfg: dict, make: Make):
        TrackDesign.__init__(self, cfg, make)
        self.tracker.P0 = self.handover_covariance
        self._compose()
        self.reset()

    def _compose(self) -> None:
        """The composition's arrays (kernel.py has the layout), the children's copied in."""
        n, w = self.n_states, self.window
        kids = (self.acquirer, self.tracker)
        sc = K.HEADER + n                                  # the composition's scalars
        st_size = sc + kernel.SCALARS
        request, ring = 0, K.RQ_X0 + n
        partials = ring + w + 1
        wk_size = partials + kernel.PARTIALS
        c = [min(k.max_step for k in kids), self.threshold, self.clip,
             self.certificate_residual]
        own_ints = [n, sc, w, self.certificate_samples, ring, partials]
        tab = K.IC_HEADER + len(own_ints)
        ic_size = tab + K.TAB_HEADER + len(kids) * K.CHILD_WIDTH
        rows, fns = [], [none_kernel()] * J.MODEL_SLOTS
        self._places = []
        for i, kid in enumerate(kids, start=1):
            size = kid._st.size
            place = dict(st=(st_size, size), clk=(st_size + size, K.CLOCK_SIZE),
                         nx=(wk_size, size), c=(len(c), kid._c.size),
                         ic=(ic_size, kid._ic.size), wk=(wk_size + size, kid._wk.size))
            self._places.append(place)
            # the child's row, in the order of the CH_* fields
            rows += [i, *place["st"], place["clk"][0], place["nx"][0], *place["c"], *place["ic"],
                     *place["wk"], i * J.MODEL_SLOTS, len(kid.models)]
            st_size += size + K.CLOCK_SIZE
            wk_size += size + kid._wk.size
            ic_size += kid._ic.size
            c += kid._c.tolist()
            fns += [m.kernel for m in kid.models] + \
                [none_kernel()] * (J.MODEL_SLOTS - len(kid.models))
        ic = K.layout_ic(n, K.HEADER, n_extra=3, extra=sc + kernel.MODE, extra_ints=own_ints)
        ic[K.COMPOSED] = tab
        ic = np.concatenate([ic, [len(kids), request], rows] + [kid._ic for kid in kids])
        self._build_kernel(np.array(c), ic.astype(np.int64), np.zeros(wk_size), st_size)
        for kid, place in zip(kids, self._places):
            for key, target in (("st", self._st), ("clk", self._st), ("wk", self._wk)):
                o, size = place[key]
                target[o:o + size] = getattr(kid, "_" + key)
        self._kernels = J.function_list([J.kernel(kernel.kernel, J.KERNEL)] +
                                        [J.kernel(kid.KERNEL.kernel, J.KERNEL) for kid in kids],
                                        J.KERNELS)
        self._model_fns = fns
        self._models = J.function_list(fns, J.MODELS)
        self._bind_children()

    def _bind_children(self) -> None:
        """The children's arrays as views into this observer's."""
        arrays = dict(st=self._st, clk=self._st, nx=self._wk, wk=self._wk, c=self._c, ic=self._ic)
        for kid, place in zip((self.acquirer, self.tracker), self._places):
            for key, (o, size) in place.items():
                setattr(kid, "_" + key, arrays[key][o:o + size])

    def adopt(self, st, nx, c, ic, wk, clk) -> None:
        super().adopt(st, nx, c, ic, wk, clk)
        self._bind_children()

    def __deepcopy__(self, memo):
        new = KernelObserver.__deepcopy__(self, memo)
        # a model list of its own: _run moves the running child's terms into its slots
        new._models = J.function_list(self._model_fns, J.MODELS)
        new._bind_children()
        return new

    # -- what the state says ----------------------------------------------------------
    def _scalar(self, which: int) -> float:
        return float(self._st[self._ic[kernel.T_SC] + which])

    def _summary(self):
        v = [int(self._scalar(k)) for k in (kernel.MODE, kernel.HANDOVERS, kernel.REACQ,
                                             kernel.RUN_HANDOVERS, kernel.RUN_REACQ)]
        return (*v, self._scalar(kernel.WIN_SUM), int(self._scalar(kernel.WIN_COUNT)))

    def _inconsistent(self, nis: float) -> bool:
        """Add nis to the window of the committed state; whether the test fails (the
        kernel's rule, for tests of it)."""
        return bool(kernel.window_add(self._st, self._c, self._ic, self._wk, float(nis)))

"""The online filter of a robot's loop: the state stays packed in the C kernel between steps.

:meth:`~liemef.filters.AbstractFilter.step` takes and returns a :class:`~liemef.filters.FilterState`, an
immutable pytree of 16 leaves; building it costs more than the C step itself. :class:`OnlineFilter` keeps
the state as the kernel's packed vector, in two buffers it swaps, and a step is one C call on preallocated
memory: the samples are copied in, the status code comes back. The state is read when asked for
(:attr:`OnlineFilter.state`, or the cheap :attr:`~OnlineFilter.K` and :attr:`~OnlineFilter.code`).
"""

from __future__ import annotations

import math

import numpy as np

from ..codegen import fast_step_module
from ..filters import AbstractFilter, FilterState
from ._select import fast_ctl, kernel, theta_address


class OnlineFilter:
    """``flt.online(state)``: steps of ``flt`` from ``state``, kept in C between calls (not thread-safe).

    :meth:`step` advances one sample interval exactly as ``flt.step`` (the same kernel) and returns the status
    code (0 while healthy; after a failure the state stays frozen, as in ``step``). Without the C engine
    (``engine="xla"``, or no C compiler) it runs ``flt.step`` underneath, with the same interface.
    """

    def __init__(self, flt: AbstractFilter, state: FilterState, engine: str | None = None):
        type(flt).check_state(flt, state)
        self.filter = flt
        self.m, self.p = flt.system.input_dim, flt.system.output_dim
        self._kern = kernel(flt, engine)
        if self._kern is None:
            self._state = state
            return
        kern = self._kern
        self._theta_address = theta_address(flt)
        self._ctl = fast_ctl(flt)
        self._step = fast_step_module().step if self._ctl is not None else None
        # two buffers of a packed state and its samples (S + 2 (m + p) doubles), swapped at each step
        width = kern.n_state + max(1, 2 * (self.m + self.p))
        self._bufs = (np.zeros(width), np.zeros(width))
        self._bufs[0][:kern.n_state] = kern.pack(state)
        self._addresses = (self._bufs[0].ctypes.data, self._bufs[1].ctypes.data)
        self._zs = (self._bufs[0][kern.n_state:], self._bufs[1][kern.n_state:])
        self._cur = 0
        k_slot = kern.sslots[kern.paths.index(".K")]
        self._k = (k_slot.offset, k_slot.shape)
        self._code = kern.sslots[kern.paths.index(".status.code")].offset

    @property
    def _x(self) -> np.ndarray:
        return self._bufs[self._cur][:self._kern.n_state]

    def step(self, t: float, u, y, dt: float, *, u_next=None, y_next=None, gap: float = math.inf) -> int:
        """Advance ``[t, t + dt]`` with the samples ``u`` (m,) and ``y`` (p,) (NaN: missing, as in
        ``flt.step``); returns the status code."""
        if self._kern is None:
            self._state = self.filter.step(self._state, t, u, y, dt, u_next=u_next, y_next=y_next, gap=gap,
                                           engine="xla")
            return int(self._state.status.code)
        cur = self._cur
        x, xo = self._addresses if cur == 0 else self._addresses[::-1]
        ctl = self._ctl
        if ctl is not None and u_next is None and y_next is None:  # the fast step (Kernel.advance's), inlined
            code = self._step(ctl, x, xo, t, u, y, dt, gap)
            if code >= 0:
                self._cur = 1 - cur
                return code
            ctl = None  # refused (or an infinite sample): the checked path says why
        code = self._kern.advance(ctl, self._theta_address, x, xo, self._zs[1 - cur], t, dt, gap, u, y,
                                  u_next, y_next)
        self._cur = 1 - cur
        return code

    @property
    def state(self) -> FilterState:
        """The current state (a new FilterState, NumPy leaves)."""
        if self._kern is None:
            return self._state
        return self._kern.state(self._x.copy())

    @property
    def K(self) -> np.ndarray:
        """The current gain (a copy)."""
        if self._kern is None:
            return np.asarray(self._state.K)
        off, shape = self._k
        return self._x[off:off + int(np.prod(shape))].reshape(shape).copy()

    @property
    def code(self) -> int:
        """The current status code (0: healthy)."""
        if self._kern is None:
            return int(self._state.status.code)
        return int(self._x[self._code])

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

from ..codegen._kernel import fill_samples, reject_infinite
from ..filters._base import AbstractFilter, FilterState, check_time
from ._select import kernel, theta_address


class OnlineFilter:
    """``flt.online(state)``: steps of ``flt`` from ``state``, kept in C between calls (not thread-safe).

    :meth:`step` advances one sample interval exactly as ``flt.step`` (the same kernel) and returns the status
    code (0 while healthy; after a failure the state stays frozen, as in ``step``). Without the C engine
    (``engine="xla"``, or no C compiler) it runs ``flt.step`` underneath, with the same interface.
    """

    def __init__(self, flt: AbstractFilter, state: FilterState, engine: str | None = None):
        type(flt)._check_state(flt, state)
        self.filter = flt
        self.m, self.p = flt.system.input_dim, flt.system.output_dim
        self._kern = kernel(flt, engine)
        if self._kern is None:
            self._state = state
            return
        self._fill, self._reject = fill_samples, reject_infinite
        kern = self._kern
        self._theta_address = theta_address(flt)
        self._x = np.array(kern.pack(state))
        self._xo = np.empty_like(self._x)
        self._z = np.zeros(max(1, 2 * (self.m + self.p)))
        self._addresses = (self._x.ctypes.data, self._xo.ctypes.data, self._z.ctypes.data)
        k_slot = kern.sslots[kern.paths.index(".K")]
        self._k = (k_slot.offset, k_slot.shape)
        self._code = kern.sslots[kern.paths.index(".status.code")].offset

    def step(self, t: float, u, y, dt: float, *, u_next=None, y_next=None, gap: float = math.inf) -> int:
        """Advance ``[t, t + dt]`` with the samples ``u`` (m,) and ``y`` (p,) (NaN: missing, as in
        ``flt.step``); returns the status code."""
        if self._kern is None:
            self._state = self.filter.step(self._state, t, u, y, dt, u_next=u_next, y_next=y_next, gap=gap,
                                           engine="xla")
            return int(self._state.status.code)
        t, dt = check_time(t, dt)
        self._fill(self._z, self.m, self.p, u, y, u_next, y_next)
        x, xo, za = self._addresses
        code = self._kern.c_step(self._theta_address, x, xo, t, dt, float(gap), za)
        if code == -2:
            self._reject(self._z, self.m, self.p)
        self._x, self._xo = self._xo, self._x
        self._addresses = (xo, x, za)
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

r"""Sensors as named blocks with noise levels in their own units, and the theorem's weights derived from them.

A noise level is a standard deviation in the sensor's units together with its meaning (docs/weights.md):

* ``Noise.density(s)``: a continuous white noise of density ``s`` (units·sqrt(s), e.g. rad/s/sqrt(Hz) for a
  gyro). A measurement of density ``s`` weighs ``1/s^2`` per unit time while it is present (held between
  samples, the papers' zero-order hold). A process noise of density ``s`` adds ``s^2`` per unit time to K.
* ``Noise.sample(sigma, rate=f)``: one discrete sample of std ``sigma``.

  - A **measurement** sample carries its information ``1/sigma^2`` once, as a discrete Kalman update: over the
    interval ``Delta`` that follows its time stamp it is a continuous measurement of weight ``1/(sigma^2 Delta)``.
    For a sensor sampled at the filter's rate this is the zero-order hold of density ``sigma^2 / f``.
  - An **input** (process noise) sample of std ``sigma`` at rate ``f`` is held over ``1/f``: its density is
    ``sigma^2 / f`` (``rate`` is then required).

Mapping to Theorem 4.1 (tested in ``tests/test_sensors.py``): with the measurement noise ``y = h + D eps``,
``Q = I`` and ``D = diag(std)``, the information ``D^-T Q D^-1 = diag(1/std^2)``, per unit time for density
components and per sample for sample components; with the process noise ``g^-1 g_dot = lambda + B delta``,
``R = I`` and ``B = noise_map diag(density std)``, so ``B R^-1 B^T`` is the process-noise density on the algebra.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from .._chi2 import quantile
from ..groups import LieGroup
from ._base import AbstractSystem, Block, matrix
from ._residuals import AngleResidual
from ._traced import array_module, check_finite, check_traced
from ._traced import at_state as _at

Meaning = Literal["density", "sample"]
MEANINGS = ("density", "sample")
ROBUST = ("huber", "cauchy")


def _positive_vector(name: str, value) -> Array:
    a = _validate.array(name, np.atleast_1d(_validate.numeric(name, value)), (None,))
    if a.size == 0 or np.any(a <= 0):
        raise ValueError(f"{name}: expected standard deviations > 0, got {a.tolist()}")
    return jnp.asarray(a)


class Noise(eqx.Module):
    """A noise level: ``std`` (one per component, in the sensor's units) and its ``meaning``.

    Build it with :meth:`density` or :meth:`sample`. ``std`` is an array leaf: changing it never recompiles.
    """

    std: Float[Array, " k"]
    meaning: str = eqx.field(static=True)
    rate: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        _validate.choice("meaning", self.meaning, set(MEANINGS))
        if self.rate is not None and not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"rate: expected a sample rate > 0 in Hz, got {self.rate}")

    @classmethod
    def density(cls, std) -> Noise:
        """Continuous white noise of density ``std`` (units·sqrt(s))."""
        return cls(_positive_vector("std", std), "density")

    @classmethod
    def sample(cls, std, rate: float | None = None) -> Noise:
        """Discrete samples of std ``std`` (the sensor's units); ``rate`` in Hz (required for inputs)."""
        return cls(_positive_vector("std", std), "sample", None if rate is None else float(rate))

    @property
    def dim(self) -> int:
        """Number of stds (components)."""
        return int(self.std.shape[0])

    def density_std(self, what: str = "noise") -> Float[Array, " k"]:
        """The density std: ``std`` itself, or ``std / sqrt(rate)`` for a sample held over ``1/rate``."""
        if self.meaning == "density":
            return self.std
        if self.rate is None:
            raise ValueError(f"{what}: a sample std held as an input needs its rate; expected "
                             "Noise.sample(std, rate=HZ), got rate=None")
        return array_module(self.std).asarray(self.std) / math.sqrt(self.rate)


def parameter(value) -> Array:
    """A model's constant as a float64 array: the converter of the fields of a parameterized function (an
    ``eqx.Module`` output map, noise model or dynamics), which makes them leaves (see :class:`Sensor`)."""
    return jnp.asarray(value, dtype=jnp.float64)


class ConstantOutput(eqx.Module):
    r"""$h(g) = c$: an output that does not depend on the state. Such a sensor is a *covariate*: its samples
    ride in the log for another sensor's noise model (``scale``), add nothing to the residual or to E, and carry
    no innovation (:attr:`Sensor.covariate`); e.g. the norms of :func:`~liemef.systems.attitude_imu`. ``c`` is a
    leaf."""

    c: Float[Array, " k"] = eqx.field(converter=parameter)

    def __call__(self, g, t):
        return self.c


class Sensor(eqx.Module):
    r"""One sensor: a named block of the output with its own sample times, noise and (optional) gate.

    Args:
        name: the sensor's name (log columns are ``{name}_{component}``).
        fn: the output map ``h(g, t)`` of this sensor, a pure JAX function returning shape (k,). A callable
            ``eqx.Module`` is a *parameterized* map: its array fields (a direction, a field's norm, landmarks) are
            leaves, so a new value is data, as a weight is (one compiled structure for every recording; the C
            engine builds one more kernel for a value with new exact zeros, docs/engines.md), and its other
            fields are structure.
        noise: its :class:`Noise` (k stds, or one for all components).
        components: k component names (default ``0..k-1``); ``units`` k units.
        gate: a chi-square probability (e.g. 0.999): a sample whose innovation
            $\nu^\top S^{-1}\nu$ with $S = Dh\,K\,Dh^\top + \Sigma$ exceeds the quantile is rejected and counted.
        robust: ``"huber"`` or ``"cauchy"``: the sample's weight is scaled by $\min(1, c/d)$ or
            $1/(1 + d^2/c^2)$ with $d$ the Mahalanobis distance of the innovation, ``c = robust_scale``.
        max_rejections: the most consecutive rejected samples allowed: the next rejection in a row is a failure
            (cause ``gate``).
        weight_fn: optional time-varying weight ``w(t) >= 0`` that multiplies the sensor's information.
        scale: optional heteroscedastic noise model: ``scale(std, params, y)`` of the whole sample ``y`` (all
            sensors' components, zeros where missing), the sensor's noise ``std`` and ``params``, returns a factor
            f in $(0, 1]$ on the sensor's information (its std becomes ``std / sqrt(f)``) or a k x k matrix T
            (its information becomes $T^\top W T$). A hashable object (e.g. a frozen dataclass), so that equal
            models are one compiled structure, or a parameterized ``eqx.Module`` (as ``fn``).
        scale_params: the parameters of ``scale``, an array leaf (tuning them never recompiles).
        angles: the components that are angles (names or indices, or True for all): their residual is the
            difference wrapped into [-pi, pi) (a bearing reported in (-pi, pi] against a prediction that is not).
        residual: the sensor's own residual ``residual(y, h) -> (k,)``, zero at ``y == h`` and smooth in h near y
            (:func:`~liemef.systems.direction_residual` for unit directions,
            :func:`~liemef.systems.rotation_residual` for rotation vectors); default ``y - h``.

    Gates, robust losses, the filters' updates and the innovations all use the residual (docs/weights.md).
    """

    name: str = eqx.field(static=True)
    fn: Callable
    noise: Noise
    components: tuple[str, ...] = eqx.field(static=True)
    units: tuple[str, ...] = eqx.field(static=True)
    gate: float | None = eqx.field(static=True, default=None)
    robust: str | None = eqx.field(static=True, default=None)
    robust_scale: float = eqx.field(static=True, default=2.0)
    max_rejections: int | None = eqx.field(static=True, default=None)
    weight_fn: Callable | None = eqx.field(static=True, default=None)
    scale: Callable | None = None
    scale_params: Float[Array, " q"] | None = None
    residual: Callable | None = eqx.field(static=True, default=None)

    def __init__(self, name: str, fn: Callable, noise: Noise, components=None, units=None, *, dim: int | None = None,
                 gate: float | None = None, robust: str | None = None, robust_scale: float = 2.0,
                 max_rejections: int | None = None, weight_fn: Callable | None = None, scale: Callable | None = None,
                 scale_params=None, angles=None, residual: Callable | None = None):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"name: expected a sensor name usable as a column prefix (letters, digits, _), "
                             f"got {name!r}")
        if not callable(fn):
            raise ValueError(f"sensor {name!r}: fn: expected a function h(g, t), got {type(fn).__name__}")
        if not isinstance(noise, Noise):
            raise ValueError(f"sensor {name!r}: noise: expected Noise.density(std) or Noise.sample(std), got "
                             f"{type(noise).__name__}")
        k = dim if dim is not None else (len(components) if components is not None else noise.dim)
        if noise.dim not in (1, k):
            raise ValueError(f"sensor {name!r}: noise: expected 1 or {k} stds, got {noise.dim}")
        if noise.dim == 1 and k > 1:
            noise = Noise(jnp.full((k,), noise.std[0]), noise.meaning, noise.rate)
        components = tuple(str(c) for c in (components if components is not None else range(k)))
        units = tuple(units) if units is not None else ("",) * k
        if len(components) != k or len(units) != k:
            raise ValueError(f"sensor {name!r}: expected {k} component names and units, got {len(components)} "
                             f"and {len(units)}")
        if gate is not None and not (0.0 < float(gate) < 1.0):
            raise ValueError(f"sensor {name!r}: gate: expected a chi-square probability in (0, 1), got {gate}")
        if robust is not None:
            _validate.choice(f"sensor {name!r}: robust", robust, set(ROBUST))
        if not (math.isfinite(robust_scale) and robust_scale > 0):
            raise ValueError(f"sensor {name!r}: robust_scale: expected a number > 0, got {robust_scale}")
        if max_rejections is not None and (int(max_rejections) != max_rejections or max_rejections < 1):
            raise ValueError(f"sensor {name!r}: max_rejections: expected an integer >= 1, got {max_rejections}")
        self.name, self.fn, self.noise, self.components, self.units = name, fn, noise, components, units
        self.gate = None if gate is None else float(gate)
        self.robust, self.robust_scale = robust, float(robust_scale)
        self.max_rejections = None if max_rejections is None else int(max_rejections)
        self.weight_fn = weight_fn
        if (scale is None) != (scale_params is None) or (scale is not None and not callable(scale)):
            raise ValueError(f"sensor {name!r}: scale, scale_params: expected both (a function scale(std, params, y) "
                             f"and its parameters) or neither, got {scale!r} and {scale_params!r}")
        self.scale = scale
        self.scale_params = None if scale_params is None else jnp.asarray(
            _validate.array(f"sensor {name!r}: scale_params", np.atleast_1d(np.asarray(scale_params, np.float64)),
                            (None,)))
        if residual is not None and not callable(residual):
            raise ValueError(f"sensor {name!r}: residual: expected a function residual(y, h), got "
                             f"{type(residual).__name__}")
        if angles is not None and angles is not False:
            if residual is not None:
                raise ValueError(f"sensor {name!r}: angles, residual: expected one of them (a residual function "
                                 "wraps its own angles), got both")
            residual = AngleResidual(_angle_mask(name, angles, components))
        self.residual = residual

    @property
    def dim(self) -> int:
        """Number of components."""
        return len(self.components)

    @property
    def covariate(self) -> bool:
        """Whether the output does not depend on the state (:class:`ConstantOutput`): the samples are another
        sensor's covariates, not measurements; the innovation monitor does not judge them."""
        return isinstance(self.fn, ConstantOutput)

    @property
    def columns(self) -> tuple[str, ...]:
        """Log column names ``{name}_{component}``."""
        return tuple(f"{self.name}_{c}" for c in self.components)


def _angle_mask(name: str, angles, components: tuple[str, ...]) -> tuple[bool, ...]:
    """The components ``angles`` names (names or indices, or True for all) as a mask."""
    if angles is True:
        return (True,) * len(components)
    mask = [False] * len(components)
    for a in (angles if isinstance(angles, list | tuple) else (angles,)):
        if isinstance(a, str) and a in components:
            mask[components.index(a)] = True
        elif isinstance(a, int) and not isinstance(a, bool) and 0 <= a < len(components):
            mask[a] = True
        else:
            raise ValueError(f"sensor {name!r}: angles: expected component names from {list(components)} or "
                             f"indices below {len(components)} (or True for all), got {a!r}")
    return tuple(mask)


def _own_residual(s: Sensor, y, h):
    """The sensor ``s``'s own residual of ``y`` against ``h`` (``(..., k)``), as float64; a one-component sensor's
    residual may be a scalar per sample (as its output may)."""
    r = jnp.asarray(s.residual(y, h), dtype=jnp.float64)
    return r[..., None] if r.ndim == y.ndim - 1 else r


def blocks_of(sensors) -> tuple[Block, ...]:
    """The engine's static layout of ``sensors`` (the gates' chi-square thresholds)."""
    out, start = [], 0
    for s in sensors:
        thr = None if s.gate is None else quantile(s.gate, s.dim)
        out.append(Block(s.name, start, start + s.dim, s.noise.meaning == "sample", thr, s.robust, s.robust_scale,
                         s.max_rejections, s.weight_fn, adaptive=s.scale is not None))
        start += s.dim
    return tuple(out)


class SensorSystem(AbstractSystem):
    r"""A system whose output is a set of :class:`Sensor` blocks and whose weights come from noise levels.

    Args:
        group: the Lie group of the state.
        dynamics: ``lambda(g, u, t)``, a pure JAX function returning an n-vector (a callable ``eqx.Module``
            has its array fields as leaves, as a :class:`Sensor`'s ``fn``).
        sensors: the sensors, in log-column order.
        process_noise: :class:`Noise` with d stds (algebra units per second, e.g. rad/s, m/s) of the model error
            $B\delta$; a sample std needs its ``rate``.
        noise_map: n x d matrix that places the d noise components in the algebra (default: the identity,
            d = n). Zero columns are allowed (e.g. a constant parameter).
        inputs: names of the m input components (log columns); ``input_units`` their units.
        state_names: names of ``group.coords()`` (reports, CSV headers).
        state_units: their units.

    The theorem's matrices are derived (module docstring): ``D = diag(std)``, ``Q = I``,
    ``B = noise_map diag(density std)``, ``R = I``.
    """

    group_type: type[LieGroup] = eqx.field(static=True)
    dynamics_fn: Callable
    sensors: tuple[Sensor, ...]
    process_noise: Noise
    noise_map: Float[Array, "n d"] = eqx.field(converter=matrix)
    inputs: tuple[str, ...] = eqx.field(static=True)
    input_units: tuple[str, ...] = eqx.field(static=True)
    coord_names: tuple[str, ...] | None = eqx.field(static=True, default=None)
    coord_units: tuple[str, ...] | None = eqx.field(static=True, default=None)

    def __init__(self, group: type[LieGroup], dynamics: Callable, sensors, process_noise: Noise, noise_map=None,
                 inputs=(), input_units=None, state_names=None, state_units=None):
        if not (isinstance(group, type) and issubclass(group, LieGroup)):
            raise ValueError(f"group: expected a liemef Lie group class, got {group!r}")
        sensors = tuple(sensors)
        if not sensors or not all(isinstance(s, Sensor) for s in sensors):
            raise ValueError(f"sensors: expected one or more Sensor objects, got {sensors!r}")
        if not isinstance(process_noise, Noise):
            raise ValueError(f"process_noise: expected a Noise, got {type(process_noise).__name__}")
        n = group.tangent_dim
        if noise_map is None and process_noise.dim == 1 and n > 1:  # one std for every algebra direction
            process_noise = Noise(jnp.full((n,), process_noise.std[0]), process_noise.meaning, process_noise.rate)
        d = process_noise.dim
        if noise_map is None and d != n:
            raise ValueError(f"process_noise: expected 1 or {n} stds (one per algebra direction of "
                             f"{group.__name__}), or a noise_map of shape ({n}, {d}), got {d} stds")
        noise_map = np.eye(n) if noise_map is None else noise_map
        _validate.array("noise_map", noise_map, (n, d))
        inputs = tuple(str(i) for i in inputs)
        input_units = tuple(input_units) if input_units is not None else ("",) * len(inputs)
        if len(input_units) != len(inputs):
            raise ValueError(f"input_units: expected {len(inputs)} units, got {len(input_units)}")
        names = ["t", *inputs, *(c for s in sensors for c in s.columns)]
        dup = sorted({c for c in names if names.count(c) > 1})
        if dup:
            raise ValueError(f"sensors: expected unique log column names, got duplicates {dup}")
        for what, v in (("state_names", state_names), ("state_units", state_units)):
            if v is not None and len(v) != group.coords_dim:
                raise ValueError(f"{what}: expected {group.coords_dim} entries, got {len(v)}")
        self.group_type, self.dynamics_fn, self.sensors = group, dynamics, sensors
        self.process_noise, self.noise_map = process_noise, noise_map
        self.process_noise.density_std("process_noise")
        self.inputs, self.input_units = inputs, input_units
        self.coord_names = None if state_names is None else tuple(state_names)
        self.coord_units = None if state_units is None else tuple(state_units)

    # --- the theorem's matrices, derived from the noise levels ------------------------------------------------
    # NumPy where no leaf is traced (._traced.array_module): the same values, no XLA compile.
    @property
    def B(self) -> Float[Array, "n d"]:
        """``noise_map diag(density std)`` of the process noise."""
        std = self.process_noise.density_std("process_noise")
        xp = array_module(self.noise_map, std)
        return xp.asarray(self.noise_map) * xp.asarray(std)[None, :]

    @property
    def R(self) -> Float[Array, "d d"]:
        """The identity: the stds are in B."""
        return np.eye(self.process_noise.dim)

    @property
    def D(self) -> Float[Array, "p p"]:
        """``diag(std)`` of the sensors, in output order."""
        stds = [s.noise.std for s in self.sensors]
        xp = array_module(stds)
        return xp.diag(xp.concatenate([xp.asarray(s) for s in stds]))

    @property
    def Q(self) -> Float[Array, "p p"]:
        """The identity: the stds are in D."""
        return np.eye(self.output_dim)

    @property
    def output_dim(self) -> int:
        """Sum of the sensors' dimensions."""
        return sum(s.dim for s in self.sensors)

    def blocks(self) -> tuple[Block, ...]:
        """One block per sensor, with its sample meaning, gate and robust loss."""
        return blocks_of(self.sensors)

    def sample_transform(self, y):
        """Block-diagonal: each sensor's ``scale`` of the sample ``y`` (a factor f gives sqrt(f) I, a matrix is
        taken as it is), the identity for the others."""
        blocks = []
        for s in self.sensors:
            if s.scale is None:
                blocks.append(jnp.eye(s.dim))
                continue
            T = jnp.asarray(s.scale(s.noise.std, s.scale_params, y), dtype=jnp.float64)
            blocks.append(jnp.sqrt(T) * jnp.eye(s.dim) if T.ndim == 0 else T)
        return jax.scipy.linalg.block_diag(*blocks)

    def with_scale_params(self, **params) -> SensorSystem:
        """A copy with new parameters of the sensors' heteroscedastic models, by sensor name: same structure."""
        out = self
        for name, value in params.items():
            idx = [i for i, s in enumerate(self.sensors) if s.name == name and s.scale is not None]
            if not idx:
                raise ValueError(f"with_scale_params: expected a sensor with a noise model from "
                                 f"{[s.name for s in self.sensors if s.scale is not None]}, got {name!r}")
            old = self.sensors[idx[0]].scale_params
            v = jnp.asarray(value, dtype=jnp.float64).reshape(-1)
            if v.shape != old.shape:
                raise ValueError(f"{name}: expected {old.shape[0]} parameters, got {v.shape[0]}")
            out = eqx.tree_at(lambda s, i=idx[0]: s.sensors[i].scale_params, out, v)
        return out

    # --- the model --------------------------------------------------------------------------------------------
    @property
    def group(self) -> type[LieGroup]:
        """The state's group."""
        return self.group_type

    @property
    def input_dim(self) -> int:
        """Number of named inputs."""
        return len(self.inputs)

    def dynamics(self, g, u, t):
        """The dynamics function, as float64."""
        return jnp.asarray(self.dynamics_fn(g, u, t), dtype=jnp.float64)

    def output(self, g, t):
        """The sensors' outputs, concatenated in order."""
        return jnp.concatenate([jnp.atleast_1d(jnp.asarray(s.fn(g, t), dtype=jnp.float64)) for s in self.sensors])

    @property
    def manifold_residuals(self) -> bool:
        """Whether a sensor declares its residual (angles or a function)."""
        return any(s.residual is not None for s in self.sensors)

    def residual(self, y, h, t=None):
        """Each sensor's residual ``y (-) h`` (its own, or ``y - h``), concatenated."""
        out, start = [], 0
        for s in self.sensors:
            yb, hb = y[..., start:start + s.dim], h[..., start:start + s.dim]
            out.append(yb - hb if s.residual is None else _own_residual(s, yb, hb))
            start += s.dim
        return jnp.concatenate(out, axis=-1)

    def output_seen_from(self, y, g, t):
        """The outputs, where a sensor declares a residual as ``y - (y (-) h(g))``: then ``y`` minus this is the
        residual, and its derivatives are the residual's."""
        if not self.manifold_residuals:
            return self.output(g, t)
        out, start = [], 0
        for s in self.sensors:
            hb = jnp.atleast_1d(jnp.asarray(s.fn(g, t), dtype=jnp.float64))
            if s.residual is not None:
                yb = y[start:start + s.dim]
                hb = yb - _own_residual(s, yb, hb)
            out.append(hb)
            start += s.dim
        return jnp.concatenate(out)

    @property
    def input_names(self) -> tuple[str, ...]:
        """The inputs' names (log columns)."""
        return self.inputs

    @property
    def output_names(self) -> tuple[str, ...]:
        """``{sensor}_{component}`` for every sensor component."""
        return tuple(c for s in self.sensors for c in s.columns)

    @property
    def output_units(self) -> tuple[str, ...]:
        """The sensors' units, in output order."""
        return tuple(u for s in self.sensors for u in s.units)

    @property
    def state_names(self) -> tuple[str, ...]:
        """The given state names, else ``q1..``."""
        return self.coord_names if self.coord_names is not None else super().state_names

    @property
    def state_units(self) -> tuple[str, ...]:
        """The given state units, else empty."""
        return self.coord_units if self.coord_units is not None else super().state_units

    def __check_init__(self):
        # the user's functions at their first trace (liemef.systems._traced), each named: the dynamics, then per
        # sensor its output h(g, t) and its residual(y, h)
        G = self.group
        g, t, m, n = G.identity(), jnp.zeros(()), self.input_dim, G.tangent_dim
        check_traced("dynamics", self.dynamics_fn, (g, jnp.zeros((m,)), t), (n,),
                     given=f" with g in {G.__name__}, u of shape ({m},) and t a scalar",
                     meaning=f"one value per direction of the algebra of {G.__name__}")
        for s in self.sensors:
            parts = f"one value per component {', '.join(s.columns)}"
            check_traced(f"sensor {s.name!r}: fn", s.fn, (g, t), (s.dim,), scalar=True,
                         given=f" with g in {G.__name__} and t a scalar", meaning=parts)
            if s.residual is not None:
                y = jax.ShapeDtypeStruct((s.dim,), jnp.float64)
                check_traced(f"sensor {s.name!r}: residual", s.residual, (y, y), (s.dim,), scalar=True,
                             given=f" with y and h of shape ({s.dim},)", meaning=parts)

    def check_finite_at(self, g, t=0.0, *, state: str = "the initial state", singular: bool = True) -> None:
        """Each sensor's output ``h(g, t)`` and, where it is finite, its residual at ``y = h`` (0 by its
        contract), evaluated once: a ValueError naming the sensor and the function when an output is NaN (also
        infinite unless ``singular``) or a residual is not finite at ``g`` (``state`` says which;
        :meth:`liemef.filters.AbstractFilter.init` calls it at the initial state)."""
        at = _at(state, t)
        for s in self.sensors:
            h = check_finite(f"sensor {s.name!r}: fn", s.fn, jnp.atleast_1d(jnp.asarray(s.fn(g, t))), at,
                             singular=singular)
            if s.residual is not None and np.all(np.isfinite(h)):
                hj = jnp.asarray(h, dtype=jnp.float64)
                check_finite(f"sensor {s.name!r}: residual", s.residual, s.residual(hj, hj),
                             f"at y = h = {np.array2string(h, precision=4, threshold=12)}, the output {at}")

    def with_noise(self, **levels) -> SensorSystem:
        """A copy with new noise levels, by sensor name (or ``process_noise=``): same structure, so a filter of
        the copy reuses the compiled code."""
        out = self
        for name, noise in levels.items():
            if name == "process_noise":
                if not isinstance(noise, Noise) or noise.dim != self.process_noise.dim:
                    raise ValueError(f"process_noise: expected a Noise with {self.process_noise.dim} stds, got "
                                     f"{noise!r}")
                out = eqx.tree_at(lambda s: s.process_noise, out, noise)
                continue
            idx = [i for i, s in enumerate(self.sensors) if s.name == name]
            if not idx:
                raise ValueError(f"with_noise: unknown sensor {name!r}; expected one of "
                                 f"{[s.name for s in self.sensors]} or process_noise")
            i = idx[0]
            old = self.sensors[i].noise
            if not isinstance(noise, Noise) or noise.dim not in (1, old.dim):
                raise ValueError(f"{name}: expected a Noise with 1 or {old.dim} stds, got {noise!r}")
            std = jnp.broadcast_to(noise.std, old.std.shape)
            if (noise.meaning, noise.rate) != (old.meaning, old.rate):
                raise ValueError(f"{name}: a new noise level must keep the meaning {old.meaning!r} and rate "
                                 f"{old.rate} (they are structure); got {noise.meaning!r}, {noise.rate}")
            out = eqx.tree_at(lambda s, i=i: s.sensors[i].noise.std, out, std)
        return out

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _validate
from ..groups import LieGroup
from ._traced import array_module, at_state, check_finite, check_traced


def matrix(x) -> Array:
    """Field converter: a float64 JAX array; complex values and objects are kept as they are, for the
    system's check to refuse them by name (a cast would truncate them)."""
    if isinstance(x, jax.core.Tracer):
        return jnp.asarray(x, dtype=jnp.float64)
    kind = getattr(x, "dtype", None)
    kind = np.asarray(x).dtype.kind if kind is None and x is not None else getattr(kind, "kind", None)
    if kind is not None and kind not in "biuf":
        return np.asarray(x)
    return jnp.asarray(x, dtype=jnp.float64)


@dataclass(frozen=True)
class Block:
    """The static layout of one sensor in the output vector, as the filter engine uses it."""

    name: str
    start: int
    stop: int
    sample: bool
    gate_threshold: float | None = None
    robust: str | None = None
    robust_scale: float = 2.0
    max_rejections: int | None = None
    weight_fn: Callable | None = None
    adaptive: bool = False
    """Whether the block's information depends on the sample (:meth:`AbstractSystem.sample_transform`)."""

    @property
    def dim(self) -> int:
        """Number of output components of the block."""
        return self.stop - self.start


class AbstractSystem(eqx.Module):
    r"""A system on a Lie group G, left-trivialized (Saccon et al. 2016, eqs. (1)-(2)):

    $$\dot g = g\,(\lambda(g, u, t) + B\delta), \qquad y = h(g, t) + D\varepsilon,$$

    with the cost weights Q (on $\varepsilon$, p x p) and R (on $\delta$, d x d) of
    $J = \tfrac12 \int e^{-\alpha(t-\tau)} (\delta^\top R \delta + \varepsilon^\top Q \varepsilon)\,d\tau$.

    A concrete system sets ``group`` and implements :meth:`dynamics` and :meth:`output` as pure JAX functions;
    every derivative the filter needs comes from autodiff. Matrices are validated on construction.
    """

    B: eqx.AbstractVar[Float[Array, "n d"]]
    D: eqx.AbstractVar[Float[Array, "p p"]]
    Q: eqx.AbstractVar[Float[Array, "p p"]]
    R: eqx.AbstractVar[Float[Array, "d d"]]

    @property
    @abc.abstractmethod
    def group(self) -> type[LieGroup]:
        """The Lie group G of the state."""

    @abc.abstractmethod
    def dynamics(self, g: LieGroup, u: Float[Array, " m"], t: Float[Array, ""]) -> Float[Array, " n"]:
        r"""Left-trivialized dynamics $\lambda(g, u, t) \in \mathbb R^n$."""

    @abc.abstractmethod
    def output(self, g: LieGroup, t: Float[Array, ""]) -> Float[Array, " p"]:
        r"""Output map $h(g, t) \in \mathbb R^p$."""

    @property
    @abc.abstractmethod
    def input_dim(self) -> int:
        """Length m of the input vector u (0 for none)."""

    @property
    def output_dim(self) -> int:
        """Length p of the output vector."""
        return self.D.shape[0]

    @property
    def noise_dim(self) -> int:
        """Number d of model-error components (columns of B)."""
        return self.B.shape[1]

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the input components (log columns)."""
        return tuple(f"u{k + 1}" for k in range(self.input_dim))

    def blocks(self) -> tuple[Block, ...]:
        """The output's sensor blocks as the filter engine sees them: one density block ``y`` by default."""
        return (Block("y", 0, self.output_dim, sample=False),)

    def sample_transform(self, y: Float[Array, " p"]) -> Float[Array, "p p"]:
        r"""A heteroscedastic measurement model: the noise of the sample ``y`` (zeros where missing) is
        $\Sigma(y) = T(y)^{-1} \Sigma\, T(y)^{-\top}$, so its information is $T^\top D^{-\top} Q D^{-1} T$. Read by
        the filters only if a block is marked ``adaptive``. Default: the identity."""
        return jnp.eye(self.output_dim)

    @property
    def manifold_residuals(self) -> bool:
        """Whether an output component has a residual other than ``y - h`` (:meth:`residual`)."""
        return False

    def residual(self, y: Float[Array, "... p"], h: Float[Array, "... p"], t=None) -> Float[Array, "... p"]:
        r"""The residual $y \ominus h$ of a sample against an output (docs/weights.md): ``y - h`` unless a sensor
        declares its own (angles, directions, rotations: :mod:`liemef.systems._residuals`)."""
        return y - h

    def output_seen_from(self, y: Float[Array, " p"], g: LieGroup, t) -> Float[Array, " p"]:
        r"""$\tilde h_y(g) = y - (y \ominus h(g))$, the output as the filters see it against the sample ``y``:
        its derivatives are the residual's. :meth:`output` itself where every residual is ``y - h``."""
        return self.output(g, t) if not self.manifold_residuals else y - self.residual(y, self.output(g, t), t)

    def process_noise_at(self, g: LieGroup, BRB: Float[Array, "n n"], u: Float[Array, " m"],
                         t: Float[Array, ""]) -> Float[Array, "n n"]:
        r"""The process-noise density on the algebra at the state ``g``, input ``u`` and time ``t``, given the
        nominal $B R^{-1} B^\top$: the nominal itself (a constant B). A system whose noise map depends on the state
        (the inverted state of :func:`~liemef.systems.right_error`) or on the input (a gyro whose error grows with
        the rate it measures) returns it there; the filters evaluate it at their estimate and the interval's input,
        which Theorem 4.1's terms allow: B enters the Hamiltonian only through $\mu^\top B R^{-1} B^\top \mu$, whose
        derivatives in g vanish with the costate $\mu$ at the estimate, and u(t) is a known function of time."""
        return BRB

    @property
    def constant_process_noise(self) -> bool:
        """Whether :meth:`process_noise_at` is the nominal B R^-1 B^T at every state, input and time (batch solvers
        and the simulator need it)."""
        return type(self).process_noise_at is AbstractSystem.process_noise_at

    def information(self) -> Float[Array, "p p"]:
        r"""Measurement information $D^{-\top} Q D^{-1}$: per unit time for density blocks, per sample for
        sample blocks (:mod:`liemef.systems._sensors`)."""
        D, Q = self.D, self.Q
        xp = array_module(D, Q)  # NumPy outside a trace: no XLA compile
        Dinv = xp.linalg.inv(xp.asarray(D))
        return Dinv.T @ xp.asarray(Q) @ Dinv

    @property
    def output_names(self) -> tuple[str, ...]:
        """Names of the output components (reports, CSV headers)."""
        return tuple(f"y{k + 1}" for k in range(self.output_dim))

    @property
    def output_units(self) -> tuple[str, ...]:
        """Units of the output components ("" when unknown)."""
        return ("",) * self.output_dim

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the state coordinates ``group.coords()`` (reports, CSV headers)."""
        return tuple(f"q{k + 1}" for k in range(self.group.coords_dim))

    @property
    def state_units(self) -> tuple[str, ...]:
        """Units of the state coordinates ("" when unknown)."""
        return ("",) * self.group.coords_dim

    def __check_init__(self):
        G = self.group
        n = G.tangent_dim
        for name in ("D", "Q"):
            _validate.numeric(name, getattr(self, name))
        B = _validate.array("B", self.B, (n, None))
        d = B.shape[1]
        _validate.symmetric_psd("R", self.R, d)
        out = check_traced("output", self.output, (G.identity(), jnp.zeros(())), None,
                           given=f" with g in {G.__name__} and t a scalar")
        if out.shape != (self.D.shape[0],) or self.D.ndim != 2:
            p = out.shape[0] if out.ndim == 1 else "p"
            raise ValueError(f"D: expected shape ({p}, {p}) to match the output h(g, t) of shape {out.shape}, "
                             f"got {self.D.shape}")
        p = out.shape[0]
        _validate.invertible("D", self.D, p)
        _validate.symmetric_psd("Q", self.Q, p)
        m = self.input_dim
        check_traced("dynamics", self.dynamics, (G.identity(), jnp.zeros((m,)), jnp.zeros(())), (n,),
                     given=f" with g in {G.__name__}, u of shape ({m},) and t a scalar",
                     meaning=f"lambda(g, u, t): one value per direction of the algebra of {G.__name__}")

    def check_finite_at(self, g: LieGroup, t=0.0, *, state: str = "the initial state", singular: bool = True) -> None:
        """The output ``h(g, t)`` and, where it is finite, the residual at ``y = h`` (0 by its contract),
        evaluated once: a ValueError naming the function when the output is NaN (also infinite unless
        ``singular``) or the residual is not finite at ``g`` (``state`` says which;
        :meth:`liemef.filters.AbstractFilter.init` calls it at the initial state;
        :class:`~liemef.systems.SensorSystem` names the sensor)."""
        at = at_state(state, t)
        h = check_finite("output", self.output, self.output(g, t), at, singular=singular)
        if np.all(np.isfinite(h)):
            hj = jnp.asarray(h)
            check_finite("residual", self.residual, self.residual(hj, hj, t), f"at y = h, the output {at}")


class System(AbstractSystem):
    """A user-defined system from plain functions: ``System(group, dynamics, output, B=, D=, Q=, R=)``.

    ``dynamics(g, u, t)`` returns an n-vector, ``output(g, t)`` a p-vector; both must be written with
    ``jax.numpy`` so that autodiff can differentiate them.
    """

    group_type: type[LieGroup] = eqx.field(static=True)
    dynamics_fn: Callable = eqx.field(static=True)
    output_fn: Callable = eqx.field(static=True)
    B: Float[Array, "n d"] = eqx.field(converter=matrix)
    D: Float[Array, "p p"] = eqx.field(converter=matrix)
    Q: Float[Array, "p p"] = eqx.field(converter=matrix)
    R: Float[Array, "d d"] = eqx.field(converter=matrix)
    n_inputs: int = eqx.field(static=True, default=0)
    names: tuple[str, ...] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        # the user's functions at their first trace, named (liemef.systems._traced); the output's size against D
        # is AbstractSystem's check
        _validate.integer("n_inputs", self.n_inputs, 0)
        G = self.group_type
        m, n = self.n_inputs, G.tangent_dim
        check_traced("dynamics", self.dynamics_fn, (G.identity(), jnp.zeros((m,)), jnp.zeros(())), (n,),
                     given=f" with g in {G.__name__}, u of shape ({m},) and t a scalar",
                     meaning=f"lambda(g, u, t): one value per direction of the algebra of {G.__name__}")
        check_traced("output", self.output_fn, (G.identity(), jnp.zeros(())), None,
                     given=f" with g in {G.__name__} and t a scalar")

    def check_finite_at(self, g: LieGroup, t=0.0, *, state: str = "the initial state", singular: bool = True) -> None:
        """The user's output ``h(g, t)``, evaluated once: a ValueError naming it when it is NaN (also infinite
        unless ``singular``) at ``g``."""
        check_finite("output", self.output_fn, self.output_fn(g, t), at_state(state, t), singular=singular)

    @property
    def group(self) -> type[LieGroup]:
        """The user's group."""
        return self.group_type

    def dynamics(self, g, u, t):
        """The user's dynamics function."""
        return jnp.asarray(self.dynamics_fn(g, u, t), dtype=jnp.float64)

    def output(self, g, t):
        """The user's output function."""
        return jnp.asarray(self.output_fn(g, t), dtype=jnp.float64)

    @property
    def input_dim(self) -> int:
        """The declared number of inputs."""
        return self.n_inputs

    @property
    def output_names(self) -> tuple[str, ...]:
        """The user's names, else ``y1..yp``."""
        return self.names if self.names is not None else super().output_names

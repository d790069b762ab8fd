"""Forms with return-point memory: the magnetization of a distribution of pinning cells.

The Jiles–Atherton forms carry one number, M, from sample to sample, so a minor loop
does not close on itself and the loop shape cannot change with the amplitude the way
measured loops do (Zirka et al., J. Appl. Phys. 112 (2012) 043916). The forms here carry
the state of N **pinning cells** instead. Cell i is a play (dry-friction) operator of
width χ_i on the effective field He = H + α̃·M: its reversible field h_i stays where it is
while |He − h_i| < χ_i and is dragged along at distance χ_i otherwise,

    h_i ← clip(h_i, He − χ_i, He + χ_i)           (exact for a monotone He),

and the magnetization is that of the cells' reversible fields plus a reversible part,

    M = Ms·[c·L(He/a_r) + (1 − c)·(1/N)·Σ_i L(h_i/a)],

L the Langevin function.
The pinning fields are log-normal: χ_i = k·exp(s·z_i), z_i the standard normal quantiles
at (i − ½)/N, so k is the median pinning field (A/m, of the order of the coercive field)
and s = ``spread`` the width of the distribution (1; 0: every cell alike). α̃ couples the
cells through the mean field (the "moving" model; α̃ = 0: independent cells); where it
is not 0, M is implicit and is found at every point by Newton's method in M, safeguarded
and differentiated by the implicit function theorem.

- `PlayJA` (a_r = a): the energy-based, dry-friction model of Bergqvist (Physica B 233
  (1997) 342) and Henrotte et al. (COMPEL 25 (2006) 71; François-Lavet et al., J.
  Comput. Appl. Math. 246 (2013) 243) in its scalar form: one anhysteretic, the
  Langevin function of the Jiles–Atherton forms, for every cell and for the reversible
  part (the cell without pinning).
- `PreisachJA` (its own a_r = ``a_rev``): the Preisach model with a factorized density
  of coercive fields (log-normal: k, s) and interaction fields (L'(x)/2 of width a, a
  heavy-tailed density like the Lorentzian of Della Torre's and Bertotti's Preisach
  models), moving by α̃ (Della Torre, IEEE Trans. Audio 14 (1966) 86), with a reversible
  component of its own width (Mayergoyz, *Mathematical Models of Hysteresis*, 1991: a
  Preisach model is a superposition of play operators followed by its interaction
  distribution; Basso & Bertotti, IEEE Trans. Magn. 32 (1996) 4210 for the factorized
  density).

Both have the Preisach properties by construction: wiping out and return-point memory
(a minor loop closes on itself), and congruent minor loops for α̃ = 0; from the
demagnetized state (every h_i = 0) a loop of amplitude Hm moves only the cells with
χ_i ≲ Hm, so the loop's shape changes with its amplitude (the Rayleigh region at small
fields). The cells' fields are exact along a piecewise-linear drive, so the substeps only
set where M and its slope are reported for the structure (no integration error).

The same forms are driven by B (the unknown per point is M with He = B/μ0 + (α̃ − 1)·M,
unique for α̃ < 1) and by M (the inverse model: He solved from M, H = He − α̃·M).
"""

from __future__ import annotations

import abc
import functools
import statistics
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._typing import Real
from ..params import MU0, Parameters, is_concrete, shown_value
from .langevin import langevin_and_slope
from .timeloop import AbstractPathForm, Interval

#: Newton steps per point (each from the previous point's solution, safeguarded).
NEWTON_STEPS = 4
#: Largest number of cells a form may have.
MAX_CELLS = 256
#: Smallest dM/dHe the inverse (M-driven) form uses, relative to Ms/(3a) (as
#: `jaxhyst.model.inverse.CHI_FLOOR` for the Jiles–Atherton forms).
SLOPE_FLOOR = 1e-3


@functools.cache
def _quantiles(cells: int) -> np.ndarray:
    """Standard normal quantiles at (i − ½)/N, i = 1 … N."""
    normal = statistics.NormalDist()
    return np.array([normal.inv_cdf((i + 0.5) / cells) for i in range(cells)])


def pinning_fields(p: Parameters, form):
    """The cells' pinning fields χ_i = k·exp(s·z_i) (A/m), shape (..., N)."""
    z = jnp.asarray(_quantiles(form.cells))
    return jnp.asarray(p.k)[..., None] * jnp.exp(jnp.asarray(form.spread)[..., None] * z)


def _cells_magnetization(p, form, He, h_prev):
    """Φ(He) from the cells' fields ``h_prev``: (M (A/m), the new cells' fields, dΦ/dHe
    with the cells that move here)."""
    chi = pinning_fields(p, form)
    lower, upper = He[..., None] - chi, He[..., None] + chi
    h = jnp.clip(h_prev, lower, upper)
    moving = (h_prev < lower) | (h_prev > upper)
    a, a_r = jnp.asarray(p.a), form.reversible_width(p)
    L, dL = langevin_and_slope(He / a_r)
    g, dg = langevin_and_slope(h / a[..., None])
    M = p.Ms * (p.c * L + (1.0 - p.c) * jnp.mean(g, axis=-1))
    slope = p.Ms * (p.c * dL / a_r
                    + (1.0 - p.c) * jnp.mean(jnp.where(moving, dg, 0.0), axis=-1) / a)
    return M, h, slope


def _effective(driver, p, v, X):
    """He at the driver value ``v`` and the unknown ``X`` (M for the drivers H and B,
    He itself for M)."""
    if driver == "H":
        return v + p.alpha * X
    if driver == "B":
        return v / MU0 + (p.alpha - 1.0) * X
    return X


def _residual(driver, p, form, v, h_prev, X):
    """The point's equation in X (zero at the solution) and Φ'(He)."""
    He = _effective(driver, p, v, X)
    M, _, slope = _cells_magnetization(p, form, He, h_prev)
    return (M - v if driver == "M" else X - M), slope


def _floor(p, form):
    """The smallest dM/dHe the M-driven form uses (`SLOPE_FLOOR`·Ms/(3a))."""
    return SLOPE_FLOOR * p.Ms / (3.0 * p.a)


def _derivative_in_X(driver, p, form, slope):
    """d(residual)/dX for Φ' = ``slope`` (kept positive: the stable branch)."""
    if driver == "H":
        return jnp.maximum(1.0 - p.alpha * slope, 0.1)
    if driver == "B":
        return 1.0 + (1.0 - p.alpha) * slope
    return jnp.maximum(slope, _floor(p, form))


def _bracket(driver, p, form, v, v_prev, X_prev):
    """An interval that holds the point's root: X moves from the previous point's
    ``X_prev`` in the direction the driver moved, at most to saturation (H), by at most
    ΔB/(μ0·(1 − α̃)) (B: dM/dB ≤ 1/(μ0·(1 − α̃))) or by at most ΔM over the floored
    slope (M)."""
    delta = jnp.where(v >= v_prev, 1.0, -1.0)
    if driver == "H":
        far = delta * p.Ms
    elif driver == "B":
        reach = jnp.abs(v - v_prev) / (MU0 * jnp.maximum(1.0 - p.alpha, 1e-3))
        far = jnp.clip(X_prev + delta * reach, -p.Ms, p.Ms)
    else:
        far = X_prev + (v - v_prev) / _floor(p, form)
    return jnp.minimum(X_prev, far), jnp.maximum(X_prev, far)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _solve(driver, p, form, v, h_prev, X_prev, v_prev, rate):
    """The unknown X of the point (`_effective`) at the driver value ``v`` from the cells'
    fields ``h_prev`` and the previous point's ``X_prev`` at ``v_prev``: Newton's method
    from the prediction X_prev + ``rate``·(v − v_prev) (``rate``: dX/dv there, in the
    direction of motion), kept inside the bracket of `_bracket` (the residual rises with
    X), bisecting where a step would leave it. Differentiated by the implicit function
    theorem (the previous point enters only through ``h_prev``)."""
    lo, hi = _bracket(driver, p, form, v, v_prev, X_prev)
    start = jnp.clip(X_prev + rate * (v - v_prev), lo, hi)

    def newton(_, state):
        X, lo, hi = state
        G, slope = _residual(driver, p, form, v, h_prev, X)
        lo, hi = jnp.where(G < 0, X, lo), jnp.where(G > 0, X, hi)
        step = X - G / _derivative_in_X(driver, p, form, slope)
        inside = (step >= lo) & (step <= hi)
        return jnp.where(G == 0, X, jnp.where(inside, step, 0.5 * (lo + hi))), lo, hi

    return jax.lax.fori_loop(0, NEWTON_STEPS, newton, (start, lo, hi))[0]


@_solve.defjvp
def _solve_jvp(driver, primals, tangents):
    p, form, v, h_prev = primals[:4]
    X = _solve(driver, *primals)

    def residual(X, p, form, v, h_prev):
        return _residual(driver, p, form, v, h_prev, X)[0]

    G_X = jax.jvp(lambda X: residual(X, p, form, v, h_prev), (X,), (jnp.ones_like(X),))[1]
    G_in = jax.jvp(lambda *a: residual(X, *a), (p, form, v, h_prev), tangents[:4])[1]
    return X, -G_in / jnp.where(G_X == 0, 1.0, G_X)


class PlayPath(AbstractPathForm):
    """A form of pinning cells in the time loop (module docstring), driven by H, B or M
    (``driver``). State: X (M, or He for the driver M) and the N cells' fields. The
    outputs of an interval: Y at its substep points u_1 … u_S (M; the field H for the
    driver M), the slope dY/d(driver) at u_0 … u_S with its direction, X and the cells'
    fields at its end: shape (2S + 2 + N,). Parameters: ``(Parameters, form)``."""

    cells: int = eqx.field(static=True)
    driver: str = eqx.field(static=True, default="H")
    parameters: tuple[str, ...] = eqx.field(static=True,
                                            default=("Ms", "a", "k", "alpha", "c", "spread"))

    @property
    def scales_with_Ms(self) -> bool:
        return False  # (the cells' fields do not scale with Ms)

    @property
    def state_size(self) -> int:
        return 1 + self.cells

    def initial_state(self, theta, H0):
        return jnp.zeros((*jnp.shape(H0), 1 + self.cells), dtype=jnp.result_type(H0))

    def n_outputs(self, substeps: int) -> int:
        return 2 * substeps + 2 + self.cells

    def state_rows(self, substeps: int) -> tuple[int, ...]:
        return tuple(range(2 * substeps + 1, 2 * substeps + 2 + self.cells))

    def interval(self, theta, x: Interval, state, substeps: int, batched: bool):
        return self.advance(theta, x.H0, x.H1, state, x.delta_prev, substeps, batched)

    def _point(self, theta, v, state, v_prev, slope):
        """(X, cells, He) at the driver value ``v`` from ``state`` at ``v_prev``, where
        dY/d(driver) in the direction of motion is ``slope``."""
        p, form = theta
        X, h = state[..., 0], state[..., 1:]
        rate = slope + p.alpha if self.driver == "M" else slope  # dX/d(driver)
        X = _solve(self.driver, p, form, v, h, X, v_prev, jax.lax.stop_gradient(rate))
        He = _effective(self.driver, p, v, X)
        _, h, _ = _cells_magnetization(p, form, He, h)
        return X, h, He

    def _slope(self, theta, He, X, h, delta):
        """dY/d(driver) at a point with the cells ``h``, moving in direction ``delta``."""
        p, form = theta
        chi = pinning_fields(p, form)
        _, dg = langevin_and_slope(h / jnp.asarray(p.a)[..., None])
        tol = 1e-9 * (jnp.abs(He)[..., None] + chi)
        moving = delta[..., None] * (He[..., None] - h) >= chi - tol
        a_r = form.reversible_width(p)
        _, dL = langevin_and_slope(He / a_r)
        phi = p.Ms * (p.c * dL / a_r
                      + (1.0 - p.c) * jnp.mean(jnp.where(moving, dg, 0.0), -1) / p.a)
        if self.driver == "H":
            return phi / (1.0 - p.alpha * phi)
        if self.driver == "B":
            return phi / (MU0 * (1.0 + (1.0 - p.alpha) * phi))
        return 1.0 / jnp.maximum(phi, _floor(p, form)) - p.alpha

    def _output(self, theta, X, He, v):
        """Y: M for the drivers H and B, the field H = He − α̃·M for the driver M."""
        return He - theta[0].alpha * v if self.driver == "M" else X

    def advance(self, theta, v0, v1, state, delta_prev, substeps: int, batched: bool):
        """One interval's outputs from ``state`` at the driver value v0 to v1."""
        S = substeps
        delta = jnp.where(v1 >= v0, 1.0, -1.0)
        X, h = state[..., 0], state[..., 1:]
        He = _effective(self.driver, theta[0], v0, X)
        Y, k = [], [self._slope(theta, He, X, h, delta)]
        v = v0
        for j in range(1, S + 1):
            v, v_prev = v0 + (j / S) * (v1 - v0), v
            X, h, He = self._point(theta, v, jnp.concatenate([X[..., None], h], axis=-1),
                                   v_prev, k[-1])
            Y.append(self._output(theta, X, He, v))
            k.append(self._slope(theta, He, X, h, delta))
        return jnp.concatenate([jnp.stack(Y, -1), jnp.stack(k, -1), X[..., None], h], -1)

    def magnetization(self, state):
        """M (A/m) of a state (driver H)."""
        return state[..., 0]

    def end_magnetization(self, theta, v0, v1, state, substeps: int, batched: bool):
        """M (A/m) at the end of the interval from ``state`` at v0 to v1 (driver H)."""
        delta = jnp.where(v1 >= v0, 1.0, -1.0)
        return self._point(theta, v1, state, v0, self.slope(theta, v0, state, delta))[0]

    def slope(self, theta, v, state, delta):
        """dY/d(driver) at the driver value ``v`` and ``state``, moving in ``delta``."""
        X, h = state[..., 0], state[..., 1:]
        return self._slope(theta, _effective(self.driver, theta[0], v, X), X, h,
                           jnp.asarray(delta, dtype=jnp.result_type(v)))

    def split(self, out, theta, H, substeps: int):
        """(Y_sub (N, S), slopes (N, S + 1)) from the loop's outputs."""
        S = substeps
        return out[:, :S], out[:, S:2 * S + 1]


class AbstractPlayForm(eqx.Module):
    """A form of pinning cells (module docstring): the Jiles–Atherton parameters Ms, a,
    k (the median pinning field), α̃, c and its own parameters (float fields, identified
    like the others): the ``spread`` s of the pinning fields, and whatever a subclass
    adds; ``cells`` N (static)."""

    #: Its own parameters (fields of the form), with their units.
    own_parameters: ClassVar[dict] = {"spread": "1"}
    #: The magnetization at the samples does not depend on the substeps (the cells are
    #: exact along each interval; the substeps only place points for the structure).
    exact_in_substeps: ClassVar[bool] = True

    spread: eqx.AbstractVar[Real]  # s: the log-normal width of the pinning fields (1)
    cells: eqx.AbstractVar[int]  # N: the number of pinning cells (static)

    @abc.abstractmethod
    def reversible_width(self, p: Parameters):
        """a_r: the width of the reversible part's Langevin function (A/m)."""

    @abc.abstractmethod
    def own_bounds(self, bounds) -> dict:
        """The default box {name: (lower, upper)} of its own parameters, given the box
        (`Bounds`) of the ten."""

    @property
    def parameters(self) -> tuple[str, ...]:
        """Parameters the form depends on (`Parameters` fields, then its own)."""
        return ("Ms", "a", "k", "alpha", "c", *self.own_parameters)

    def path_form(self, driver: str = "H", end_slope_here: bool = False) -> PlayPath:
        """The time-loop form for the driver ``H``, ``B`` or ``M`` (every interval
        reports its own end slope)."""
        return PlayPath(self.cells, driver, self.parameters)

    def loop_parameters(self, p: Parameters):
        """The time loop's parameters: ``(p, self)``."""
        return (p, self)

    def irreversible_magnetization(self, H, M, p: Parameters):
        """The cells' part of M (A/m): M − c·Ms·L(He/a_r)."""
        a_r = self.reversible_width(p)
        return M - p.c * p.Ms * langevin_and_slope((H + p.alpha * M) / a_r)[0]


def _check_spread(spread):
    if is_concrete(spread):
        s = np.asarray(spread, dtype=np.float64)
        if not (np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(s <= 10)):
            raise ValueError(f"spread must lie in [0, 10] (the log-normal width of the "
                             f"pinning fields); got {shown_value(spread)}.")
    return jnp.asarray(spread, dtype=jnp.float64)


def _check_cells(cells) -> int:
    if isinstance(cells, bool) or not isinstance(cells, (int, np.integer)) or \
            not 1 <= int(cells) <= MAX_CELLS:
        raise ValueError(f"cells must be an integer in [1, {MAX_CELLS}]; got {cells!r}.")
    return int(cells)


#: The default box of the spread in identification.
SPREAD_BOX = (0.05, 3.0)


class PlayJA(AbstractPlayForm):
    """Pinning cells with one Langevin anhysteretic for every cell and the reversible
    part: the energy-based, dry-friction model of Bergqvist and Henrotte et al. in
    scalar form (module docstring). ``spread`` s (1), ``cells`` N."""

    spread: Real
    cells: int = eqx.field(static=True, default=16)

    def __init__(self, spread=1.0, cells: int = 16):
        self.spread = _check_spread(spread)
        self.cells = _check_cells(cells)

    def reversible_width(self, p: Parameters):
        return jnp.asarray(p.a)

    def own_bounds(self, bounds) -> dict:
        return {"spread": SPREAD_BOX}


class PreisachJA(AbstractPlayForm):
    """The moving Preisach model of the module docstring: log-normal coercive fields
    (k, ``spread`` s), Langevin-shaped interaction fields of width a, and a reversible
    component of its own width ``a_rev`` (A/m). ``cells`` N."""

    spread: Real
    a_rev: Real
    cells: int = eqx.field(static=True, default=16)
    own_parameters: ClassVar[dict] = {"spread": "1", "a_rev": "A/m"}

    def __init__(self, spread=1.0, a_rev=30.0, cells: int = 16):
        self.spread = _check_spread(spread)
        if is_concrete(a_rev):
            v = np.asarray(a_rev, dtype=np.float64)
            if not (np.all(np.isfinite(v)) and np.all(v >= 1e-6) and np.all(v <= 1e9)):
                raise ValueError(f"a_rev must lie in [1e-6, 1e9] A/m (the reversible "
                                 f"component's Langevin width); got {shown_value(a_rev)}.")
        self.a_rev = jnp.asarray(a_rev, dtype=jnp.float64)
        self.cells = _check_cells(cells)

    def reversible_width(self, p: Parameters):
        return self.a_rev

    def own_bounds(self, bounds) -> dict:
        lo, hi = float(bounds.lower.a), float(bounds.upper.a)
        return {"spread": SPREAD_BOX, "a_rev": (lo, hi)}

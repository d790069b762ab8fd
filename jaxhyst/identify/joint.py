"""Joint identification of several loops, and magnetization-only (B–H / M–H) problems.

A `JointProblem` fits L loops (different amplitudes, frequencies, drives) of one material
at once. Each parameter is either **shared** by all loops, **per loop** (one value per
loop: the paper's Table 3 identifies the JA parameters per frequency while Ms, E, Kz, Mz
and Cz are common), or **fixed**. The loops are padded to a common length — in front
with H = 0 (the demagnetized state does not move while H stays 0), at the end by holding
the last field value — so that one ``jax.vmap`` over loops evaluates them all; a static
mask drops the padding from the residuals. Each loop's residuals are normalised by its
own max|data|, so small loops count as much as large ones.

A `JointProblem` offers what the solvers, the hybrid driver and the identifiability
analysis use (``residuals``, ``cost_u``, ``predict_free``, ``space``...), so `solve`,
`multistart`, `run_hybrid` and `identifiability` work on it unchanged. Its parameters are
a batched `Parameters` with leaves of shape (L,).

`loop_problem` builds the common single-loop magnetization-only problem: an observed
B(H) or M(H) loop as field samples (no time axis, no structure: the JA model is rate
independent), with the initial sweep from the demagnetized state handled by
`drive_from_record`.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..actuator import Actuator
from ..drive import Drive, drive_from_record
from ..model.jiles_atherton import JAVariant
from ..model.simulate import DEFAULT_SUBSTEPS, PAPER_VARIANT, simulate_unchecked
from ..params import NAMES, Bounds, Parameters
from ..sharding import batch_sharding, map_sharded
from .problem import OUTPUTS, ParameterSpace, Problem, u_from_z, z_from_u

#: Parameters that only the structure and magnetostriction see: irrelevant (and so fixed)
#: when the observed output is M or B.
STRUCTURAL = ("lambda_s", "E", "Kz", "Mz", "Cz")
#: The actuator of a magnetization-only problem (its geometry never enters M or B).
NO_ACTUATOR = Actuator(Ar=1.0, lr=1.0, name="none (magnetization only)")


def fix_structural(bounds: Bounds, fixed: dict | None = None) -> dict:
    """``fixed`` plus the `STRUCTURAL` parameters not already in it, at their box centre:
    for M or B data they are irrelevant, and left free they would be null directions."""
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    out = dict(fixed or {})
    for n in STRUCTURAL:
        out.setdefault(n, 0.5 * (lo[n] + hi[n]))
    return out


class JointSpace(eqx.Module):
    """Free parameters of L loops: shared, per loop, or fixed.

    **Arguments:**
    - ``bounds``: `Bounds` of the ten parameters (per-loop copies share them).
    - ``n_loops``: L.
    - ``per_loop``: names free separately in every loop.
    - ``fixed``: ``{name: value}`` (same value in every loop) or ``{name: [v_0 … v_L-1]}``.

    Free entries are named ``Ms`` (shared) or ``a[2]`` (loop 2), in that order: the shared
    ones in `NAMES` order, then each per-loop name for loop 0 … L-1.
    """

    lower: jax.Array
    upper: jax.Array
    base: jax.Array  # (L, 10) values of the fixed entries
    index: tuple = eqx.field(static=True)  # (L, 10) position in the free vector, or -1
    names: tuple = eqx.field(static=True)

    def __init__(self, bounds: Bounds, n_loops: int, per_loop: Sequence[str] = (),
                 fixed: dict | None = None):
        fixed = dict(fixed or {})
        per_loop = tuple(per_loop)
        bad = [n for n in (*per_loop, *fixed) if n not in NAMES]
        if bad:
            raise ValueError(f"Unknown parameter(s) {bad}; names are {list(NAMES)}.")
        both = sorted(set(per_loop) & set(fixed))
        if both:
            raise ValueError(f"{both} cannot be both per-loop and fixed.")
        if int(n_loops) < 1:
            raise ValueError("A joint problem needs at least one loop.")
        L = int(n_loops)
        lo = np.asarray(bounds.lower.to_array())
        hi = np.asarray(bounds.upper.to_array())
        base = np.tile(0.5 * (lo + hi), (L, 1))
        for n, v in fixed.items():
            v = np.broadcast_to(np.asarray(v, dtype=float), (L,))
            if not np.all(np.isfinite(v)):
                raise ValueError(f"Fixed value of {n} is not finite.")
            base[:, NAMES.index(n)] = v
        index = -np.ones((L, len(NAMES)), dtype=int)
        names, lower, upper = [], [], []
        for j, n in enumerate(NAMES):
            if n not in fixed and n not in per_loop:
                index[:, j] = len(names)
                names.append(n)
                lower.append(lo[j])
                upper.append(hi[j])
        for n in per_loop:
            j = NAMES.index(n)
            for l_ in range(L):
                index[l_, j] = len(names)
                names.append(f"{n}[{l_}]")
                lower.append(lo[j])
                upper.append(hi[j])
        if not names:
            raise ValueError("Every parameter is fixed: there is nothing to identify.")
        self.lower = jnp.asarray(lower)
        self.upper = jnp.asarray(upper)
        self.base = jnp.asarray(base)
        self.index = tuple(map(tuple, index.tolist()))
        self.names = tuple(names)

    @property
    def n_loops(self) -> int:
        return len(self.index)

    @property
    def n_free(self) -> int:
        return len(self.names)

    @property
    def free(self) -> tuple:
        """Hashable description of the free set (for checkpoints' fingerprints)."""
        return self.names

    def theta_from_free(self, x) -> jax.Array:
        """All ten SI values per loop, shape (..., L, 10), from free values x (..., n)."""
        x = jnp.asarray(x)
        idx = np.asarray(self.index)
        gathered = jnp.take(x, jnp.asarray(np.maximum(idx, 0)), axis=-1)  # (..., L, 10)
        return jnp.where(jnp.asarray(idx >= 0), gathered, self.base)

    def params_from_free(self, x) -> Parameters:
        return Parameters.from_array(self.theta_from_free(x))

    def theta_from_u(self, u) -> jax.Array:
        return self.theta_from_free(self.lower + (self.upper - self.lower) * u)

    def params_from_u(self, u) -> Parameters:
        return Parameters.from_array(self.theta_from_u(u))

    def params_from_z(self, z) -> Parameters:
        return self.params_from_u(u_from_z(z))

    def free_values(self, params: Parameters) -> jax.Array:
        """Free values from `Parameters` with leaves (L,) (or scalars: the same in every
        loop). A shared parameter is read from the last loop (its values should agree).
        Traceable (static gather), so it works inside jit/vmap."""
        theta = jnp.broadcast_to(params.to_array(), (self.n_loops, len(NAMES)))
        idx = np.asarray(self.index)
        sel = idx >= 0
        return jnp.zeros(self.n_free, theta.dtype).at[idx[sel]].set(theta[sel])

    def u_from_params(self, params: Parameters) -> jax.Array:
        width = jnp.where(self.upper > self.lower, self.upper - self.lower, 1.0)
        return jnp.clip((self.free_values(params) - self.lower) / width, 0.0, 1.0)

    def z_from_params(self, params: Parameters) -> jax.Array:
        return z_from_u(self.u_from_params(params))


def _pad_drives(drives: Sequence[Drive]):
    """Stack drives to one batched `Drive` with a common run-in R and length: front
    padding with H = 0, end padding holding the last value; per-loop observed mask."""
    R = max(d.run_in for d in drives)
    n_obs = max(d.n_observed for d in drives)
    ts, Hs, mask = [], [], np.zeros((len(drives), n_obs), bool)
    for i, d in enumerate(drives):
        t, H = np.asarray(d.t), np.asarray(d.H)
        dt = float(np.mean(np.diff(t)))
        front, back = R - d.run_in, n_obs - d.n_observed
        if front and H[0] != 0.0:
            raise ValueError(f"Loop {i}: its drive must start at H = 0 (demagnetized) to be "
                             "padded; build it with drive_from_record or sinusoidal_*.")
        t = np.concatenate([t[0] - dt * np.arange(front, 0, -1), t,
                            t[-1] + dt * np.arange(1, back + 1)])
        H = np.concatenate([np.zeros(front), H, np.full(back, H[-1])])
        ts.append(t)
        Hs.append(H)
        mask[i, : d.n_observed] = True
    # each loop keeps its own time step (t is data); the batch is uniform if every loop is
    uniform = all(d.uniform for d in drives)
    batched = [Drive(t, H, run_in=R, uniform=uniform) for t, H in zip(ts, Hs, strict=True)]
    drive = jax.tree.map(lambda *xs: jnp.stack(xs), *batched)
    return drive, mask


class JointProblem(eqx.Module):
    """Several loops of one material fitted as one problem (see the module docstring).

    **Arguments:**
    - ``data``: one observed signal per loop (each aligned with its drive's observed
      samples), in the unit of ``output``.
    - ``drives``: one `Drive` per loop (`drive_from_record`, `sinusoidal_field`...).
    - ``actuator``, ``output``, ``variant``, ``substeps``: as in `Problem` (common).
    - ``space``: a `JointSpace` for L = len(data) loops.
    - ``shard_loops``: spread the loops over all devices (`jaxhyst.sharding.map_sharded`):
      each device simulates its share of the loops, so that one local solve can use
      several devices. ``True`` needs L to be a multiple of the device count (and does
      nothing on one device). Measured on 2 CPU host devices: a 2-loop joint LM solve
      1.6× faster, same result (`benchmarks/bench_sharding.py`). Opt-in (default
      ``False``) because a GA on such a problem would split the loops *and* its
      population over the same devices, which we have not measured.
    """

    data: jax.Array  # (N,) valid samples of all loops, concatenated
    padded: jax.Array  # (L, n_obs)
    drive: Drive  # batched: leaves (L, T)
    actuator: Actuator
    space: JointSpace
    sample_scale: jax.Array  # (N,) max|data| of each sample's loop
    mask: tuple = eqx.field(static=True)
    scale: float = eqx.field(static=True)
    output: str = eqx.field(static=True, default="displacement")
    variant: JAVariant = PAPER_VARIANT
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    shard_loops: bool = eqx.field(static=True, default=False)

    def __init__(self, data: Sequence, drives: Sequence[Drive], actuator: Actuator,
                 space: JointSpace, output: str = "displacement",
                 variant: JAVariant = PAPER_VARIANT, substeps: int = DEFAULT_SUBSTEPS,
                 shard_loops: bool = False):
        if output not in OUTPUTS:
            raise ValueError(f"Unknown output {output!r}; choose one of {list(OUTPUTS)}.")
        if len(data) != len(drives) or len(data) != space.n_loops:
            raise ValueError(f"{len(data)} data sets, {len(drives)} drives and a space for "
                             f"{space.n_loops} loops: give one drive per loop.")
        # validate each loop exactly as a single-loop problem would
        single = ParameterSpace(Bounds(Parameters.from_array(space.base[0]),
                                       Parameters.from_array(space.base[0])))
        scales = []
        for i, (y, d) in enumerate(zip(data, drives, strict=True)):
            try:
                scales.append(Problem(y, d, actuator, single, output=output).scale)
            except ValueError as err:
                raise ValueError(f"Loop {i}: {err}") from None
        drive, mask = _pad_drives(drives)
        padded = np.zeros(mask.shape)
        for i, y in enumerate(data):
            padded[i, : len(y)] = np.asarray(y, dtype=float)
        self.drive = drive
        self.mask = tuple(map(tuple, mask.tolist()))
        self.padded = jnp.asarray(padded)
        self.data = jnp.asarray(padded[mask])
        self.sample_scale = jnp.asarray(np.broadcast_to(np.asarray(scales)[:, None],
                                                        mask.shape)[mask])
        self.scale = float(max(scales))
        self.actuator = actuator
        self.space = space
        self.output = output
        self.variant = variant
        self.substeps = int(substeps)
        try:
            self.shard_loops = bool(shard_loops) and batch_sharding(len(data), True) is not None
        except ValueError:
            raise ValueError(f"shard_loops=True: {len(data)} loops cannot be split evenly over "
                             f"{jax.device_count()} devices; use a multiple of the device "
                             "count or shard_loops=False.") from None

    @property
    def n_loops(self) -> int:
        return len(self.mask)

    @property
    def unit(self) -> str:
        return OUTPUTS[self.output][0]

    def simulate(self, params: Parameters):
        """Per-loop `Simulation` (leaves (L, T)) for `Parameters` with leaves (L,)."""
        def loops(params, drive):
            return jax.vmap(simulate_unchecked, in_axes=(0, None, 0, None, None))(
                params, self.actuator, drive, self.variant, self.substeps)

        return map_sharded(loops, self.n_loops, self.shard_loops)(params, self.drive)

    def predict_loops(self, params: Parameters) -> jax.Array:
        """Model output per loop, (L, n_obs) (padding included)."""
        sim = self.simulate(params)
        return OUTPUTS[self.output][1](sim)[:, self.drive.run_in:]

    def predict(self, params: Parameters) -> jax.Array:
        """Model output at the valid samples of all loops, concatenated (N,)."""
        return self.predict_loops(params)[np.asarray(self.mask)]

    def predict_free(self, x) -> jax.Array:
        return self.predict(self.space.params_from_free(x))

    def residuals_u(self, u) -> jax.Array:
        r = (self.predict(self.space.params_from_u(u)) - self.data) / self.sample_scale
        return r / np.sqrt(self.data.shape[0])

    def residuals(self, z, args=None) -> jax.Array:
        del args
        return self.residuals_u(u_from_z(z))

    def cost_u(self, u) -> jax.Array:
        return jnp.sum(self.residuals_u(u) ** 2)

    def cost(self, z) -> jax.Array:
        return self.cost_u(u_from_z(z))

    def fitness_from_cost(self, cost, c1: float = 1e-30) -> jax.Array:
        """F = 1/√(c1 + E) with E = cost·scale²·N, scale the largest loop's max|data|."""
        E = cost * self.scale**2 * self.data.shape[0]
        return jnp.where(jnp.isfinite(E), 1.0 / jnp.sqrt(c1 + E), 0.0)


def loop_problem(H, data, bounds: Bounds, *, output: str = "flux_density", t=None,
                 fixed: dict | None = None, variant: JAVariant = PAPER_VARIANT,
                 substeps: int = 8, from_demagnetized: bool = False,
                 run_in_periods: int = 1) -> Problem:
    """A magnetization-only problem from one measured loop.

    **Arguments:**
    - ``H``: field samples, A/m, in the order measured (one or more closed loops).
    - ``data``: B (T) for ``output="flux_density"`` or M (A/m) for ``"magnetization"``.
    - ``t``: sample times (s) or ``None`` (the JA model is rate independent).
    - ``fixed``: parameters to hold; λs, E, Kz, Mz, Cz never affect M or B and are
      always fixed (at their box centre unless given).
    - ``from_demagnetized``: the record itself starts from the demagnetized state at
      H = 0 (it contains the initial curve), so it is fitted from its first sample with
      no ramp or run-in; otherwise a ramp from H = 0 and ``run_in_periods`` copies of the
      (closed) loop precede it.
    - ``substeps``: RK4 substeps per sample (default 8: measured loops are often coarse
      compared with a, the width of the anhysteretic).
    """
    if output not in ("flux_density", "magnetization"):
        raise ValueError("loop_problem observes magnetization or flux_density; use Problem "
                         "for displacement or strain.")
    H = np.asarray(H, dtype=float)
    if from_demagnetized:
        if abs(H[0]) > 1e-12 * max(np.max(np.abs(H)), 1.0):
            raise ValueError("from_demagnetized=True needs the record to start at H = 0.")
        tt = np.arange(H.shape[0], dtype=float) if t is None else np.asarray(t, float)
        drive = Drive(tt, H)
    else:
        drive = drive_from_record(t, H, run_in_periods=run_in_periods)
    return Problem(data, drive, NO_ACTUATOR,
                   ParameterSpace(bounds, fix_structural(bounds, fixed)), output=output,
                   variant=variant, substeps=substeps)

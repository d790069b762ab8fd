"""Joint identification of several loops, and magnetization-only (B–H / M–H) problems.

A `JointProblem` fits L loops (different amplitudes, frequencies, drives) of one material
at once. Each parameter is either **shared** by all loops, **per loop** (one value per
loop: the paper's Table 3 identifies the JA parameters per frequency while Ms, E, Kz, Mz
and Cz are common), or **fixed**. The loops are padded to a common length — in front
with H = 0 (the demagnetized state does not move while H stays 0), at the end by holding
the last field value — so that one ``jax.vmap`` over loops evaluates them all; a mask
that is data (``valid``) zeroes the padding's residuals and every statistic counts only
the observed samples. ``pad_to`` pads further, to a common shape: the problems of a
leave-one-out (each loop alone, each fold) padded to the file's longest loop share one
compiled program however unequal the loops' lengths. Each loop's residuals are normalised by its
own max|data|, so small loops count as much as large ones.

A `JointProblem` implements the problem protocol (`AbstractProblem`; one residual
group per loop), so every solver, the GA and the analyses work on it unchanged. Its
parameters are a `Parameters` with leaves of shape (L,); each loop may observe its own
output.

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

from ..actuator import MAGNETIZATION_ONLY, Actuator
from ..drive import Drive, drive_from_record, require_times_for
from ..model.paths import split_parameters
from ..model.simulate import DEFAULT_SUBSTEPS, PAPER_VARIANT, simulate_unchecked
from ..names import checked_substeps
from ..params import STRUCTURAL, Bounds
from ..saved import Model
from ..sharding import batch_sharding, map_sharded
from .outputs import output_kind
from .problem import AbstractProblem, GaussianPrior, ResidualGroup
from .signal import Problem
from .space import JointSpace, ParameterSpace

__all__ = ["JointProblem", "JointSpace", "NO_ACTUATOR", "STRUCTURAL", "fix_structural",
           "loop_problem"]

# STRUCTURAL (from params): irrelevant, and so fixed, when the observed output is M or B.
#: The actuator of a magnetization-only problem (its geometry never enters M or B).
NO_ACTUATOR = Actuator(Ar=1.0, lr=1.0, name=MAGNETIZATION_ONLY)


def fix_structural(bounds: Bounds, fixed: dict | None = None) -> dict:
    """``fixed`` plus the `STRUCTURAL` parameters not already in it, at their box centre:
    for M or B data they are irrelevant, and left free they would be null directions."""
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    out = dict(fixed or {})
    for n in STRUCTURAL:
        out.setdefault(n, 0.5 * (lo[n] + hi[n]))
    return out


def common_shape(drives) -> tuple[int, int]:
    """(run-in, observed samples) of the longest of ``drives`` (`Drive`s or
    `FluxDrive`s): what `pad_drives` pads them to."""
    return max(d.run_in for d in drives), max(d.n_observed for d in drives)


def _padded_samples(drive, run_in: int, n_observed: int):
    """(t, x) of ``drive`` (x: a `Drive`'s H or a `FluxDrive`'s B) with x = 0 in front up
    to ``run_in`` run-in samples (times stepping back by its mean step) and its last value
    held to ``n_observed`` observed samples; ValueError where it needs front padding and
    does not start at 0."""
    t, name = np.asarray(drive.t), "B" if hasattr(drive, "B") else "H"
    x = np.asarray(getattr(drive, name))
    dt = float(np.mean(np.diff(t)))
    front, back = run_in - drive.run_in, n_observed - drive.n_observed
    if front and x[0] != 0.0:
        raise ValueError(f"its drive must start at {name} = 0 (demagnetized) to be padded; "
                         "build it with drive_from_record, flux_from_record or "
                         "sinusoidal_*.")
    t = np.concatenate([t[0] - dt * np.arange(front, 0, -1), t,
                        t[-1] + dt * np.arange(1, back + 1)])
    return t, np.concatenate([np.zeros(front), x, np.full(back, x[-1])])


def pad_drive(drive, pad_to):
    """``drive`` (a `Drive` or a `FluxDrive`) padded as a joint problem pads its loops, to
    at least ``pad_to`` = (run-in, observed samples): one compiled simulation then serves
    drives of several lengths, its observed samples ``[run_in : run_in +
    drive.n_observed]``. A drive that cannot be padded in front (it does not start at 0)
    is returned as it is."""
    run_in, n_observed = max(drive.run_in, int(pad_to[0])), max(drive.n_observed,
                                                                 int(pad_to[1]))
    try:
        t, x = _padded_samples(drive, run_in, n_observed)
    except ValueError:
        return drive
    return type(drive)(t, x, run_in=run_in, uniform=drive.uniform, timed=drive.timed)


def pad_drives(drives: Sequence, pad_to=None):
    """Stack drives (all `Drive`s or all `FluxDrive`s) to one batched drive with a common
    run-in R and length (at least ``pad_to`` = (run-in, observed samples) where given):
    front padding with 0, end padding holding the last value; per-loop observed mask."""
    R, n_obs = common_shape(drives)
    if pad_to is not None:
        R, n_obs = max(R, int(pad_to[0])), max(n_obs, int(pad_to[1]))
    padded, mask = [], np.zeros((len(drives), n_obs), bool)
    for i, d in enumerate(drives):
        try:
            padded.append(_padded_samples(d, R, n_obs))
        except ValueError as err:
            raise ValueError(f"Loop {i}: {err}") from None
        mask[i, : d.n_observed] = True
    # each loop keeps its own time step (t is data); the batch is uniform if every loop is
    uniform, timed = all(d.uniform for d in drives), all(d.timed for d in drives)
    batched = [type(drives[0])(t, x, run_in=R, uniform=uniform, timed=timed)
               for t, x in padded]
    drive = jax.tree.map(lambda *xs: jnp.stack(xs), *batched)
    return drive, mask


class JointProblem(AbstractProblem):
    """Several loops of one material fitted as one problem (see the module docstring).

    **Arguments:**
    - ``data``: one observed signal per loop (each aligned with its drive's observed
      samples), in the unit of that loop's output.
    - ``drives``: one `Drive` per loop (`drive_from_record`, `sinusoidal_field`...).
    - ``actuator``, ``variant``, ``substeps``: as in `Problem` (common).
    - ``output``: one output name for every loop, or one per loop (displacement on one
      drive and strain on another).
    - ``space``: `ParameterSpace.for_loops` (`JointSpace`) for L = len(data) loops.
    - ``sigma``: noise level per loop (a number for all, a sequence, or None: estimated);
      ``priors``: `GaussianPrior` terms (need sigma).
    - ``pad_to``: (run-in, observed samples): pad every loop to at least these lengths
      (the shape of other problems whose programs this one should share; see the module
      docstring). None: to the longest of these loops.
    - ``shard_loops``: spread the loops over all devices (`jaxhyst.sharding.map_sharded`):
      each device simulates its share of the loops, so that one local solve can use
      several devices. ``True`` needs L to be a multiple of the device count (and does
      nothing on one device). Opt-in: a GA on such a problem would split the loops *and*
      its population over the same devices.

    Each loop is one residual group, normalised by its own max|data| (or its sigma), so
    small loops count as much as large ones.
    """

    padded: jax.Array  # (L, n_obs): the observations, 0 in the padding
    valid: jax.Array  # (L, n_obs) bool: observed samples (data: lengths do not recompile)
    drive: Drive  # batched: leaves (L, T)
    actuator: Actuator
    space: ParameterSpace
    scales: jax.Array  # (L,) max|data| of each loop (data: a new data set does not recompile)
    outputs: tuple = eqx.field(static=True)
    sigmas: tuple  # (per loop: None, or its σ as an array: a new value does not recompile)
    variant: eqx.Module = PAPER_VARIANT  # (a model form)
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    shard_loops: bool = eqx.field(static=True, default=False)
    priors: tuple = eqx.field(static=True, default=())

    def __init__(self, data: Sequence, drives: Sequence[Drive], actuator: Actuator,
                 space: ParameterSpace, output: str | Sequence[str] = "displacement",
                 variant=PAPER_VARIANT, substeps: int = DEFAULT_SUBSTEPS,
                 shard_loops: bool = False, sigma=None,
                 priors: Sequence[GaussianPrior] = (), pad_to=None):
        if isinstance(drives, Drive):
            raise TypeError("give the loops' drives as a list, one jaxhyst.Drive per loop "
                            "([drive] for one), and their data likewise ([y]).")
        L = len(data)
        outputs = (output,) * L if isinstance(output, str) else tuple(output)
        outputs = tuple(output_kind(o).name for o in outputs)
        if len(outputs) != L:
            raise ValueError(f"{len(outputs)} outputs for {L} loops: give one per loop.")
        if len(drives) != L or space.n_loops != L:
            raise ValueError(f"{L} data sets, {len(drives)} drives and a space for "
                             f"{space.n_loops} loops: give one drive per loop (and a "
                             "space from ParameterSpace.for_loops).")
        require_times_for(space, drives)
        sigmas = (sigma,) * L if sigma is None or np.ndim(sigma) == 0 else tuple(sigma)
        if len(sigmas) != L:
            raise ValueError(f"{len(sigmas)} noise levels for {L} loops.")
        # validate each loop exactly as a single-loop problem would
        single = ParameterSpace(space_bounds_of_loop(space))
        scales = []
        for i, (y, d) in enumerate(zip(data, drives, strict=True)):
            try:
                scales.append(Problem(y, d, actuator, single, output=outputs[i],
                                      substeps=substeps).scale)
            except ValueError as err:
                raise ValueError(f"Loop {i}: {err}") from None
        if pad_to is not None and not (
                np.shape(pad_to) == (2,) and all(isinstance(v, (int, np.integer)) and v >= 0
                                                 for v in pad_to)):
            raise ValueError(f"pad_to={pad_to!r}: give (run-in, observed samples), two whole "
                             "numbers >= 0, or None to pad to the longest loop.")
        drive, mask = pad_drives(drives, pad_to)
        padded = np.zeros(mask.shape)
        for i, y in enumerate(data):
            padded[i, : len(y)] = np.asarray(y, dtype=float)
        self.drive = drive
        self.valid = jnp.asarray(mask)
        self.padded = jnp.asarray(padded)
        self.scales = jnp.asarray(scales, dtype=jnp.float64)
        self.outputs = outputs
        self.sigmas = tuple(None if s is None else jnp.asarray(float(s), dtype=jnp.float64)
                            for s in sigmas)
        self.actuator = actuator
        self.space = space
        self.variant = variant
        self.substeps = checked_substeps(substeps)
        self.priors = tuple(priors)
        try:
            self.shard_loops = bool(shard_loops) and batch_sharding(L, True) is not None
        except ValueError:
            raise ValueError(f"shard_loops=True: {L} loops cannot be split evenly over "
                             f"{jax.device_count()} devices; use a multiple of the device "
                             "count or shard_loops=False.") from None
        self._check_priors()

    @property
    def n_loops(self) -> int:
        return self.padded.shape[0]

    @property
    def mask(self) -> np.ndarray:
        """(L, n_obs) bool: the observed samples (host; the problem must be concrete)."""
        return np.asarray(self.valid, bool)

    @property
    def data(self) -> np.ndarray:
        """(N,) the observed samples of all loops, concatenated (host)."""
        return np.asarray(self.padded)[self.mask]

    @property
    def output(self) -> str:
        """The common output (or ``"mixed"`` when loops observe different outputs)."""
        return self.outputs[0] if len(set(self.outputs)) == 1 else "mixed"

    @property
    def unit(self) -> str:
        units = {output_kind(o).unit for o in self.outputs}
        return units.pop() if len(units) == 1 else "mixed"

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        n_obs = self.padded.shape[1]
        return tuple(ResidualGroup(f"loop {i} ({o})", n_obs, output_kind(o).unit,
                                   self.sigmas[i], scale=self.scales[i],
                                   data_size=self.scales[i], valid=self.valid[i])
                     for i, o in enumerate(self.outputs))

    def simulate(self, params):
        """Per-loop `Simulation` (leaves (L, T)) for a model's parameters with leaves (L,)
        (`Parameters`, or a tuple with `Losses` and/or the form: `ParameterSpace.for_model`)."""
        def one(params, drive):
            p, losses, form = split_parameters(params)
            return simulate_unchecked(p, self.actuator, drive,
                                      self.variant if form is None else form, self.substeps,
                                      losses)

        def loops(params, drive):
            return jax.vmap(one)(params, drive)

        return map_sharded(loops, self.n_loops, self.shard_loops)(params, self.drive)

    def predict_loops(self, params) -> jax.Array:
        """Model output per loop, (L, n_obs) (padding included), each loop's own output."""
        sim = self.simulate(params)
        kinds = sorted(set(self.outputs))
        out = output_kind(kinds[0]).of(sim)
        for kind in kinds[1:]:  # elementwise per loop (a gather would undo loop sharding)
            this = np.array([o == kind for o in self.outputs])[:, None]
            out = jnp.where(this, output_kind(kind).of(sim), out)
        return out[:, self.drive.run_in:]

    def predict(self, params) -> jax.Array:
        """Model output at the valid samples of all loops, concatenated (N,) (the problem
        concrete: the mask is data; `predict_loops` inside a traced function)."""
        return self.predict_loops(params)[self.mask]

    def predict_valid(self, params) -> jax.Array:
        """Model output per loop, (L, n_obs), 0 in the padding (traceable)."""
        return jnp.where(self.valid, self.predict_loops(params), 0.0)

    def group_residuals(self, params) -> tuple:
        """Per loop, model − data over its padded length, 0 in the padding (``valid``)."""
        e = jnp.where(self.valid, self.predict_loops(params) - self.padded, 0.0)
        return tuple(e[i] for i in range(self.n_loops))

    def model(self, params) -> Model:
        """The identified model at ``params`` (this problem's actuator, form and
        substeps), to simulate other drives or save (`jaxhyst.save_model`)."""
        p, losses, form = split_parameters(params)
        return Model(p, self.actuator, self.variant if form is None else form,
                     self.substeps, losses)

    @property
    def observations(self):
        """The observations, (L, n_obs), padding included (its values are never used)."""
        return self.padded

    def with_data(self, data) -> JointProblem:
        """This problem with other observations: (L, n_obs) like `observations`, or the
        observed samples of all loops concatenated, (N,) (the problem concrete)."""
        data = jnp.asarray(data, dtype=jnp.float64)
        if data.shape != self.padded.shape:
            mask = self.mask
            if data.shape != (int(mask.sum()),):
                raise ValueError(f"with_data: data of shape {data.shape}; give "
                                 f"{self.padded.shape} (loops × padded samples) or "
                                 f"({int(mask.sum())},) (the observed samples).")
            data = jnp.zeros_like(self.padded).at[mask].set(data)
        return eqx.tree_at(lambda q: q.padded, self, jnp.where(self.valid, data, 0.0))


def space_bounds_of_loop(space: ParameterSpace) -> Bounds:
    """`Bounds` whose values are a joint space's first loop's base values (lower =
    upper): only used to validate each loop's data as a single-loop problem."""
    from ..params import NAMES, Parameters

    L = space.n_loops
    base = np.asarray(space.base).reshape(-1, L)[:len(NAMES), 0]
    p = Parameters.from_array(jnp.asarray(base))
    return Bounds(p, p)


def loop_problem(H, data, bounds: Bounds | dict | None = None, *,
                 output: str = "flux_density", t=None, fixed: dict | None = None,
                 variant=PAPER_VARIANT, substeps: int = DEFAULT_SUBSTEPS,
                 from_demagnetized: bool = False, run_in_periods: int = 1,
                 monotone_field: bool = True, require_full_period: bool = True) -> Problem:
    """A magnetization-only problem from one measured loop.

    **Arguments:**
    - ``H``: field samples, A/m, in the order measured (one or more closed loops, starting
      anywhere; noisy or digitized).
    - ``data``: B (T) for ``output="flux_density"`` or M (A/m) for ``"magnetization"``.
    - ``bounds``: `Bounds`; or ``None`` for the box derived from the loop
      (`jaxhyst.identify.measured.default_loop_bounds`), or a dict ``{name: (lower,
      upper)}`` changing only those parameters of it.
    - ``t``: sample times (s) or ``None`` (the JA model is rate independent).
    - ``fixed``: parameters to hold; λs, E, Kz, Mz, Cz never affect M or B and are
      always fixed (at their box centre unless given).
    - ``from_demagnetized``: the record itself starts from the demagnetized state at
      H = 0 (it contains the initial curve), so it is fitted from its first sample with
      no ramp or run-in; otherwise a ramp from H = 0 and ``run_in_periods`` copies of the
      (closed) loop precede it.
    - ``monotone_field``: replace field reversals smaller than 5 % of the range (noise of
      the measurement or the digitizer) by the monotone least-squares fit of each branch
      (`jaxhyst.identify.measured.monotone_branches`); the data are not changed.
    - ``substeps``: RK4 substeps per sample (the package default; a `SamplingWarning`
      says when the record is too coarse for it).
    - ``require_full_period``: refuse a record that holds no loop (see `Problem`).
    """
    from .measured import loop_bounds, monotone_branches

    if not output_kind(output).magnetic_only:
        raise ValueError("loop_problem observes magnetization or flux_density; use Problem "
                         "for displacement or strain.")
    H = np.asarray(H, dtype=float)
    if H.ndim != 1 or np.shape(data) != H.shape:
        raise ValueError(f"H and data must be 1-D of equal length; got shapes {H.shape} and "
                         f"{np.shape(data)}.")
    bounds = loop_bounds(H, np.asarray(data, float), output, bounds)
    H_model = monotone_branches(H) if monotone_field else H
    if from_demagnetized:
        if abs(H[0]) > 1e-12 * max(np.max(np.abs(H)), 1.0):
            raise ValueError("from_demagnetized=True needs the record to start at H = 0.")
        tt = np.arange(H.shape[0], dtype=float) if t is None else np.asarray(t, float)
        drive = Drive(tt, H_model, timed=t is not None)
    else:
        drive = drive_from_record(t, H_model, run_in_periods=run_in_periods)
    return Problem(data, drive, NO_ACTUATOR,
                   ParameterSpace(bounds, fix_structural(bounds, fixed)), output=output,
                   variant=variant, substeps=substeps,
                   require_full_period=require_full_period)

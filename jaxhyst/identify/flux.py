"""B-driven identification: `FluxProblem`, the magnetic parameters (and the loss
coefficients of the rate-dependent model) from records of the flux density B(t) with
either the measured field H(t) or the measured energy per cycle ∮ H dB (the core loss
per volume divided by the frequency).

Each record is one `FluxDrive`; records of different lengths are padded to a common one
as a `jaxhyst.JointProblem`'s loops are (B = 0 in front, the last B held at the end, a
mask that is data), and simulated in one ``jax.vmap``. The parameter
pytree is `Parameters` (the static model) or ``(Parameters, Losses)``
(`ParameterSpace.with_losses`), shared by all records, or with leaves of shape (L,) for
one value per record (a space from `ParameterSpace.for_loops`, or the
condition-dependent parameters of `jaxhyst.identify.conditions`).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..drive import require_times_for
from ..model.flux import FluxDrive, simulate_flux_unchecked
from ..model.jiles_atherton import PAPER_VARIANT
from ..model.paths import split_parameters
from ..names import DEFAULT_SUBSTEPS, base_name, checked_substeps
from .joint import pad_drives
from .problem import AbstractProblem, GaussianPrior, ResidualGroup
from .space import ParameterSpace

#: What a `FluxProblem` observes: name → unit of its data.
FLUX_OUTPUTS = {"field": "A/m", "cycle_energy": "J/m^3"}


def stack_flux_drives(drives: Sequence[FluxDrive], pad_to=None) -> FluxDrive:
    """One `FluxDrive` with leaves (L, T) from L drives, padded as a `JointProblem` pads
    its loops (`jaxhyst.identify.joint.pad_drives`: B = 0 in front to the longest run-in,
    the last B held to the longest record, or to ``pad_to`` = (run-in, observed samples)
    where longer); `FluxProblem.valid` marks each record's observed samples."""
    return _stacked(drives, pad_to)[0]


def _stacked(drives, pad_to):
    drives = None if isinstance(drives, FluxDrive) else list(drives)
    if not drives or not all(isinstance(d, FluxDrive) for d in drives):
        raise TypeError("give the records' drives as a list, one jaxhyst.FluxDrive per "
                        "record ([drive] for one; flux_from_period, flux_from_record, "
                        "sinusoidal_flux …), and their data likewise ([H]).")
    if pad_to is not None and not (
            np.shape(pad_to) == (2,) and all(isinstance(v, (int, np.integer)) and v >= 0
                                             for v in pad_to)):
        raise ValueError(f"pad_to={pad_to!r}: give (run-in, observed samples), two whole "
                         "numbers >= 0, or None to pad to the longest record.")
    if pad_to is None and len({(d.n_samples, d.run_in) for d in drives}) == 1:
        uniform, timed = all(d.uniform for d in drives), all(d.timed for d in drives)
        drives = [d if (d.uniform, d.timed) == (uniform, timed) else  # (one structure)
                  FluxDrive(d.t, d.B, d.run_in, uniform, timed) for d in drives]
        return (jax.tree.map(lambda *xs: jnp.stack(xs), *drives),
                np.ones((len(drives), drives[0].n_observed), bool))
    try:
        return pad_drives(drives, pad_to)
    except ValueError as err:
        raise ValueError(str(err).replace("Loop", "record", 1)) from None


def _padded_data(data, valid: np.ndarray) -> np.ndarray:
    """The records' field data as (L, n_obs) with 0 in each record's padding, from an
    (L, n_obs) array or one array per record (each its record's observed length)."""
    L, n_obs = valid.shape
    rows = list(data) if not isinstance(data, np.ndarray) or data.ndim == 2 else None
    if rows is None or len(rows) != L:
        return np.asarray(data, dtype=np.float64)  # (the shape check says what is wrong)
    out = np.zeros((L, n_obs))
    for i, row in enumerate(rows):
        row = np.asarray(row, dtype=np.float64)
        n = int(valid[i].sum())
        if row.shape != (n,):
            raise ValueError(f"record {i}: its field data must have one value per observed "
                             f"sample of its drive, shape ({n},); got {row.shape}.")
        out[i, :n] = row
    return out


class FluxProblem(AbstractProblem):
    """Identify from L B-driven records (see the module docstring).

    **Arguments:**
    - ``data``: per record, the measured field H at the drive's observed samples (A/m,
      ``output="field"``) or the measured energy per cycle over its observed part
      (J/m³, ``output="cycle_energy"``: power loss per volume / frequency).
    - ``drives``: one `FluxDrive` per record. Records of different lengths are padded to
      the longest (`stack_flux_drives`; a record must then start at B = 0, as
      `flux_from_record`'s and `flux_from_period`'s do), and ``data`` is then a list of
      one array per record.
    - ``space``: the `ParameterSpace` (`ParameterSpace.with_losses` for the rate-dependent
      model; its structural parameters never enter and are best fixed).
    - ``variant``, ``substeps``: the Jiles–Atherton form and RK4 substeps.
    - ``sigma``, ``priors``: as in `jaxhyst.Problem` (sigma: a number for every record).
    - ``pad_to``: (run-in, observed samples): pad every record to at least these lengths
      (to share the program of other problems, as `jaxhyst.JointProblem`'s).

    Residuals: for ``field``, model − data per record (one group each, normalised by the
    record's max|H|, 0 in its padding: ``valid``); for ``cycle_energy``, the relative
    error model/data − 1 of each record (one group of L), so that records of different
    loss count alike.
    """

    data: jax.Array  # (L, n_obs) field (0 in a record's padding), or (L,) energies
    drive: FluxDrive
    valid: jax.Array  # (L, n_obs) bool: each record's observed samples (data)
    space: ParameterSpace
    output: str = eqx.field(static=True)
    scales: jax.Array  # (L,) max|data| per record (data: new data do not recompile)
    variant: eqx.Module = PAPER_VARIANT  # (a model form)
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    sigma: jax.Array | None = None  # (data: a new σ does not recompile; None: estimated)
    priors: tuple = eqx.field(static=True, default=())
    #: the path with the after-effect (relax free, or fixed > 0 in the space): static
    after_effect: bool = eqx.field(static=True, default=False)

    def __init__(self, data, drives: Sequence[FluxDrive], space: ParameterSpace,
                 output: str = "field", variant=PAPER_VARIANT,
                 substeps: int = DEFAULT_SUBSTEPS, sigma: float | None = None,
                 priors: Sequence[GaussianPrior] = (), pad_to=None):
        if output not in FLUX_OUTPUTS:
            raise ValueError(f"Unknown output {output!r} of a FluxProblem; choose one of "
                             f"{list(FLUX_OUTPUTS)}.")
        if not isinstance(space, ParameterSpace):
            raise TypeError("space must be a jaxhyst.ParameterSpace.")
        drive, valid = _stacked(drives, pad_to)
        require_times_for(space, [drive])
        L, n_obs = len(drives), drive.n_observed
        data = _padded_data(data, valid) if output == "field" else \
            np.asarray(data, dtype=np.float64)
        want = (L, n_obs) if output == "field" else (L,)
        if data.shape != want:
            what = ("one value per observed sample" if output == "field"
                    else "one energy per record")
            raise ValueError(f"{output} data for {L} records must have shape {want} "
                             f"({what}); got {data.shape}.")
        if not np.all(np.isfinite(data)):
            raise ValueError(f"{output} data contain NaN or inf; remove those records.")
        if output == "cycle_energy" and np.any(data <= 0):
            i = int(np.flatnonzero(data <= 0)[0])
            raise ValueError(f"record {i}: an energy per cycle must be > 0 (J/m^3); got "
                             f"{data[i]:g}.")
        scales = np.max(np.abs(data), axis=-1) if output == "field" else np.ones(L)
        if np.any(scales == 0):
            raise ValueError("a record's field data are identically zero; nothing to fit.")
        self.data, self.drive, self.space = jnp.asarray(data), drive, space
        self.valid = jnp.asarray(valid)
        self.output, self.scales = output, jnp.asarray(scales, dtype=jnp.float64)
        self.variant, self.substeps = variant, checked_substeps(substeps)
        self.sigma = None if sigma is None else jnp.asarray(float(sigma), dtype=jnp.float64)
        self.priors = tuple(priors)
        # (shared: "relax"; per record: "relax[i]")
        self.after_effect = any(base_name(n) == "relax" for n in space.names) or any(
            base_name(n) == "relax" and float(np.max(v)) > 0 for n, v in space.fixed.items())
        self._check_priors()

    @property
    def n_records(self) -> int:
        return int(self.scales.shape[0])

    def simulate(self, params):
        """The `FluxSimulation` of every record (leaves with a leading axis L)."""
        per_record = jnp.ndim(split_parameters(params)[0].Ms) == 1

        def one(params, drive):
            p, losses, form = split_parameters(params)
            return simulate_flux_unchecked(p, drive, self.variant if form is None else form,
                                           self.substeps, losses, self.after_effect)

        return jax.vmap(one, in_axes=(0 if per_record else None, 0))(params, self.drive)

    def model(self, params):
        """The identified material model at ``params`` (no actuator: `Model.simulate_flux`
        drives it by B), to simulate other drives or save (`jaxhyst.save_model`)."""
        from ..saved import Model
        from .joint import NO_ACTUATOR

        p, losses, form = split_parameters(params)
        return Model(p, NO_ACTUATOR, self.variant if form is None else form,
                     self.substeps, losses)

    def predict(self, params) -> jax.Array:
        """The model's field (L, n_obs; in a record's padding, at its last B held) or
        energies per cycle (L,)."""
        sim = self.simulate(params)
        if self.output == "field":
            return sim.H[..., self.drive.run_in:]
        return sim.cycle_energy

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        if self.output == "field":
            return tuple(ResidualGroup(f"record {i} (field)", int(self.data.shape[1]), "A/m",
                                       self.sigma, scale=self.scales[i],
                                       data_size=self.scales[i], valid=self.valid[i])
                         for i in range(self.n_records))
        return (ResidualGroup("cycle energy (relative)", self.n_records, "1", self.sigma),)

    def group_residuals(self, params) -> tuple:
        pred = self.predict(params)
        if self.output == "field":
            e = jnp.where(self.valid, pred - self.data, 0.0)
            return tuple(e[i] for i in range(self.n_records))
        return (pred / self.data - 1.0,)

    @property
    def observations(self):
        return self.data

    def with_data(self, data) -> FluxProblem:
        return eqx.tree_at(lambda q: q.data, self, jnp.asarray(data, dtype=jnp.float64))

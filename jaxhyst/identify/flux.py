"""B-driven identification: `FluxProblem`, the magnetic parameters (and the loss
coefficients of the rate-dependent model) from records of the flux density B(t) with
either the measured field H(t) or the measured energy per cycle ∮ H dB (the core loss
per volume divided by the frequency).

Each record is one `FluxDrive` (all of one length and run-in, as measured periods of a
core-loss database are); the records are simulated in one ``jax.vmap``. The parameter
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
from .problem import AbstractProblem, GaussianPrior, ResidualGroup
from .space import ParameterSpace

#: What a `FluxProblem` observes: name → unit of its data.
FLUX_OUTPUTS = {"field": "A/m", "cycle_energy": "J/m^3"}


def stack_flux_drives(drives: Sequence[FluxDrive]) -> FluxDrive:
    """One `FluxDrive` with leaves (L, T) from L drives of one length and run-in."""
    drives = None if isinstance(drives, FluxDrive) else list(drives)
    if not drives or not all(isinstance(d, FluxDrive) for d in drives):
        raise TypeError("give the records' drives as a list, one jaxhyst.FluxDrive per "
                        "record ([drive] for one; flux_from_period, flux_from_record, "
                        "sinusoidal_flux …), and their data likewise ([H]).")
    shapes = {(d.n_samples, d.run_in) for d in drives}
    if len(shapes) != 1:
        raise ValueError(f"the records must have one length and run-in (their (samples, "
                         f"run-in) are {sorted(shapes)}); resample them to a common length.")
    uniform, timed = all(d.uniform for d in drives), all(d.timed for d in drives)
    drives = [d if (d.uniform, d.timed) == (uniform, timed) else  # (one structure for all)
              FluxDrive(d.t, d.B, d.run_in, uniform, timed) for d in drives]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *drives)


class FluxProblem(AbstractProblem):
    """Identify from L B-driven records (see the module docstring).

    **Arguments:**
    - ``data``: per record, the measured field H at the drive's observed samples (A/m,
      ``output="field"``) or the measured energy per cycle over its observed part
      (J/m³, ``output="cycle_energy"``: power loss per volume / frequency).
    - ``drives``: one `FluxDrive` per record (one length and run-in).
    - ``space``: the `ParameterSpace` (`ParameterSpace.with_losses` for the rate-dependent
      model; its structural parameters never enter and are best fixed).
    - ``variant``, ``substeps``: the Jiles–Atherton form and RK4 substeps.
    - ``sigma``, ``priors``: as in `jaxhyst.Problem` (sigma: a number for every record).

    Residuals: for ``field``, model − data per record (one group each, normalised by the
    record's max|H|); for ``cycle_energy``, the relative error model/data − 1 of each
    record (one group of L), so that records of different loss count alike.
    """

    data: jax.Array
    drive: FluxDrive
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
                 priors: Sequence[GaussianPrior] = ()):
        if output not in FLUX_OUTPUTS:
            raise ValueError(f"Unknown output {output!r} of a FluxProblem; choose one of "
                             f"{list(FLUX_OUTPUTS)}.")
        if not isinstance(space, ParameterSpace):
            raise TypeError("space must be a jaxhyst.ParameterSpace.")
        drive = stack_flux_drives(drives)
        require_times_for(space, [drive])
        L, n_obs = len(drives), drive.n_observed
        data = np.asarray(data, dtype=np.float64)
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
        """The model's field (L, n_obs) or energies per cycle (L,)."""
        sim = self.simulate(params)
        if self.output == "field":
            return sim.H[..., self.drive.run_in:]
        return sim.cycle_energy

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        if self.output == "field":
            return tuple(ResidualGroup(f"record {i} (field)", int(self.data.shape[1]), "A/m",
                                       self.sigma, scale=self.scales[i],
                                       data_size=self.scales[i])
                         for i in range(self.n_records))
        return (ResidualGroup("cycle energy (relative)", self.n_records, "1", self.sigma),)

    def group_residuals(self, params) -> tuple:
        pred = self.predict(params)
        if self.output == "field":
            return tuple(pred[i] - self.data[i] for i in range(self.n_records))
        return (pred / self.data - 1.0,)

    @property
    def observations(self):
        return self.data

    def with_data(self, data) -> FluxProblem:
        return eqx.tree_at(lambda q: q.data, self, jnp.asarray(data, dtype=jnp.float64))

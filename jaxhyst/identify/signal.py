"""The built-in problem: one observed signal of one drive (`Problem`), and synthetic data
for it (`synthetic_problem`)."""

from __future__ import annotations

import copy
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..actuator import Actuator
from ..drive import Drive, require_times_for
from ..model.accuracy import may_be_coarse, richardson_error
from ..model.paths import split_parameters
from ..model.simulate import (
    DEFAULT_SUBSTEPS,
    PAPER_VARIANT,
    Simulation,
    simulate,
    simulate_unchecked,
)
from ..names import checked_substeps
from ..params import Bounds, Parameters, check_parameters
from ..saved import Model
from .measured import holds_loop
from .outputs import MAGNETIC_OUTPUTS, AbstractOutput, output_kind
from .problem import AbstractProblem, GaussianPrior, ResidualGroup
from .space import ParameterSpace


def _caller_level() -> int:
    """The ``stacklevel`` that points a warning raised in this module at the first frame
    outside jaxhyst and equinox (the user's line that built the problem)."""
    import inspect

    frame, level = inspect.currentframe().f_back, 1  # the function that warns
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in (
            "jaxhyst", "equinox"):
        frame, level = frame.f_back, level + 1
    return level


class Problem(AbstractProblem):
    """Identify `Parameters` from one observed signal of one drive.

    **Arguments:**
    - ``data``: observed samples, shape (T_obs,), in the unit of ``output``; aligned with
      the drive's observed samples (after its run-in).
    - ``drive``: the `Drive` that produced the data (t in s, H in A/m).
    - ``actuator``: known `Actuator` constants.
    - ``space``: a `ParameterSpace` (bounds, free and fixed parameters).
    - ``output``: what the data are: ``displacement`` (m), ``strain``,
      ``magnetostriction``, ``magnetization`` (A/m), ``flux_density`` (T, B = μ0(H + M));
      the names of `jaxhyst.identify.outputs.OUTPUTS` (or an output kind).
    - ``variant``, ``substeps``: model settings, as in `simulate`.
    - ``sigma``: the data's noise level (unit of ``output``) if known; ``priors``: a
      sequence of `GaussianPrior` (needs ``sigma``).
    - ``require_full_period``: refuse data whose field holds no loop (the turning-point
      rule of `jaxhyst.identify.measured`: noise reversals below 5 % of the range do not
      count), which cannot determine a hysteresis loop.

    Whether the sampling is fine enough is judged after a fit, at the fitted parameters
    (`sampling_error`: `jaxhyst.solve` & co. put it in the result and warn there).
    """

    data: jax.Array
    drive: Drive
    actuator: Actuator
    space: ParameterSpace
    scale: jax.Array  # max|data| (0-d; data, so a new data set does not recompile)
    output: str = eqx.field(static=True, default="displacement")
    variant: eqx.Module = PAPER_VARIANT  # (a model form: a JA variant, PlayJA …)
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    sigma: jax.Array | None = None  # the noise level (0-d), if known
    priors: tuple = eqx.field(static=True, default=())

    def __init__(self, data, drive: Drive, actuator: Actuator, space: ParameterSpace,
                 output: str = "displacement", variant=PAPER_VARIANT,
                 substeps: int = DEFAULT_SUBSTEPS, require_full_period: bool = True,
                 sigma: float | None = None, priors: Sequence[GaussianPrior] = ()):
        kind = output_kind(output)
        if not isinstance(drive, Drive):
            raise TypeError(f"drive must be a jaxhyst.Drive; got {type(drive).__name__}.")
        if not isinstance(space, ParameterSpace):
            raise TypeError("space must be a jaxhyst.ParameterSpace (bounds + fixed values).")
        require_times_for(space, [drive])
        data = np.asarray(data, dtype=np.float64)
        if data.ndim != 1:
            raise ValueError(f"data must be 1-D (one observed signal); got shape {data.shape}.")
        if data.shape[0] != drive.n_observed:
            raise ValueError(
                f"data has {data.shape[0]} samples but the drive observes {drive.n_observed} "
                f"(it has {drive.n_samples} samples, {drive.run_in} of them run-in); give one "
                "data sample per observed drive sample."
            )
        if not np.all(np.isfinite(data)):
            bad = np.flatnonzero(~np.isfinite(data))[:5].tolist()
            raise ValueError(f"data contain NaN or inf at samples {bad}; remove or repair them.")
        H_obs = np.asarray(drive.observed(drive.H))
        if require_full_period and not holds_loop(H_obs):
            raise ValueError(
                "The observed field holds no hysteresis loop: after its first turning point "
                "(a reversal larger than 5 % of its range) it must sweep back over 90 % of "
                "its range. Observe a whole period or loop (or pass "
                "require_full_period=False)."
            )
        big = np.flatnonzero(np.abs(data) > kind.largest)
        if big.size:
            i = int(big[0])
            raise ValueError(
                f"data[{i}] = {data[i]:g} {kind.unit} is beyond any {kind.name} "
                f"(|value| <= {kind.largest:g} {kind.unit}); check the unit and the column "
                "of that sample.")
        scale = float(np.max(np.abs(data)))
        if scale == 0.0:
            raise ValueError("data are identically zero; nothing to fit.")
        if float(np.ptp(data)) == 0.0:
            raise ValueError(f"data are constant ({data[0]:g} {kind.unit} at every sample): "
                             "a constant record holds no response to the drive to fit.")
        self.data = jnp.asarray(data)
        self.drive = drive
        self.actuator = actuator
        self.space = space
        self.scale = jnp.asarray(scale, dtype=jnp.float64)
        self.output = kind.name
        self.variant = variant
        self.substeps = checked_substeps(substeps)
        self.sigma = None if sigma is None else jnp.asarray(float(sigma), dtype=jnp.float64)
        self.priors = tuple(priors)
        self._check_priors()

    # -- model ----------------------------------------------------------------------
    def simulate(self, params) -> Simulation:
        """The simulation at ``params``: `Parameters`, or a tuple of them with `Losses`
        (the rate-dependent model) and/or the form with its own parameters (a space from
        `ParameterSpace.for_model`; `jaxhyst.model.paths.split_parameters`)."""
        p, losses, form = split_parameters(params)
        return simulate_unchecked(p, self.actuator, self.drive,
                                  self.variant if form is None else form, self.substeps,
                                  losses)

    def predict(self, params: Parameters) -> jax.Array:
        """The model's observed output at ``params`` (unit of ``output``)."""
        return self.drive.observed(self.kind.of(self.simulate(params)))


    @property
    def kind(self) -> AbstractOutput:
        """The output kind (`jaxhyst.identify.outputs`)."""
        return output_kind(self.output)

    @property
    def unit(self) -> str:
        """Unit of the observed output."""
        return self.kind.unit

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        return (ResidualGroup(self.output, int(self.data.shape[0]), self.unit, self.sigma,
                              scale=self.scale, data_size=self.scale),)

    def group_residuals(self, params) -> tuple:
        return (self.predict(params) - self.data,)

    def model(self, params) -> Model:
        """The identified model at ``params`` (this problem's actuator, form and
        substeps), to simulate other drives or save (`jaxhyst.save_model`)."""
        p, losses, form = split_parameters(params)
        return Model(p, self.actuator, self.variant if form is None else form,
                     self.substeps, losses)

    @property
    def observations(self):
        return self.data

    def with_data(self, data) -> Problem:
        return eqx.tree_at(lambda q: q.data, self, jnp.asarray(data, dtype=jnp.float64))

    def with_fixed(self, fixed: dict[str, float]) -> Problem:
        """The same problem with the parameters in ``fixed`` ({name: SI value}) held fixed:
        the reparameterisation an `IdentifiabilityReport.suggest_fixed` asks for."""
        return eqx.tree_at(lambda q: q.space, self,
                           self.space.with_fixed({n: float(v) for n, v in fixed.items()}))

    def objective(self, params: Parameters) -> jax.Array:
        """The paper's E(θ) = Σ_k (y(k) − ỹ(k, θ))² (eq 15), in the output's unit squared."""
        return jnp.sum((self.predict(params) - self.data) ** 2)


def synthetic_problem(params: Parameters, drive: Drive, actuator: Actuator, bounds: Bounds,
                      fixed: Sequence[str] | dict | None = None, output: str = "displacement",
                      noise: float = 0.0, key=None, **kwargs) -> Problem:
    """A problem whose data are simulated at ``params`` (plus Gaussian noise of standard
    deviation ``noise``, in the output's unit). ``fixed`` lists parameter names to hold at
    their values in ``params`` (or gives ``{name: value}``)."""
    check_parameters(params)
    if fixed is not None and not isinstance(fixed, dict):
        fixed = {n: float(getattr(params, n, np.nan)) for n in fixed}  # (unknown: refused)
    space = ParameterSpace(bounds, fixed)
    # compiled as one program (op by op, the first call compiled ~150 small programs)
    sim = simulate(params, actuator, drive, kwargs.get("variant", PAPER_VARIANT),
                   kwargs.get("substeps", DEFAULT_SUBSTEPS))
    # the observed part sliced in NumPy (eagerly, JAX would compile the slice on its own)
    data = np.asarray(output_kind(output).of(sim))[drive.run_in:]
    if noise:
        if key is None:
            raise ValueError("noise > 0 needs a jax.random key for reproducibility.")
        data = data + noise * jax.random.normal(key, data.shape)
    return Problem(data, drive, actuator, space, output=output, **kwargs)


def sampling_error(problem, params) -> float | None:
    """The model's error at ``problem``'s sampling and substeps, relative to the size of
    its output, at ``params`` (`jaxhyst.model.accuracy`: the same prediction at twice the
    substeps); None where the drive is fine enough that it cannot matter (its field — or
    flux density — moves at most 1 % of its range per substep), where the form's
    magnetization does not depend on the substeps (``exact_in_substeps``: the pinning
    cells) and only magnetic outputs are fitted, or for a problem without a drive and
    substeps of this kind."""
    drive, substeps = getattr(problem, "drive", None), getattr(problem, "substeps", None)
    signal = getattr(drive, "H", getattr(drive, "B", None))
    if signal is None or not isinstance(substeps, int):
        return None
    outputs = getattr(problem, "outputs", None) or (getattr(problem, "output", None),)
    if getattr(getattr(problem, "variant", None), "exact_in_substeps", False) and \
            all(o in MAGNETIC_OUTPUTS for o in outputs):  # (not a B-driven fit's field)
        return None
    rows = np.atleast_2d(np.asarray(signal))[:, drive.run_in:]
    if not any(may_be_coarse(row, substeps) for row in rows):
        return None
    finer = copy.copy(problem)
    object.__setattr__(finer, "substeps", 2 * substeps)
    coarse, fine = _predictions(problem, finer, params)
    return richardson_error(coarse, fine)


@eqx.filter_jit
def _predictions(problem, finer, params):
    # (a joint problem's mask is data: its padded predictions, 0 in the padding)
    if hasattr(problem, "predict_valid"):
        return problem.predict_valid(params), finer.predict_valid(params)
    return problem.predict(params), finer.predict(params)

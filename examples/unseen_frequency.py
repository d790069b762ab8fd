"""Prediction at frequencies that were not measured.

A conducting core's B–H loop widens with frequency. The "measurements" here are loops
at 50, 100 and 200 Hz of a material with eddy-current and excess losses (the H-driven
rate-dependent model, known parameters, B read to 0.2 % of its range); 400 and 800 Hz
are held back. Two models are fitted to the three measured loops jointly:

- static: one Jiles–Atherton parameter set for all three frequencies (the paper's model);
- rate dependent: one parameter set plus the loss coefficients (`jaxhyst.Losses`).

Each then predicts the loops at 400 and 800 Hz, which neither has seen.

Run: ``python examples/unseen_frequency.py [OUTDIR]`` (the figure goes to OUTDIR).
"""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
MU0 = 4e-7 * np.pi
FITTED, HELD_OUT = (50.0, 100.0, 200.0), (400.0, 800.0)

truth = jh.TABLE1_TRUE  # its magnetization parameters (Ms, a, k, α̃, c); no actuator
true_losses = jh.Losses(eddy=0.5, excess=5.0)  # A/m per T/s, A/m per √(T/s)
drives = {f: jh.sinusoidal_field(f, 20e3, 0.0, samples_per_period=200)
          for f in FITTED + HELD_OUT}


def flux_density(params, f, losses=None):
    """B(t) over the observed period (T) for the field drive at f Hz."""
    sim = jh.simulate_unchecked(params, NO_ACTUATOR, drives[f], losses=losses)
    return drives[f].observed(MU0 * (sim.H_hyst + sim.M))


rng = np.random.default_rng(0)
measured = {}
for f in FITTED + HELD_OUT:
    B = np.asarray(flux_density(truth, f, true_losses))
    measured[f] = B + 0.002 * np.ptp(B) * rng.standard_normal(B.size)

# --- the box: the magnetization parameters free, the actuator's five unused and fixed
bounds = jh.TABLE1_BOUNDS
fixed = {n: float(getattr(truth, n)) for n in ("lambda_s", "E", "Kz", "Mz", "Cz")}
data = [jnp.asarray(measured[f]) for f in FITTED]
groups = {f"{f:g} Hz": {"scale": float(np.max(np.abs(measured[f]))), "unit": "T"}
          for f in FITTED}


def static_residuals(params, d):
    return {f"{f:g} Hz": flux_density(params, f) - d[i] for i, f in enumerate(FITTED)}


def rate_residuals(params, d):
    p, losses = params
    return {f"{f:g} Hz": flux_density(p, f, losses) - d[i] for i, f in enumerate(FITTED)}


centre = jh.Parameters.from_array(0.5 * (bounds.lower.to_array() + bounds.upper.to_array()))
centre = jh.Parameters(**{**centre.to_dict(), **fixed})
static = jh.solve(jh.ResidualProblem(static_residuals, jh.ParameterSpace(bounds, fixed),
                                     data, groups=groups), centre, solver="lm")
rate_space = jh.ParameterSpace.with_losses(bounds, {"eddy": (0.0, 10.0),
                                                    "excess": (0.0, 100.0)}, fixed=fixed)
rate = jh.solve(jh.ResidualProblem(rate_residuals, rate_space, data, groups=groups),
                (centre, jh.Losses(0.1, 1.0)), solver="lm")
p_rate, losses = rate.params
print(f"static fit: rms {1e3 * static.rms_error:.2f} mT over the three loops "
      f"({static.result}, {static.steps} steps)")
print(f"rate-dependent fit: rms {1e3 * rate.rms_error:.2f} mT ({rate.result}, "
      f"{rate.steps} steps); eddy {float(losses.eddy):.3g} (true {true_losses.eddy}), "
      f"excess {float(losses.excess):.3g} (true {true_losses.excess})")

print("\nrms error of the prediction, % of the loop's peak B:")
print("| f (Hz) | seen in the fit | static JA | rate dependent |")
print("|---|---|---|---|")
predictions = {}
for f in FITTED + HELD_OUT:
    peak = float(np.max(np.abs(measured[f])))
    pred_s = np.asarray(flux_density(static.params, f))
    pred_r = np.asarray(flux_density(p_rate, f, losses))
    e_s = 100 * np.sqrt(np.mean((pred_s - measured[f]) ** 2)) / peak
    e_r = 100 * np.sqrt(np.mean((pred_r - measured[f]) ** 2)) / peak
    predictions[f] = (pred_s, pred_r)
    print(f"| {f:g} | {'yes' if f in FITTED else '**no**'} | {e_s:.2f} % | {e_r:.2f} % |")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
for ax, f in zip(axes, HELD_OUT, strict=True):
    H = np.asarray(drives[f].observed(drives[f].H)) / 1e3
    ax.plot(H, measured[f], ".", ms=2.5, color="0.45", label="measured (not fitted)")
    ax.plot(H, predictions[f][0], lw=1.3, label="static JA, predicted")
    ax.plot(H, predictions[f][1], "--", lw=1.3, label="rate dependent, predicted")
    ax.set(xlabel="H (kA/m)", ylabel="B (T)", title=f"{f:g} Hz, fitted at 50–200 Hz")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
fig.savefig(out / "unseen_frequency.png", dpi=110)

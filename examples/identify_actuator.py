"""An actuator identified from displacement data, with its identifiability report.

The data stand in for a measurement: the paper's Table 1 actuator driven at 100 Hz,
its displacement with white noise of 0.1 % of its peak. Ms, λs and Mz are held at known
values (displacement alone cannot determine them, see the theory page); the other seven
parameters are fitted by Levenberg–Marquardt from eight random starts in one vmapped
batch, and the report says what the data determine and how well.

Run: ``python examples/identify_actuator.py [OUTDIR]`` (figures go to OUTDIR, default .).
"""

import sys
from pathlib import Path

import jax
import numpy as np

import jaxhyst as jh
from jaxhyst.plots import plot_fit, plot_identifiability

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")

# --- the "measurement": 100 Hz, I = 0.77 sin(2π·100 t) + 1.53 A, 100 samples per period
actuator = jh.ACTUATOR1
drive = jh.sinusoidal_current(100.0, 0.77, 1.53, actuator, samples_per_period=100)
clean = jh.simulate(jh.TABLE1_TRUE, actuator, drive).observed("y")  # m
sigma = 1e-3 * float(np.max(np.abs(clean)))  # 0.1 % of the peak displacement, m
noise = sigma * jax.random.normal(jax.random.PRNGKey(1), clean.shape)
y_measured = clean + noise

# --- the problem: data, drive, actuator, the search box and what is known
space = jh.ParameterSpace(jh.TABLE1_BOUNDS,
                          fixed={n: float(getattr(jh.TABLE1_TRUE, n))
                                 for n in ("Ms", "lambda_s", "Mz")})
problem = jh.Problem(y_measured, drive, actuator, space, output="displacement",
                     sigma=sigma)  # a declared σ makes the cost a χ²

# --- eight random starts in the box (coordinates u in [0, 1]), solved in one batch
starts = jax.random.uniform(jax.random.PRNGKey(0), (8, space.n_free))
result = jh.multistart(problem, starts, solver="lm")
print(result)

# --- what a reader wants from the report
report = result.report
print("\nrank of the Jacobian:", report.rank, "of", len(report.names))
for name in report.names:
    lo, hi = report.intervals[name]
    value = float(getattr(result.params, name))
    truth = float(getattr(jh.TABLE1_TRUE, name))
    print(f"{name:>6} = {value:.5g}  95 % interval [{lo:.5g}, {hi:.5g}]  truth {truth:.5g}  "
          f"{'holds it' if lo <= truth <= hi else 'MISSES it'}")

# --- figures: the paper's Fig. 6 (data, fit, error) and the report's singular values
model_y = problem.predict(result.params)
plot_fit(drive.observed(drive.H), y_measured, model_y, "displacement",
         out / "identify_actuator_fit.png", t=drive.observed(drive.t))
plot_identifiability(report, out / "identify_actuator_report.png")

"""A measured B–H loop fitted from a CSV file.

The file stands in for a measurement: one loop of a soft ferrite-like material (the
classic Jiles–Atherton form, known parameters), 400 samples, with the field and the flux
density read to 0.2 % of their range, written as ``H [A/m], B [T]``. It is read back as a
user's file would be, fitted with the box jaxhyst derives from the loop itself, and the
fitted loop is compared with the data and with the parameters that made it.

Run: ``python examples/fit_bh_loop.py [OUTDIR]`` (the CSV and the figure go to OUTDIR).
"""

import sys
from pathlib import Path

import jax
import numpy as np

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR
from jaxhyst.plots import plot_fit

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
MU0 = 4e-7 * np.pi

# --- a "measured" file: H = 30 kA/m·cos(2π n/400), B from the model plus reading noise
truth = jh.Parameters(Ms=1.2e6, lambda_s=0.0, a=2000.0, k=1500.0, alpha=1e-3, c=0.3,
                      E=1.0, Kz=1.0, Mz=1.0, Cz=1.0)  # magnetization-only: the last 5 unused
H = 30e3 * np.cos(2 * np.pi * np.arange(400) / 400)
sim = jh.simulate(truth, NO_ACTUATOR, jh.drive_from_record(None, H), variant=jh.ClassicJA(),
                  substeps=4)
B = MU0 * (H + np.asarray(sim.observed("M")))
rng = np.random.default_rng(0)
H_read = H + 0.002 * np.ptp(H) * rng.standard_normal(H.size)
B_read = B + 0.002 * np.ptp(B) * rng.standard_normal(B.size)
csv = out / "bh_loop.csv"
np.savetxt(csv, np.column_stack([H_read, B_read]), delimiter=",", fmt="%.6g",
           header="H [A/m],B [T]", comments="")

# --- what a user does with their own file
(loop,) = jh.io.read_loops(csv)  # SI units from the header
problem = jh.loop_problem(loop.H, loop.signals["B"], variant=jh.ClassicJA(), substeps=4)
print("box derived from the loop:")
space = problem.space  # free names, lower and upper bounds (SI)
for name, lo, hi in zip(space.names, space.lower, space.upper, strict=True):
    print(f"  {name:>5} in [{float(lo):.4g}, {float(hi):.4g}]")

starts = jax.random.uniform(jax.random.PRNGKey(0), (16, problem.space.n_free))
result = jh.multistart(problem, starts, solver="lm")
print(result)

B_fit = np.asarray(problem.predict(result.params))
rms_mT = 1e3 * float(np.sqrt(np.mean((B_fit - loop.signals["B"]) ** 2)))
B_true = np.asarray(problem.predict(truth))
dev_mT = 1e3 * float(np.sqrt(np.mean((B_fit - B_true) ** 2)))
print(f"rms misfit to the noisy file: {rms_mT:.2f} mT (B read to "
      f"{1e3 * 0.002 * np.ptp(B):.2f} mT); fitted loop vs the true loop: {dev_mT:.2f} mT")
for name in space.names:
    print(f"  {name:>5}: fitted {float(getattr(result.params, name)):.5g}, "
          f"true {float(getattr(truth, name)):.5g}")

plot_fit(loop.H, loop.signals["B"], B_fit, "flux_density", out / "fit_bh_loop.png")

"""A GA population and a multi-start fit in one batch — on a GPU when JAX has one, on the
CPU otherwise (the same code: JAX places the batch on its default device).

1. 4096 parameter sets spread over the Table 1 box simulated in one call
   (`jaxhyst.simulate_batch`), timed after compilation; their costs against a target loop.
2. A multi-start Levenberg–Marquardt fit: 32 starts solved in one vmapped batch.
3. The paper's best hybrid (GATR1) for a few generations, the whole population evaluated
   per generation in one batch.

Run: ``python examples/population.py [OUTDIR]`` (the figure goes to OUTDIR, default .).
On a machine with a GPU, ``pip install "jax[cuda12]"`` first; ``JAX_PLATFORMS=cpu``
forces the CPU.
"""

import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxhyst as jh

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
device = jax.devices()[0]
print(f"JAX default device: {device.platform} ({device.device_kind})")

actuator = jh.ACTUATOR1
drive = jh.sinusoidal_current(100.0, 0.77, 1.53, actuator, samples_per_period=100)
target = jh.simulate(jh.TABLE1_TRUE, actuator, drive).observed("y")

# --- 1. a population: P parameter sets, uniformly in the box, one batched simulation
P = 4096
u = jax.random.uniform(jax.random.PRNGKey(0), (P, 10))
lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
population = jh.Parameters.from_array(lo + u * (hi - lo))  # leaves of shape (P,)
sims = jh.simulate_batch(population, actuator, drive)  # compiles, then runs
sims.y.block_until_ready()
times = []
for _ in range(3):
    t0 = time.perf_counter()
    jh.simulate_batch(population, actuator, drive).y.block_until_ready()
    times.append(time.perf_counter() - t0)
T = sims.y.shape[1]
per = np.median(times) / (P * T) * 1e9
print(f"population of {P} x {T} samples: {np.median(times):.3f} s per batch "
      f"(median of 3), {per:.1f} ns per individual·sample")
costs = jnp.sum((drive.observed(sims.y) - target) ** 2, axis=1) / jnp.sum(target**2)
print(f"relative costs over the population: best {float(jnp.min(costs)):.3g}, "
      f"median {float(jnp.median(costs)):.3g}")

# --- 2. a multi-start fit of the seven identifiable parameters, 32 starts in one batch
problem = jh.synthetic_problem(jh.TABLE1_TRUE, drive, actuator, jh.TABLE1_BOUNDS,
                               fixed=["Ms", "lambda_s", "Mz"])
starts = jax.random.uniform(jax.random.PRNGKey(1), (32, problem.space.n_free))
result = jh.multistart(problem, starts, solver="lm", max_steps=100)
finals = np.array([row["cost"] for row in result.extra["starts"]])  # one row per start
print(f"multi-start: {np.sum(finals < 1e-20)} of {len(finals)} starts reached a cost "
      f"below 1e-20; best {result.cost:.2e} in {result.wall_time:.1f} s")

# --- 3. the hybrid GA, a short run: every generation's population is one batch
ga = jh.run_hybrid(problem, "GATR1", seed=0,
                   settings={"q1": 60, "q2": 20, "T1": 2, "T2": 10, "T3": 10})
print(f"GATR1 (q1 = 60, 12 generations): cost {ga.cost:.2e} in {ga.wall_time:.1f} s")

# --- a figure: the population's costs and the best loops
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
a1.hist(np.log10(np.asarray(costs)), bins=60)
a1.set(xlabel="log10 relative cost", ylabel="individuals",
       title=f"{P} random parameter sets, one batch ({device.platform})")
best = np.argsort(np.asarray(costs))[:5]
H = np.asarray(drive.observed(drive.H)) / 1e3
for i in best:
    a2.plot(H, np.asarray(drive.observed(sims.y[i])) * 1e6, lw=0.8)
a2.plot(H, np.asarray(target) * 1e6, "k", lw=2, alpha=0.4, label="target")
a2.set(xlabel="H (kA/m)", ylabel="y (μm)", title="the five best loops of the population")
a2.legend()
fig.savefig(out / "population.png", dpi=110)

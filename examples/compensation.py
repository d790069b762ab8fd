"""Hysteresis compensation: the current that makes the actuator follow a displacement you
choose, within a current limit — then, on an actuator that differs from the model, the
correction learned from what it did (iterative learning).

The model is the paper's Table 1 actuator; the "real" actuator stands in for the
hardware: every parameter 10 % off the model's, with random signs, measured by a sensor
with noise of 0.01 % of the stroke (`jaxhyst.control.SimulatedPlant`). Learning says
what each step did, and stops where further steps would only learn the noise.

Run: ``python examples/compensation.py [OUTDIR]`` (the figures go to OUTDIR, default .).
"""

import sys
from pathlib import Path

import numpy as np

import jaxhyst as jh
from jaxhyst.control import IterativeLearning, SimulatedPlant
from jaxhyst.control.compensate import rms_error
from jaxhyst.plots import plot_compensation

out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")

model = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1)  # identified parameters and actuator
reference = jh.sinusoidal_reference(100.0, 20e-6, 45e-6)  # y = 45 + 20 sin(2π·100 t) µm
comp = jh.compensate(model, reference, current_limit=2.5)  # |I| ≤ 2.5 A
print(comp.summary())
plot_compensation(comp, out / "compensation.png")

# --- on an actuator that differs from the model: learn from each measured period
signs = np.random.default_rng(0).choice([-1.0, 1.0], size=10)
real = jh.Model(jh.Parameters.from_array(np.asarray(jh.TABLE1_TRUE.to_array())
                                         * (1.0 + 0.1 * signs)), jh.ACTUATOR1)
plant = SimulatedPlant(real, reference, noise=1e-4)  # stands in for the hardware
learner = IterativeLearning.of(model, reference, current_limit=2.5)
state = learner.init()  # the model's compensating current

errors = []  # the true tracking error of each current applied (the plant without noise)
for _ in range(8):
    true = rms_error(plant.response(state.input), reference.displacement, reference.scale)
    errors.append(100 * true)  # %
    print(f"iteration {state.iteration}: rms tracking error {errors[-1]:.3g} % of the "
          f"peak-to-peak; current in [{state.input.min():.3f}, {state.input.max():.3f}] A")
    state = learner.step(state, plant.measure(state.input))  # apply, measure, learn
    print(f"  {state.reports[-1]}")
    if state.stopped:
        break

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(5.5, 3.6), constrained_layout=True)
ax.semilogy(range(len(errors)), errors, "o-")
ax.set(xlabel="learning iteration (0: the model's current)",
       ylabel="rms tracking error (% of p-p)",
       title="the real actuator, 10 % off the model")
ax.grid(alpha=0.3, which="both")
fig.savefig(out / "compensation_learning.png", dpi=110)

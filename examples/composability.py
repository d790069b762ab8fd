"""jaxhyst inside your own JAX code: a user-written loss on `simulate`, its exact
gradient, a few Optimistix steps, and `jax.vmap` over parameter sets.

The loss: a weighted mean square error on strain (the top of the loop counts double)
plus a weak Gaussian prior on log(a, k, c); the other seven parameters are known.
Run: ``python examples/composability.py`` (the test suite runs it too).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

import jaxhyst as jh

actuator = jh.ACTUATOR1
drive = jh.sinusoidal_current(100.0, 0.77, 1.53, actuator, samples_per_period=50)
truth = jh.TABLE1_TRUE
measured = jh.simulate(truth, actuator, drive).observed("strain")  # stand-in for a measurement
H_obs = drive.observed(drive.H)
weights = jnp.where(H_obs > 0.8 * jnp.max(H_obs), 2.0, 1.0)

prior_mean = jnp.log(jnp.array([6000.0, 3000.0, 0.2]))  # log a, log k, log c
prior_sd = 1.0


def params_from(x):
    """Parameters with (a, k, c) = exp(x); everything else as known."""
    a, k, c = jnp.exp(x)
    return eqx.tree_at(lambda p: (p.a, p.k, p.c), truth, (a, k, c))


def loss(x, args=None):
    # simulate_unchecked is the pure function: no Python checks, safe under jit/grad/vmap
    sim = jh.simulate_unchecked(params_from(x), actuator, drive)
    r = (drive.observed(sim.strain) - measured) / jnp.max(jnp.abs(measured))
    misfit = jnp.sum(weights * r**2) / jnp.sum(weights)
    return misfit + 1e-8 * jnp.sum(((x - prior_mean) / prior_sd) ** 2)


x0 = prior_mean
grad = jax.jit(jax.grad(loss))(x0)  # exact reverse-mode gradient through the scan

solver = optx.BFGS(rtol=1e-9, atol=1e-12)
sol = optx.minimise(loss, solver, x0, max_steps=60, throw=False)
found = params_from(sol.value)

# one vmapped call evaluates the loss for a whole batch of parameter sets
batch = x0 + 0.1 * jax.random.normal(jax.random.PRNGKey(0), (16, 3))
losses = jax.jit(jax.vmap(loss))(batch)

if __name__ == "__main__":
    print("gradient at the prior mean:", grad)
    ok = "converged" if sol.result == optx.RESULTS.successful else "stopped"
    print(f"loss {float(loss(x0)):.3e} -> {float(loss(sol.value)):.3e} in "
          f"{int(sol.stats['num_steps'])} BFGS steps ({ok})")
    print(f"a = {float(found.a):.2f} A/m, k = {float(found.k):.2f} A/m, c = {float(found.c):.4f}"
          f"  (truth 7012, 3283, 0.18)")
    print("batch of losses:", losses)

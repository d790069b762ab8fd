"""The model driven either way (issue 30): what the rate-dependent H-driven form and the
B-driven form cost against the static H-driven model, forward and under `grad` and
`jacfwd`, on one run (T = 451 samples, 2 substeps, the same soft material).

    python benchmarks/bench_rate_flux.py [--repeats 30]

Medians of interleaved repeated calls after compilation (`bench_transforms.interleaved_ms`).
"""

from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    sys.path.insert(0, HERE)
    import jax
    import jax.numpy as jnp
    from bench_simulate import machine
    from bench_transforms import interleaved_ms

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    p0 = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                       Kz=1.0, Mz=1.0, Cz=0.0)
    field = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=200)
    flux = jh.sinusoidal_flux(300.0, 0.3, 0.0, samples_per_period=200)
    x0 = jnp.array([jnp.log(30.0), jnp.log(20.0), 0.3, jnp.log(0.05), jnp.log(0.5)])

    def parts(x):
        return (p0.replace(a=jnp.exp(x[0]), k=jnp.exp(x[1]), c=x[2]),
                jh.Losses(jnp.exp(x[3]), jnp.exp(x[4])))

    def static_H(x):
        return jh.simulate_unchecked(parts(x)[0], NO_ACTUATOR, field).M

    def dynamic_H(x):
        p, L = parts(x)
        return jh.simulate_unchecked(p, NO_ACTUATOR, field, losses=L).M

    def static_B(x):
        return jh.simulate_flux_unchecked(parts(x)[0], flux).H

    def dynamic_B(x):
        p, L = parts(x)
        return jh.simulate_flux_unchecked(p, flux, losses=L).H

    print(f"machine: {machine()}\n")
    print("| form | forward (ms) | grad of Σ(out²) (ms) | × forward | jacfwd, 5 parameters "
          "(ms) | × forward |")
    print("|---|---|---|---|---|---|")
    for name, f in (("static, H-driven", static_H), ("rate-dependent, H-driven", dynamic_H),
                    ("static, B-driven", static_B), ("rate-dependent, B-driven", dynamic_B)):
        fwd = jax.jit(f)
        grad = jax.jit(jax.grad(lambda x, f=f: jnp.sum(f(x) ** 2)))
        jac = jax.jit(jax.jacfwd(f))
        t = interleaved_ms({"f": lambda: fwd(x0).block_until_ready(),
                            "g": lambda: grad(x0).block_until_ready(),
                            "j": lambda: jac(x0).block_until_ready()}, args.repeats)
        print(f"| {name} | {t['f']:.3f} | {t['g']:.3f} | {t['g'] / t['f']:.1f} | "
              f"{t['j']:.3f} | {t['j'] / t['f']:.1f} |", flush=True)


if __name__ == "__main__":
    main()

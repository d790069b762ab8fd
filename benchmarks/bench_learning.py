"""Learning control on plants that are not the model (issue 42).

    python benchmarks/bench_learning.py [--plants 20] [--iterations 10] [--seeds 0,1]
                                        [--delay correct|refuse|SAMPLES] [--parts 1,2,3,4,5]
                                        [--out benchmarks/bench_learning_output.md]

The model is Table 1's Actuator1; the reference a 100 Hz sine over 30 % of the stroke
(200 samples per period), the current limited to ±2.5 A. Each plant is the model with
every one of its ten parameters 10 % off (random signs, one draw per plant, seeded), a
sensor with Gaussian noise of σ = 0.5 % of the peak-to-peak, and:

1. **mismatch + noise**: `IterativeLearning` for ``--iterations`` steps, for each draw
   of 20 plants in ``--seeds``; per plant the true tracking error (noise-free) after them
   over the noise σ, how often a measured error rose above the one before by more than
   the noise of an rms error (2σ/√N) and by more than σ, and how learning ended;
   beside it the skeptic's baseline, plain-gain learning (u += γ·e/g with g the plant's
   static gain dy/du fitted through the model, γ = 0.5, the same robustness filter);
2. **an unmodelled mode** at a random 1.5–3 kHz (damping 0.05) as well: 20 iterations;
   no divergence (the largest measured error after the first over the first), and the
   band learning ended trusting;
3. **delay** of 1–5 samples on the plant 10 % off and on the exact model: the lag found
   and corrected at the first step;
4. **an unreachable reference** (1.3× the stroke): the refinement's time and outcome;
5. **a true acquisition delay** of 1 and 2 samples on the plants of ``--seeds`` (10 %
   off, noise): the actuator's own tracking error (without the delay) after
   ``--iterations`` steps.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def plants(jh, n, seed=0):
    rng = np.random.default_rng(seed)
    x = np.asarray(jh.TABLE1_TRUE.to_array())
    for _ in range(n):
        yield jh.Parameters.from_array(x * (1 + 0.1 * rng.choice([-1.0, 1.0], 10)))


def plain_gain(learner, plant, iterations, gamma=0.5):
    """u += γ·Q·e/g, g the model's static gain dy/du (least squares through the model)."""
    from jaxhyst.control.signals import low_pass

    ref = learner.reference
    u = learner.init().input
    y_model = learner.predict(learner.init())
    g = float(np.polyfit(u, y_model, 1)[0])
    band = learner.initial_band()
    r = np.asarray(ref.displacement)
    errors = []
    lo, hi = learner.compensation.limits.lower, learner.compensation.limits.upper
    for _ in range(iterations):
        y = plant.measure(u)
        errors.append(float(np.sqrt(np.mean((plant.response(u) - r) ** 2)) / ref.scale))
        u = np.clip(u + gamma * low_pass(r - y, ref.dt, band) / g, lo, hi)
    return errors


def run(jh, learner, plant, iterations):
    state = learner.init()
    true, measured = [], []
    r = np.asarray(learner.reference.displacement)
    for _ in range(iterations):
        true.append(float(np.sqrt(np.mean((plant.response(state.input) - r) ** 2))
                          / learner.reference.scale))
        state = learner.step(state, plant.measure(state.input))
        measured.append(state.errors[-1])
        if state.stopped:
            break
    return state, true, measured


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", type=int, default=20)
    ap.add_argument("--iterations", type=int, default=10)
    ap.add_argument("--seeds", default="0",
                    help="draws of the plants for part 1, comma-separated (each 20 plants)")
    ap.add_argument("--delay", default="correct",
                    help="IterativeLearning's delay: correct, refuse or the known samples")
    ap.add_argument("--parts", default="1,2,3,4")
    ap.add_argument("--out", default=os.path.join(HERE, "bench_learning_output.md"))
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    delay = int(args.delay) if args.delay.isdigit() else args.delay
    import warnings

    import jaxhyst as jh
    from jaxhyst.control import IterativeLearning, SimulatedPlant

    warnings.simplefilter("ignore")
    sigma = 0.005
    ref = jh.sinusoidal_reference(100.0, 13.9e-6, 46.4e-6)
    model = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1)
    learner = IterativeLearning.of(model, ref, current_limit=2.5, delay=delay)
    N = ref.n_samples
    lines = [f"# bench_learning — {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores", "",
             f"σ = {sigma} of the peak-to-peak; {args.plants} plants, every parameter 10 % "
             f"off (random signs); learning with delay={delay!r}", ""]
    for seed in ([] if "1" not in parts else [int(v) for v in args.seeds.split(",")]):
        lines += [f"## 1. mismatch and noise (plants of draw {seed})", "",
                  "| plant | start | after (true / σ) | iterations | ended | rose > 2σ/√N | "
                  "rose > σ | plain gain after (true / σ) |", "|---|---|---|---|---|---|---|---|"]
        worst, rises, big = 0.0, 0, 0
        for i, p in enumerate(plants(jh, args.plants, seed=seed)):
            plant = SimulatedPlant(jh.Model(p, jh.ACTUATOR1), ref, noise=sigma,
                                   seed=i + 100 * seed)
            state, true, measured = run(jh, learner, plant, args.iterations)
            final = float(np.sqrt(np.mean((plant.response(state.input)
                                           - np.asarray(ref.displacement)) ** 2)) / ref.scale)
            pairs = list(zip(measured, measured[1:], strict=False))
            rose = sum(b > a + 2 * sigma / np.sqrt(N) + 1e-3 * a for a, b in pairs)
            jump = sum(b > a + sigma for a, b in pairs)
            plain = plain_gain(learner, SimulatedPlant(jh.Model(p, jh.ACTUATOR1), ref,
                                                       noise=sigma, seed=i + 100 * seed),
                               args.iterations)
            worst, rises, big = max(worst, final / sigma), rises + rose, big + jump
            lines.append(f"| {i} | {true[0]:.3g} | {final / sigma:.2f} | {state.iteration} | "
                         f"{state.stopped or 'going on'} | {rose} | {jump} | "
                         f"{plain[-1] / sigma:.2f} |")
            print(lines[-1], flush=True)
        lines += ["", f"draw {seed}: worst true error after learning {worst:.2f} σ; iterations "
                  f"whose measured error rose by more than 2σ/√N (the noise of an rms error): "
                  f"{rises}, by more than σ: {big}", ""]
        print(lines[-2], flush=True)
    if "2" in parts:
        lines += ["## 2. an unmodelled mode at 1.5–3 kHz", "",
                  "| plant | mode (Hz) | start | after 20 (true / σ) | max measured / first | "
                  "ended |", "|---|---|---|---|---|---|"]
        rng = np.random.default_rng(7)
        for i, p in enumerate(plants(jh, args.plants, seed=1)):
            f = float(rng.uniform(1500.0, 3000.0))
            plant = SimulatedPlant(jh.Model(p, jh.ACTUATOR1), ref, noise=sigma, seed=i,
                                   mode=(f, 0.05))
            state, true, measured = run(jh, learner, plant, 20)
            final = float(np.sqrt(np.mean((plant.response(state.input)
                                           - np.asarray(ref.displacement)) ** 2)) / ref.scale)
            lines.append(f"| {i} | {f:.0f} | {true[0]:.3g} | {final / sigma:.2f} | "
                         f"{max(measured) / measured[0]:.2f} | {state.stopped or 'going on'} "
                         f"(band {state.band:.4g} Hz) |")
            print(lines[-1], flush=True)
        lines.append("")
    if "3" in parts:
        lines += ["## 3. delay (samples): found at the first step", "",
                  "| plant | 1 | 2 | 3 | 4 | 5 |", "|---|---|---|---|---|---|"]
        for label, p in [("exact model", jh.TABLE1_TRUE), *[(f"10 % off #{i}", q) for i, q in
                                                             enumerate(plants(jh, 5, seed=2))]]:
            cells = []
            for d in range(1, 6):
                plant = SimulatedPlant(jh.Model(p, jh.ACTUATOR1), ref, noise=sigma, delay=d)
                s = learner.step(learner.init(), plant.measure(learner.init().input))
                rep = s.reports[-1]
                cells.append(f"{rep.lag:+.2f} → {rep.delay}")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
        lines.append("")
    if "4" in parts:
        lines += ["## 4. an unreachable reference (1.3× the stroke)", ""]
        far = jh.sinusoidal_reference(100.0, 0.65 * 92.8e-6, 46.4e-6)
        for attempt in ("first (compiles)", "again"):
            t0 = time.perf_counter()
            comp = jh.compensate(model, far, current_limit=2.5)
            lines.append(f"- {attempt}: {time.perf_counter() - t0:.2f} s, {comp.steps} steps, "
                         f"{comp.outcome}; {len(comp.unreachable)} unreachable stretches, the "
                         f"first: {comp.unreachable[0] if comp.unreachable else '—'}")
            print(lines[-1], flush=True)
    if "5" in parts:
        lines += ["## 5. a true acquisition delay on plants 10 % off: true error after "
                  f"{args.iterations} iterations", "",
                  "| delay (samples) | plants within 2σ | median | worst |", "|---|---|---|---|"]
        seeds = [int(v) for v in args.seeds.split(",")]
        r = np.asarray(ref.displacement)
        for d in (1, 2):
            finals = []
            for seed in seeds:
                for i, p in enumerate(plants(jh, args.plants, seed=seed)):
                    model_p = jh.Model(p, jh.ACTUATOR1)
                    late = SimulatedPlant(model_p, ref, noise=sigma, delay=d,
                                          seed=i + 100 * seed)
                    state, _, _ = run(jh, learner, late, args.iterations)
                    # (the actuator's own displacement: the plant without the acquisition)
                    y = SimulatedPlant(model_p, ref).response(state.input)
                    finals.append(float(np.sqrt(np.mean((y - r) ** 2)) / ref.scale) / sigma)
            f = np.array(finals)
            lines.append(f"| {d} | {int(np.sum(f <= 2.0))}/{f.size} | {np.median(f):.2f} σ | "
                         f"{f.max():.2f} σ |")
            print(lines[-1], flush=True)
        lines.append("")
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

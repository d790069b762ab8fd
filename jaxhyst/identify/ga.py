"""Genetic-algorithm operators of the paper (§3.3) as pure, keyed functions.

Everything works in box coordinates u ∈ [0, 1]ⁿ (θ = d + (b − d)·u), so the operators
know nothing of the model. Per-individual operators are written for one individual and
vmapped over split keys by the generation steps at the bottom of this file.

Choices (the paper is silent or ambiguous; see docs/identification.md):
- ``pm`` is a probability per gene (parameter): a mutated BCGA gene flips one random bit
  of its p bits, a mutated FCGA gene gets a non-uniform mutation. (Per bit, pm = 0.05
  would flip 8 of the 160 bits of every individual: a random search.)
- Crossover pairs consecutive selected individuals (0–1, 2–3, …), each pair crossing
  with probability ``pc``; the two elites are copied unchanged.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

# -- binary coding (BCGA) -----------------------------------------------------------------


def encode(u, bits: int):
    """Box coordinates u (..., n) → bit array (..., n, bits), most significant bit first,
    with v = round(u·(2^p − 1))."""
    levels = 2**bits - 1
    v = jnp.round(jnp.clip(u, 0.0, 1.0) * levels).astype(jnp.int64)
    shifts = jnp.arange(bits - 1, -1, -1)
    return ((v[..., None] >> shifts) & 1).astype(jnp.uint8)


def decode(b):
    """Bit array (..., n, bits) → u = v/(2^p − 1) ∈ [0, 1] (paper: θ = d + v(b − d)/(2^p − 1))."""
    bits = b.shape[-1]
    weights = 2 ** jnp.arange(bits - 1, -1, -1, dtype=jnp.int64)
    v = jnp.sum(b.astype(jnp.int64) * weights, axis=-1)
    return v.astype(jnp.float64) / (2**bits - 1)


def single_point_crossover(key, a, b):
    """Cut two bit strings (shape (L,)) at one random point in 1..L−1 and swap the tails."""
    L = a.shape[0]
    point = jax.random.randint(key, (), 1, L)
    tail = jnp.arange(L) >= point
    return jnp.where(tail, b, a), jnp.where(tail, a, b)


def bit_flip_mutation(key, genes, pm):
    """Each gene (row of ``genes``, shape (n, p)) mutates with probability pm by flipping
    one uniformly chosen bit."""
    n, p = genes.shape
    k1, k2 = jax.random.split(key)
    mutate = jax.random.uniform(k1, (n,)) < pm
    which = jax.random.randint(k2, (n,), 0, p)
    flip = mutate[:, None] & (jnp.arange(p)[None, :] == which[:, None])
    return jnp.where(flip, 1 - genes, genes).astype(genes.dtype)


# -- floating-point coding (FCGA) --------------------------------------------------------


def arithmetic_crossover(key, x, z):
    """x' = η·x + (1 − η)·z, z' = (1 − η)·x + η·z with η ~ U[0, 1] (children inside the
    parents' box)."""
    eta = jax.random.uniform(key, ())
    return eta * x + (1 - eta) * z, (1 - eta) * x + eta * z


def non_uniform_mutation(key, x, generation, total_generations, pm, beta: float = 5.0):
    """Michalewicz's non-uniform mutation in the unit box, per gene with probability pm:
    x + Δ(i, 1 − x) or x − Δ(i, x) with equal probability, Δ(i, y) = y·(1 − μ^((1−i/T)^β)),
    μ ~ U[0, 1]. Steps shrink to 0 as the generation i approaches T."""
    k1, k2, k3 = jax.random.split(key, 3)
    n = x.shape[0]
    mutate = jax.random.uniform(k1, (n,)) < pm
    up = jax.random.uniform(k2, (n,)) < 0.5
    mu = jax.random.uniform(k3, (n,))
    frac = jnp.clip(1.0 - generation / total_generations, 0.0, 1.0)
    shrink = 1.0 - mu ** (frac**beta)
    moved = jnp.where(up, x + (1.0 - x) * shrink, x - x * shrink)
    return jnp.where(mutate, jnp.clip(moved, 0.0, 1.0), x)


# -- selection -----------------------------------------------------------------------------


def roulette_wheel(key, fitness, n: int):
    """n indices drawn with probability F_j/ΣF (all-zero fitness → uniform)."""
    f = jnp.where(jnp.isfinite(fitness) & (fitness > 0), fitness, 0.0)
    total = jnp.sum(f)
    probs = jnp.where(total > 0, f / jnp.where(total > 0, total, 1.0), 1.0 / f.shape[0])
    return jax.random.choice(key, f.shape[0], (n,), replace=True, p=probs)


def elitist_selection(key, fitness, n: int, elites: int = 2):
    """Indices of the next generation's parents: the ``elites`` fittest first (they pass
    on unchanged), then n − elites roulette-wheel draws."""
    f = jnp.where(jnp.isfinite(fitness), fitness, 0.0)
    best = jnp.argsort(-f)[:elites]
    return jnp.concatenate([best, roulette_wheel(key, f, n - elites)])


# -- one generation of reproduction -----------------------------------------------------------


def _pairwise(key, parents, pc, crossover):
    """Cross consecutive pairs of ``parents`` (shape (m, ...), m even) with probability pc."""
    m = parents.shape[0]
    a, b = parents[0::2], parents[1::2]
    kx, kc = jax.random.split(key)
    keys = jax.random.split(kx, m // 2)
    ca, cb = jax.vmap(crossover)(keys, a, b)
    do = jax.random.uniform(kc, (m // 2,)) < pc
    shape = (m // 2,) + (1,) * (a.ndim - 1)
    ca = jnp.where(do.reshape(shape), ca, a)
    cb = jnp.where(do.reshape(shape), cb, b)
    return jnp.stack([ca, cb], axis=1).reshape(parents.shape)


def bcga_offspring(key, genes, fitness, pc, pm, elites: int = 2):
    """Next BCGA population from genes (q, n, p) and their fitness (q,)."""
    q, n, p = genes.shape
    ks, kc, km = jax.random.split(key, 3)
    idx = elitist_selection(ks, fitness, q, elites)
    parents = genes[idx]
    rest = parents[elites:]
    odd = rest.shape[0] % 2
    body = rest[: rest.shape[0] - odd].reshape(-1, n * p)
    crossed = _pairwise(kc, body, pc, single_point_crossover).reshape(-1, n, p)
    rest = jnp.concatenate([crossed, rest[rest.shape[0] - odd :]], axis=0)
    keys = jax.random.split(km, rest.shape[0])
    rest = jax.vmap(bit_flip_mutation, in_axes=(0, 0, None))(keys, rest, pm)
    return jnp.concatenate([parents[:elites], rest], axis=0)


def fcga_offspring(key, U, fitness, generation, total_generations, pc, pm, beta=5.0,
                   elites: int = 2):
    """Next FCGA population from U (q, n) and fitness (q,) at generation i of T."""
    q, n = U.shape
    ks, kc, km = jax.random.split(key, 3)
    idx = elitist_selection(ks, fitness, q, elites)
    parents = U[idx]
    rest = parents[elites:]
    odd = rest.shape[0] % 2
    crossed = _pairwise(kc, rest[: rest.shape[0] - odd], pc, arithmetic_crossover)
    rest = jnp.concatenate([crossed, rest[rest.shape[0] - odd :]], axis=0)
    keys = jax.random.split(km, rest.shape[0])
    rest = jax.vmap(non_uniform_mutation, in_axes=(0, 0, None, None, None, None))(
        keys, rest, generation, total_generations, pm, beta
    )
    return jnp.concatenate([parents[:elites], rest], axis=0)


class GAState(eqx.Module):
    """Everything a generation changes; a checkpoint is this state serialized."""

    key: jax.Array  # PRNG key (uint32, (2,))
    genes: jax.Array  # BCGA population, (q1, n, bits) uint8
    U: jax.Array  # FCGA population in box coordinates, (q2, n)
    generation: jax.Array  # generations completed
    best_u: jax.Array  # (n,)
    best_cost: jax.Array
    evaluations: jax.Array
    failures: jax.Array
    local_steps: jax.Array
    step_size: jax.Array  # the local search's damping (1/h) or radius, carried over
    last_local_u: jax.Array  # (n,) where the last local search converged
    has_last_local: jax.Array  # bool

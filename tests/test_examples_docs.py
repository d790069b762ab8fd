"""The documented composability example runs and does what the docs say (its gradient
against differences); the site build and the other examples: test_docs_site.py."""

from __future__ import annotations

import os
import runpy

import jax.numpy as jnp
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_composability_example():
    ns = runpy.run_path(os.path.join(ROOT, "examples", "composability.py"))
    loss, x0, grad = ns["loss"], ns["x0"], np.asarray(ns["grad"])
    # the reverse-mode gradient matches central differences
    for i in range(3):
        h = 1e-5
        e = jnp.zeros(3).at[i].set(h)
        fd = (float(loss(x0 + e)) - float(loss(x0 - e))) / (2 * h)
        assert abs(grad[i] - fd) <= 1e-5 * np.max(np.abs(grad)), (i, grad[i], fd)
    assert float(loss(ns["sol"].value)) < 1e-5 * float(loss(x0))
    found = ns["found"]
    assert abs(float(found.a) / 7012.0 - 1) < 1e-3
    assert abs(float(found.k) / 3283.0 - 1) < 1e-2 and abs(float(found.c) / 0.18 - 1) < 1e-2
    assert ns["losses"].shape == (16,) and np.all(np.isfinite(ns["losses"]))

"""The documented composability example runs and does what the docs say (its gradient
against differences); the site build and the other examples: test_docs_site.py."""

from __future__ import annotations

import os
import runpy

import jax.numpy as jnp
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.docs  # (an example of the site: its step, beside the site's build)
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


def test_an_interrupted_site_build_resumes_after_its_finished_steps(tmp_path, monkeypatch,
                                                                   capsys):
    """docs/generate.py stamps each step that finished without a failure with the
    sources' fingerprint; a second run of the same sources keeps those steps (a build
    stopped part-way resumes at the step it was in), reruns a failed or unstamped one,
    and writes the site's fingerprint only when every step is done."""
    gen = runpy.run_path(os.path.join(ROOT, "docs", "generate.py"))
    main, steps = gen["main"], gen["STEPS"]
    ran = []

    def fake(name, rc):
        def step(s):
            ran.append(name)
            s.status[name] = rc
        return step

    codes = {name: 0 for name in steps}
    codes[list(steps)[1]] = 1  # the second step fails (as a build stopped in it)
    for name in steps:
        monkeypatch.setitem(steps, name, fake(name, codes[name]))
    assert main([str(tmp_path)]) == 1
    assert ran == list(steps) and not (tmp_path / "generated" / "fingerprint").exists()
    ran.clear()
    codes[list(steps)[1]] = 0
    monkeypatch.setitem(steps, list(steps)[1], fake(list(steps)[1], 0))
    assert main([str(tmp_path)]) == 0
    assert ran == [list(steps)[1]]  # only the step that had not finished
    assert "kept from an earlier run" in capsys.readouterr().out
    assert (tmp_path / "generated" / "fingerprint").read_text() == gen["fingerprint"]()

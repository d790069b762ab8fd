"""Every reach into JAX's extension or private API works on this JAX: none of the
fallbacks of `jaxhyst._jax_compat` is taken, and each name does its job. Runs in the
oldest-versions environment of .ci/run too (marker ``compat``)."""

from __future__ import annotations

import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst import _jax_compat as compat

pytestmark = pytest.mark.compat
ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_no_fallback_is_taken():
    jnp.ones(2).sum().block_until_ready()
    assert compat.backends_are_initialized()  # (JAX has computed by now)
    assert compat.FALLBACKS == set(), compat.FALLBACKS


def test_jit_and_vmap_are_told_apart():
    seen = {}

    def probe(x, tag):
        seen[tag] = (compat.under_jit(), compat.under_vmap())
        return x

    jax.jit(lambda x: probe(x, "jit"))(1.0)
    jax.vmap(lambda x: probe(x, "vmap"))(jnp.ones(2))
    jax.grad(lambda x: probe(x, "grad"))(1.0)
    assert seen["jit"] == (True, False)
    assert seen["vmap"] == (False, True)
    assert seen["grad"] == (False, False)


def test_values_are_read_under_an_eager_grad_but_not_inside_jit():
    got = {}

    def f(x, tag):
        got[tag] = compat.concrete_value(x)
        return x * x

    jax.grad(lambda x: f(x, "grad"))(3.0)
    jax.jit(lambda x: f(x, "jit"))(3.0)
    assert float(got["grad"]) == 3.0 and got["jit"] is None
    # what it serves: a bad parameter under an eager grad is named, not a silent NaN
    drive = jh.sinusoidal_field(10.0, 1e4, 0.0, samples_per_period=20)
    with pytest.raises(ValueError, match="Parameter a = -1"):
        jax.grad(lambda a: jh.simulate(jh.TABLE1_TRUE.replace(a=a), jh.ACTUATOR1,
                                       drive).y.sum())(-1.0)


def test_a_traced_jaxpr_evaluates_to_the_function():
    closed = jax.make_jaxpr(lambda x: jnp.sin(x) * 2.0)(0.3)
    np.testing.assert_allclose(compat.jaxpr_as_fun(closed)(0.3)[0], np.sin(0.3) * 2.0)


def test_the_internals_are_reached_in_the_compatibility_module_only():
    pattern = re.compile(r"DO_NOT_USE|jax\._src|jax\.extend")
    found = [str(p.relative_to(ROOT)) for p in (ROOT / "jaxhyst").rglob("*.py")
             if pattern.search(p.read_text(encoding="utf-8"))]
    assert found == ["jaxhyst/_jax_compat.py"], found


def test_the_xla_loop_setting_is_in_effect():
    assert jh.cpu_loop_kernels().startswith("in effect"), jh.cpu_loop_kernels()


def test_the_xla_emitter_setting_is_in_effect():
    assert jh.cpu_kernel_emitters().startswith("in effect"), jh.cpu_kernel_emitters()


_EMITTER_CHECK = """
import json, os, numpy as np, jax, jaxhyst as jh
drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=64)
out = {"state": jh.cpu_kernel_emitters(), "flags": os.environ.get("XLA_FLAGS", "")}
for name, form in (("energy", jh.EnergyBasedJA()), ("play", jh.PlayJA(spread=0.6, cells=8))):
    y = lambda x: jh.simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive,
                                        form).M
    x = jh.TABLE1_TRUE.to_array()
    out[name] = np.asarray(y(x)).tolist()
    out[name + "_jac"] = np.asarray(jax.jit(jax.jacfwd(y))(x)).tolist()
print(json.dumps(out))
"""


def test_the_two_emitters_give_the_same_paths_and_jacobians():
    """XLA:CPU's earlier kernel emitters (jaxhyst's default, for compile time) and its MLIR
    fusion emitters (where the user chooses them) give the same paths and Jacobians of
    the JA and pinning-cell forms (the two processes run side by side)."""
    import json
    import os
    import subprocess
    import sys

    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS",
                                                             "JAXHYST_XLA_FLAGS")}
    procs = [subprocess.Popen([sys.executable, "-c", _EMITTER_CHECK], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env={**base, **extra})
             for extra in ({}, {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"})]
    runs = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        runs.append(json.loads(out.strip().splitlines()[-1]))
    assert runs[0]["state"] == "in effect", runs[0]["state"]
    assert runs[1]["state"].startswith("not applied: XLA_FLAGS chooses"), runs[1]["state"]
    for key in ("energy", "energy_jac", "play", "play_jac"):
        a, b = np.asarray(runs[0][key]), np.asarray(runs[1][key])
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-11 * np.max(np.abs(a)),
                                   err_msg=key)


@pytest.mark.parametrize("env, state, applied", [
    ({}, "in effect", True),
    ({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=false"}, "in effect (set by the user)",
     True),
    ({"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}, "not applied: XLA_FLAGS", False),
    ({"JAXHYST_XLA_FLAGS": "off"}, "disabled by JAXHYST_XLA_FLAGS", False)])
def test_the_emitter_setting_is_applied_unless_the_user_chooses(env, state, applied):
    import os
    import subprocess
    import sys

    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS",
                                                             "JAXHYST_XLA_FLAGS")}
    code = ("import os, jaxhyst\nprint(jaxhyst.cpu_kernel_emitters())\n"
            "print(os.environ.get('XLA_FLAGS', ''))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**base, **env}, timeout=120)
    assert r.returncode == 0, r.stderr
    got, flags = (r.stdout.strip().splitlines() + [""])[:2]
    assert got.startswith(state), got
    assert ("--xla_cpu_use_fusion_emitters=false" in flags.split()) == applied, flags
    assert "PerformanceWarning" not in r.stderr, r.stderr


@pytest.mark.parametrize("setup, env", [
    ("import jax; jax.numpy.ones(2).sum().block_until_ready()", {}),  # JAX started first
    ("", {"XLA_FLAGS": "--xla_backend_extra_options=xla_cpu_enable_fast_math=false"}),
])
def test_a_warning_says_once_when_the_xla_setting_cannot_be_applied(setup, env):
    import os
    import subprocess
    import sys

    code = f"{setup}\nimport jaxhyst\nimport jaxhyst.model\nprint(jaxhyst.cpu_loop_kernels())"
    base = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # (set by jaxhyst)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**base, "JAXHYST_XLA_FLAGS": "", **env}, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().startswith("not applied"), r.stdout
    assert r.stderr.count("PerformanceWarning") == 1, r.stderr
    assert "slower" in r.stderr and "JAXHYST_XLA_FLAGS=off" in r.stderr


@pytest.mark.parametrize("flags, warned", [
    ("--xla_backend_optimization_level=0", 1), ("--xla_backend_optimization_level=1", 0)])
def test_a_warning_says_once_that_llvm_o0_computes_the_pinning_cells_wrongly(flags, warned):
    import os
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", "import jaxhyst"], capture_output=True,
                       text=True, env={**os.environ, "XLA_FLAGS": flags}, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("xla_backend_optimization_level=0") == warned, r.stderr
    assert ("pinning-cell forms" in r.stderr) == bool(warned), r.stderr


def test_compiled_programs_are_released_before_the_mapping_limit(monkeypatch):
    """XLA aborts a process that reaches vm.max_map_count inside a compilation; between
    units of work the compiled programs are dropped where half of it is in use."""
    from jaxhyst import _mappings

    used = _mappings.mappings_in_use()
    if used is None or _mappings._limit() is None:
        pytest.skip("no /proc/self/maps here")
    f = jax.jit(lambda x: jnp.sin(x) * 3.0)
    f(jnp.ones(7)).block_until_ready()
    assert f._cache_size() == 1
    assert not _mappings.release_if_crowded()  # far below the limit: nothing dropped
    assert f._cache_size() == 1
    monkeypatch.setattr(_mappings, "_limit", lambda: used // 4)
    assert _mappings.release_if_crowded()
    assert f._cache_size() == 0


def test_a_release_drops_the_executables_and_keeps_the_traces():
    """The mappings go with the compiled programs; a function called again after a
    release is compiled again (or loaded) but not traced again, and computes the same."""
    from jaxhyst import _mappings

    traced = []

    def body(x):
        traced.append(1)
        return jnp.cumsum(jnp.sin(x) * jnp.arange(x.shape[0]))

    f = jax.jit(body)
    x = jnp.linspace(0.0, 1.0, 37)
    want = np.asarray(f(x))
    programs = [jax.jit(lambda x, k=k: jnp.cos(x * k).sum()) for k in range(40)]
    for g in programs:
        g(x).block_until_ready()
    before = _mappings.mappings_in_use()
    compat.release_compiled()
    assert f._cache_size() == 0
    after = _mappings.mappings_in_use()
    if before is not None:  # (Linux: the 41 programs' mappings are gone)
        assert after < before - 40, (before, after)
    np.testing.assert_array_equal(np.asarray(f(x)), want)
    assert len(traced) == 1  # (not traced again)
    assert f._cache_size() == 1


def test_the_test_profile_hears_jaxs_trace_and_compile_events(tmp_path):
    """tests/compile_profile.py names JAX's duration events: a new program fires them."""
    from compile_profile import Profile, summary

    profile = Profile(str(tmp_path))
    profile.current = "a::test"
    try:
        jax.jit(lambda x: jnp.sin(x) * 3.0 + 0.123456)(jnp.arange(7.0)).block_until_ready()
    finally:
        jax.monitoring.unregister_event_duration_listener(profile._event)
    seen = profile.seconds["a::test"]
    assert seen["trace_n"] >= 1 and seen["lower_n"] >= 1 and seen["compile_n"] >= 1, seen
    profile.seconds["a::test"]["wall"] = 1.0
    profile.pytest_sessionfinish(None)
    text = summary(str(tmp_path))
    assert "a::test" in text and "programs compiled or loaded" in text

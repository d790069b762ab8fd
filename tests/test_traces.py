"""Traces kept on disk (`jaxhyst._traces`, issue 45): a later process loads a fit's
programs instead of tracing them, with the same values; the key tells apart everything
that changes a trace; what it cannot describe, or a damaged file, falls back to tracing."""

from __future__ import annotations

import pickle

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst import _kept_files, _traces
from jaxhyst.identify import _stepped
from jaxhyst.identify.problem import cost_at

DRIVE = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=60)
FIXED = ["Ms", "lambda_s", "alpha", "E", "Kz", "Mz", "Cz"]


def _problem(substeps=2, drive=DRIVE):
    return jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS,
                                fixed=FIXED, substeps=substeps)


def _shaped(substeps=2, drive=DRIVE):
    """`_problem`'s structure with data that simulate nothing: a key depends on shapes
    and structure only (a simulation under each patched constant would compile)."""
    data = np.linspace(0.0, 1e-6, drive.t.shape[0] - drive.run_in)
    fixed = {n: float(getattr(jh.TABLE1_TRUE, n)) for n in FIXED}
    return jh.Problem(data, drive, jh.ACTUATOR1, jh.ParameterSpace(jh.TABLE1_BOUNDS, fixed),
                      substeps=substeps)


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """Traces kept in ``tmp_path`` (the compilation cache stays where it is), none in
    memory before or after."""
    if not jax.config.jax_compilation_cache_dir:
        jh.enable_compilation_cache(tmp_path / "xla")
    monkeypatch.delenv("JAXHYST_TRACE_CACHE", raising=False)
    monkeypatch.setattr(_traces, "_directory", lambda: tmp_path / "traces")
    _traces.forget()
    yield
    _traces.forget()


def _fit(problem):
    starts = jh.Parameters.from_array(np.stack([
        jh.TABLE1_TRUE.replace(a=a, k=k, c=c).to_array()
        for a, k, c in ((6000.0, 3800.0, 0.15), (8000.0, 2500.0, 0.3))]))
    return jh.multistart(problem, starts, max_steps=8, report=False)


@pytest.mark.compat  # (jax.export's serialization and Exported's fields, oldest jax too)
@pytest.mark.extended  # (three multi-start fits: the same programs traced, loaded, plain)
def test_a_later_process_loads_a_fits_programs_with_the_same_values(kept, tmp_path,
                                                                    monkeypatch):
    problem = _problem()
    first = _fit(problem)
    files = _files(tmp_path)
    assert files  # (the start, step and end programs of the batch)
    _traces.forget()  # (as a new process: nothing in memory)
    traced = []
    real = _stepped.advance
    monkeypatch.setattr(_stepped, "advance", lambda *a: traced.append(1) or real(*a))
    again = _fit(problem)
    assert not traced  # the step's program was loaded, not traced
    # nothing new was kept: the reloaded outputs keep their weak types, so the next
    # chunk's key is the first one's
    assert _files(tmp_path) == files
    monkeypatch.setattr(_stepped, "advance", real)
    monkeypatch.setenv("JAXHYST_TRACE_CACHE", "off")  # (plain eqx.filter_jit)
    plain = _fit(problem)
    for fit in (again, plain):
        assert np.array_equal(np.asarray(fit.params.to_array()),
                              np.asarray(first.params.to_array()))
        assert fit.cost == first.cost and fit.steps == first.steps


def test_the_key_tells_apart_what_changes_a_trace(kept, monkeypatch):
    def key(*args):
        leaves, treedef = jax.tree.flatten(args)
        return _traces._key("jaxhyst.identify.problem.cost_at", leaves, treedef)

    z = jnp.zeros(3)
    base = key(_shaped(), z)
    assert key(_shaped(), jnp.ones(3)) == base  # (values of arrays are data)
    assert key(_shaped(substeps=4), z) != base  # (structure)
    assert key(_shaped(), jnp.zeros(4)) != base  # (a shape)
    assert key(_shaped(), jnp.asarray(0.0) + z) == base
    assert key(_shaped(), 1.0) != key(_shaped(), 2.0)  # (a Python number is static)
    longer = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=64)
    assert key(_shaped(drive=longer), z) != base
    from jaxhyst.model import interval, play

    monkeypatch.setattr(play, "NEWTON_STEPS", play.NEWTON_STEPS + 1)  # (a constant)
    assert key(_shaped(), z) != base
    monkeypatch.undo()
    monkeypatch.setattr(interval, "FORCE_BRANCH_FREE", True)  # (the branch-free loops)
    assert key(_shaped(), z) != base
    monkeypatch.undo()
    from jaxhyst.model.simulate import plain_vmap

    with plain_vmap():  # (a switch that is not a constant)
        assert key(_shaped(), z) != base
    assert key(_shaped(), z) == base
    # static values equal by == but of other types, asked twice (the second time from
    # the remembered structures): told apart each time
    keys = [key(_Static(v), z) for v in (1, 1.0, True, 1, 1.0, True)]
    assert len(set(keys[:3])) == 3 and keys[3:] == keys[:3]


class _Static(eqx.Module):
    value: object = eqx.field(static=True)


def _files(tmp_path) -> set:
    return {p for p in (tmp_path / "traces").rglob("*") if p.is_file()}


def test_what_the_key_cannot_describe_is_traced_as_before(kept, tmp_path):
    problem = _problem()
    z = jnp.full(3, 0.3)
    before = _files(tmp_path)
    value = cost_at(problem, z)
    mine = _files(tmp_path) - before
    assert mine  # (the cost's program)
    with pytest.raises(_traces._Undescribed):
        _traces._describe(lambda x: x)  # (a closure's captured values are not in the key)
    with pytest.raises(_traces._Undescribed):
        _traces._describe(object())
    assert _traces._describe(jh.Losses(0.1, 0.2)) == _traces._describe(jh.Losses(0.1, 0.2))
    assert _traces._describe(jh.Losses(0.1, 0.2)) != _traces._describe(jh.Losses(0.1, 0.3))
    # a damaged file is traced again and replaced
    for path in mine:
        path.write_bytes(b"not a kept trace")
    _traces.forget()
    assert float(cost_at(problem, z)) == float(value)
    assert all(p.read_bytes() != b"not a kept trace" for p in mine)


def test_calls_inside_a_trace_are_plain(kept, tmp_path):
    problem = _problem()
    before = _files(tmp_path)
    grad = jax.grad(lambda v: cost_at(problem, v))(jnp.full(3, 0.3))  # (under a transform)
    assert _files(tmp_path) == before
    assert np.all(np.isfinite(np.asarray(grad)))
    assert _stepped._advance_batch.__wrapped__.__name__ == "_advance_batch"


def test_operator_tags_are_loaded_as_the_live_objects():
    """A lineax operator's tags (objects compared by identity) are part of its structure:
    the kept files load them as the live tags, which plain pickling does not."""
    tags = frozenset({lx.positive_semidefinite_tag})
    assert _kept_files.loads(_kept_files.dumps(tags)) == tags
    assert pickle.loads(pickle.dumps(tags)) != tags  # (why the files need it)


@pytest.mark.extended  # (BFGS, a solver beyond the paper's, is in the extended step too)
def test_a_minimisers_state_with_operator_tags_is_loaded_equal_to_the_live_one(kept, tmp_path):
    """A BFGS state holds its inverse Hessian as a lineax operator with tags: a kept
    start loads them as the live tags, so a later process's steps combine with it (they
    failed with a pytree structure error) and its solve is the first one's."""
    problem, start = _problem(), jh.TABLE1_TRUE.replace(a=6000.0, k=3800.0, c=0.15)
    first = jh.solve(problem, start, solver="bfgs", max_steps=3, report=False)
    assert _files(tmp_path) and not [p for p in _files(tmp_path) if p.suffix == ".not-kept"]
    _traces.forget()  # (as a new process: the start, steps and end loaded from the files)
    again = jh.solve(problem, start, solver="bfgs", max_steps=3, report=False)
    assert again.cost == first.cost and again.steps == first.steps
    assert np.array_equal(np.asarray(again.values), np.asarray(first.values))

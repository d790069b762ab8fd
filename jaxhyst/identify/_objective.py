"""A problem as Optimistix sees it: the function ``fn(y, args)`` a solver iterates on.

Every solver works in the unconstrained coordinates z of the problem's space (bounds by
construction). Least-squares solvers see the residual vector with its Jacobian from
``jax.jacfwd`` (handed over whole through a custom JVP, `jacobian_linearized`);
minimisers (``bfgs``, any ``optx.AbstractMinimiser``) see the cost and its reverse-mode
gradient. Never finite differences.
"""

from __future__ import annotations

import equinox as eqx
import jax
import optimistix as optx

from .problem import AbstractProblem
from .solvers import BoxTermination


def jacobian_linearized(fn):
    """``fn`` (a residual vector of a few parameters) with a custom JVP that forms the
    whole Jacobian by one forward-mode pass (`jax.jacfwd`, primal computed once) and
    returns J·t.

    Optimistix linearizes the residuals once per step and then applies the linear map
    to a basis (to materialise J for its QR) and its transpose (for Jᵀr). Linearizing
    the simulation itself would store its intermediates and replay the tangent for
    each use; with this rule the stored linearization is just the matrix J, so each step
    costs one jacfwd. Values and derivatives are unchanged (the rule is the exact
    derivative); it differentiates again (jacfwd inside) if needed.

    The Jacobian is formed by one jitted function of (fn, z, args), so a program that
    linearizes ``fn`` more than once (Optimistix's ``init`` for the shapes, then
    ``step``) traces it once, provided ``fn`` is the same pytree each time (a bound
    method of an equinox Module, as ``problem.residuals``, is one: its arrays are
    arguments, the rest is compared by equality).
    """

    @jax.custom_jvp
    def f(z, args=None):
        return fn(z, args)

    @f.defjvp
    def f_jvp(primals, tangents):
        z, args = primals
        t, _ = tangents
        J, r = _jacobian_and_value(fn, z, args)
        return r, J @ t

    return f


@eqx.filter_jit
def _jacobian_and_value(fn, z, args):
    """(∂fn/∂z, fn(z, args)) by one forward-mode pass."""

    def both(z):
        r = fn(z, args)
        return r, r

    return jax.jacfwd(both, has_aux=True)(z)


def objective(problem: AbstractProblem, solver):
    """(the solver as run, ``fn(y, args) -> (out, aux)``, options) as Optimistix sets them
    up for ``problem``: a minimiser sees the cost; a least-squares solver the residuals
    (a Gauss–Newton-family one wrapped in `BoxTermination`)."""
    if isinstance(solver, optx.AbstractMinimiser):
        return solver, (lambda y, args: (problem.cost(y, args), None)), {}
    wrapped = BoxTermination(solver) if isinstance(solver, optx.AbstractGaussNewton) \
        else solver
    res = jacobian_linearized(problem.residuals)
    return wrapped, (lambda y, args: (res(y, args), None)), {"jac": "fwd"}

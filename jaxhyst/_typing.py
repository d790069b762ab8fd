"""Array types with shapes for the public signatures (jaxtyping, as diffrax and
optimistix use). Dimensions: ``T`` samples of a drive, ``N = T − 1`` intervals, ``S``
RK4 substeps, ``n`` free parameters, ``K`` starts, ``P`` a population, ``*batch`` any
leading batch axes (a population, loops of a joint fit)."""

from __future__ import annotations

from jaxtyping import Array, ArrayLike, Bool, Complex, Float, Int

#: A real number as a 0-d array (one parameter, one constant), or a batch of them.
Real = Float[Array, "*batch"]
#: One sampled signal (times, field, magnetization, displacement …), shape (T,) or batched.
Signal = Float[Array, "*batch T"]

__all__ = ["Array", "ArrayLike", "Bool", "Complex", "Float", "Int", "Real", "Signal"]

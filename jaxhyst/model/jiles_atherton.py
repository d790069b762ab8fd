"""Jiles–Atherton magnetization: pluggable forms of the slope dM/dH.

A variant is a small ``equinox.Module``: abstract classes declare what a form provides,
the forms themselves are final (equinox's abstract-or-final rule: no concrete method is
overridden). `AbstractJAVariant` is the interface the integrator in
`jaxhyst.model.magnetization` calls — the slope dM/dH at applied field ``H`` (A/m) and
total magnetization ``M`` (A/m) while the field moves in direction ``delta`` (±1), the
δM switch distance with it, and Mirr — so a new form plugs in without touching the loop.
The built-in forms implement `AbstractAnhystereticForm`, which evaluates the Langevin
function once per call of ``evaluate`` (slope and switch distance together, the
integrator's hot path).

State is the *total* magnetization M. With He = H + α̃·M every quantity below is an
explicit function of (H, M), so no implicit equation has to be solved per step.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ..params import Parameters
from .langevin import langevin_and_slope


def anhysteretic(H, M, p: Parameters):
    """(Man, dMan/dHe): Man = Ms·L(He/a) with He = H + α̃·M (eqs 1–2); A/m and 1."""
    L, dL = langevin_and_slope((H + p.alpha * M) / p.a)
    return p.Ms * L, (p.Ms / p.a) * dL


def _pinned_ratio(numerator, denominator, active):
    """numerator/denominator where ``active``, else 0 — with no 0/0 in value or gradient."""
    safe = jnp.where(active, denominator, 1.0)
    return jnp.where(active, numerator / safe, 0.0)


class AbstractJAVariant(eqx.Module):
    """Interface of a Jiles–Atherton form (abstract; the built-in forms are final).

    - ``slope(H, M, delta, p, pinning=True)``: dM/dH (1) at field H (A/m) and
      magnetization M (A/m) with the field moving in direction ``delta`` = ±1.
      ``pinning=False`` forces the purely reversible branch; the integrator uses it to
      step exactly up to the point where δM switches on after a field reversal (a kink
      in dM/dH).
    - ``evaluate(H, M, delta, p, pinning=True)``: (dM/dH, d, dd/dH along the path M(H)
      of that slope), where d is the switch distance δ·(Man − M) (A/m): the
      irreversible term acts where d > 0, so where d ≤ 0 the slope must not depend on
      ``pinning`` (the integrator reuses the slope it evaluated there as the reversible
      one). A form without a δM switch returns d = 1 and dd/dH = 0.
      `evaluate_by_differentiation` forms it from a switch-distance function.
    - ``irreversible_magnetization(H, M, p)``: Mirr (A/m) implied by the state.

    Class constants: ``parameters`` names the `Parameters` fields the slope depends on
    (the derivative rule of the time loop differentiates with respect to those only);
    ``scales_with_Ms`` is True only if the slope has the form dM/dH = Ms·g(H, M/Ms) with g
    depending on Ms only through α̃·Ms, as in the three forms here with a δM switch (the
    derivative rule then forms ∂/∂Ms from ∂/∂α̃). Both keep their defaults unless a form
    states otherwise.
    """

    parameters: ClassVar[tuple[str, ...]] = ("Ms", "a", "k", "alpha", "c")
    scales_with_Ms: ClassVar[bool] = False

    @abc.abstractmethod
    def slope(self, H, M, delta, p: Parameters, pinning=True):
        """dM/dH at field H (A/m), magnetization M (A/m), field direction delta = ±1."""

    @abc.abstractmethod
    def evaluate(self, H, M, delta, p: Parameters, pinning=True):
        """(dM/dH, switch distance (A/m), its rate d/dH along the path): see the class."""

    @abc.abstractmethod
    def irreversible_magnetization(self, H, M, p: Parameters):
        """Mirr (A/m) implied by the state (H, M)."""


def evaluate_by_differentiation(variant: AbstractJAVariant, distance_to_switch, H, M, delta,
                                p: Parameters, pinning=True):
    """`AbstractJAVariant.evaluate` for a form given as its slope and a switch-distance
    function ``distance_to_switch(H, M, delta, p)`` (A/m): the rate along the path by
    one forward-mode derivative. A form of your own can return this from ``evaluate``."""
    s = variant.slope(H, M, delta, p, pinning)
    d, rate = jax.jvp(lambda H, M: distance_to_switch(H, M, delta, p), (H, M),
                      (jnp.ones_like(H), jnp.ones_like(M) * s))
    return s, d, rate


def mirr_of_reversible_fraction(H, M, p: Parameters):
    """Mirr = (M − c·Man)/(1 − c) (A/m) of M = (1 − c)·Mirr + c·Man (eqs 4–5); M itself
    where c ≥ 1 (no irreversible part)."""
    Man, _ = anhysteretic(H, M, p)
    reversible_only = p.c >= 1.0
    safe = jnp.where(reversible_only, 1.0, 1.0 - p.c)
    return jnp.where(reversible_only, M, (M - p.c * Man) / safe)


class AbstractAnhystereticForm(AbstractJAVariant):
    """A form whose slope is an explicit function of M, δ and the anhysteretic (Man and
    Man' = dMan/dHe at He = H + α̃·M): implement `slope_from_anhysteretic` and
    ``irreversible_magnetization``. The Langevin function is evaluated once per
    `evaluate` (slope and switch distance together, the integrator's hot path).
    ``has_switch`` (class constant, default True): the irreversible term obeys the δM
    rule, with switch distance δ·(Man − M); False for a form without it."""

    has_switch: ClassVar[bool] = True

    @abc.abstractmethod
    def slope_from_anhysteretic(self, M, delta, p: Parameters, Man, dMan, pinning=True):
        """dM/dH given Man (A/m) and dMan/dHe (1) at the current (H, M)."""

    def slope(self, H, M, delta, p: Parameters, pinning=True):
        Man, dMan = anhysteretic(H, M, p)
        return self.slope_from_anhysteretic(M, delta, p, Man, dMan, pinning)

    def evaluate(self, H, M, delta, p: Parameters, pinning=True):
        Man, dMan = anhysteretic(H, M, p)
        s = self.slope_from_anhysteretic(M, delta, p, Man, dMan, pinning)
        if not self.has_switch:  # the integrator never splits an interval
            return s, jnp.ones_like(s), jnp.zeros_like(s)
        # d/dH of δ·(Man − M) along M(H): dMan/dH = Man'·(1 + α̃·s)
        return s, delta * (Man - M), delta * (dMan * (1.0 + p.alpha * s) - s)


class EnergyBasedJA(AbstractAnhystereticForm):
    """The paper's form (eqs 1–5; Calkins, Smith & Flatau 2000), differentiated exactly.

    With M = (1 − c)·Mirr + c·Man(H + α̃M) (eqs 4–5) and eq 3 for dMirr/dH,

        dM/dH = [(1 − c)·χirr + c·Man'] / (1 − α̃·c·Man'),
        (1 − c)·χirr = δM·(1 − c)·D / ((1 − c)·δ·k − α̃·D),   D = Man − M,

    where Man' = dMan/dHe and D = (1 − c)(Man − Mirr). The denominator 1 − α̃cMan' is the
    exact chain rule through He (dropping it changes y by ~1e-3 relative). δM = 0 when the
    field moves away from the anhysteretic (δ·D < 0): no negative irreversible
    susceptibility. Where δ·((1−c)δk − α̃D) ≤ 0 (only possible for α̃ > 0, when the
    pinning term is overwhelmed) the irreversible part is taken as 0 rather than negative.
    """

    scales_with_Ms: ClassVar[bool] = True

    def slope_from_anhysteretic(self, M, delta, p: Parameters, Man, dMan, pinning=True):
        D = Man - M
        one_minus_c = 1.0 - p.c
        denominator = one_minus_c * delta * p.k - p.alpha * D
        active = (delta * D > 0) & (delta * denominator > 0) & pinning
        irreversible = _pinned_ratio(one_minus_c * D, denominator, active)
        return (irreversible + p.c * dMan) / (1.0 - p.alpha * p.c * dMan)

    def irreversible_magnetization(self, H, M, p: Parameters):
        return mirr_of_reversible_fraction(H, M, p)


class ClassicJA(AbstractAnhystereticForm):
    """The classic Jiles–Atherton form with reversible part Mrev = c·(Man − M):

        dM/dH = [δM·(Man − M)/(δ·k − α̃·(Man − M)) + c·Man'] / (1 + c),

    the textbook statement of the 1986 model (Jiles & Atherton, J. Magn. Magn. Mater. 61
    (1986) 48; in this closed form e.g. Jiles, Thoelke & Devine, IEEE Trans. Magn. 28
    (1992) 27). Man' = dMan/dHe with no feedback through He, as in those papers. From
    M = Mirr + c·(Man − M): Mirr = (1 + c)·M − c·Man.

    This is also the "dMan/dHe" form of Szewczyk et al. (R. Szewczyk, Materials 7 (2014)
    5109; the JAmodel toolbox, whose fits to the MnZn loops in ``shared/data`` use it):
    the same equation, term by term. Unlike the energy-based form, c = 1 still leaves a
    hysteretic (irreversible) part.
    """

    scales_with_Ms: ClassVar[bool] = True

    def slope_from_anhysteretic(self, M, delta, p: Parameters, Man, dMan, pinning=True):
        D = Man - M
        denominator = delta * p.k - p.alpha * D
        active = (delta * D > 0) & (delta * denominator > 0) & pinning
        irreversible = _pinned_ratio(D, denominator, active)
        return (irreversible + p.c * dMan) / (1.0 + p.c)

    def irreversible_magnetization(self, H, M, p: Parameters):
        Man, _ = anhysteretic(H, M, p)
        return (1.0 + p.c) * M - p.c * Man


class VenkataramanJA(AbstractAnhystereticForm):
    """The bulk ferromagnetic form of Venkataraman (PhD thesis, University of Maryland,
    1999, eq 30), which COMSOL Multiphysics and Altair Flux implement. Irreversible change
    is driven by the effective field, dMirr/dHe = δM·(Man − Mirr)/(δ·k), with
    M = c·Man + (1 − c)·Mirr and He = H + α̃·M, so that

        dM/dH = X / (1 − α̃·X),   X = δM·(Man − M)/(δ·k) + c·Man',

    (Man − Mirr = (Man − M)/(1 − c)). k is in A/m here; the thesis and COMSOL write k/μ0
    with k in J/m³ (multiply our k by μ0 to move parameters across). δM as in the other
    forms. Where 1 − α̃X ≤ 0 (an α̃ so large that the mean field runs away) the slope is
    not defined; the simulation then returns non-finite values, which identification
    treats as a failed individual.
    """

    scales_with_Ms: ClassVar[bool] = True

    def slope_from_anhysteretic(self, M, delta, p: Parameters, Man, dMan, pinning=True):
        D = Man - M
        active = (delta * D > 0) & pinning
        X = jnp.where(active, D / (delta * p.k), 0.0) + p.c * dMan
        return X / (1.0 - p.alpha * X)

    def irreversible_magnetization(self, H, M, p: Parameters):
        return mirr_of_reversible_fraction(H, M, p)


class PopJA(AbstractAnhystereticForm):
    """The sign-continuous form attributed to Pop & Caltun (N. C. Pop and O. F. Caltun,
    Acta Phys. Pol. A 120 (2011) 491): M = Mirr + c·(Man − Mirr) (their eq 4), the
    irreversible slope of the classic model written in M, and no δM switch:

        dM/dH = [(1 − c)·D/((1 − c)·δ·k − α̃·D) + c·Man'] / (1 − α̃·c),   D = Man − M.

    The irreversible susceptibility follows the sign of δ·D continuously: just after a
    field reversal (δ·D < 0) it is negative instead of being switched off, so dM/dH has
    no kink where D changes sign (the behaviour the δM rule of the other forms removes).
    The denominator 1 − α̃·c is constant (the exact chain rule through He would give
    1 − α̃·c·Man', as in `EnergyBasedJA`), so c = 1 (no irreversible part) reproduces
    M = Man only when α̃ = 0.

    Provenance: the paper's eq 4 is the only equation of it we could read; this closed
    form is the one the open-source fitting tool jafit (P. Kirienko, Zubax Robotics, 2025)
    implements as "the model described in Pop et al.". Parameters move between the two
    unchanged (k and a in A/m; their c_r is c, their alpha is α̃). Where
    (1 − c)·δ·k − α̃·D = 0 (c < 1) the slope is infinite; the simulation then returns
    non-finite values, which identification treats as a failed individual.
    """

    has_switch: ClassVar[bool] = False

    def slope_from_anhysteretic(self, M, delta, p: Parameters, Man, dMan, pinning=True):
        D = Man - M
        one_minus_c = 1.0 - p.c
        denominator = one_minus_c * delta * p.k - p.alpha * D
        # c = 1: no irreversible part; without the guard D = 0 there would give 0/0
        irreversible = _pinned_ratio(one_minus_c * D, denominator, (p.c < 1.0) & pinning)
        return (irreversible + p.c * dMan) / (1.0 - p.alpha * p.c)

    def irreversible_magnetization(self, H, M, p: Parameters):
        return mirr_of_reversible_fraction(H, M, p)


#: The paper's form (an immutable Module: a safe shared default).
PAPER_VARIANT = EnergyBasedJA()

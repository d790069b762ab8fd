"""The same model as `jaxhyst.simulate` (energy-based JA, RK4 in H with the δM switch
located, exact structural step with a cubic-Hermite λ), written as a scalar per-sample
loop. Run as plain Python/NumPy, or compiled with Numba (`numba.njit(simulate_loop)`).
Used only by the benchmarks, as the like-for-like CPU alternative."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

# Plain Python by default; `numba_module()` re-executes this file with jit = numba.njit.
jit = globals().get("jit") or (lambda f: f)
jit_parallel = globals().get("jit_parallel") or (lambda f: f)
prange = globals().get("prange") or range


def structural_matrices(Kz, Mz, Cz, h):
    """(Φ, G) of the exact cubic-hold discretization, as in jaxhyst.model.structure."""
    aug = np.zeros((6, 6))
    aug[0, 1] = 1.0
    aug[1, 0] = -Kz / Mz
    aug[1, 1] = -Cz / Mz
    aug[1, 2] = 1.0
    aug[2, 3] = aug[3, 4] = aug[4, 5] = 1.0
    E = expm(aug * h)
    return np.ascontiguousarray(E[:2, :2]), np.ascontiguousarray(E[:2, 2:])


@jit
def _slope(H, M, delta, th, pinning):
    Ms, a, k, alpha, c = th[0], th[2], th[3], th[4], th[5]
    x = (H + alpha * M) / a
    ax = abs(x)
    if ax < 0.1:
        x2 = x * x
        L = x * (1 / 3 + x2 * (-1 / 45 + x2 * (2 / 945 + x2 * (-1 / 4725 + x2 * (2 / 93555)))))
        dL = 1 / 3 + x2 * (-1 / 15 + x2 * (2 / 189 + x2 * (-1 / 675 + x2 * (2 / 10395))))
    else:
        e = math.exp(-2.0 * ax)
        L = math.copysign((1.0 + e) / (1.0 - e) - 1.0 / ax, x)
        dL = 1.0 / (x * x) - 4.0 * e / ((1.0 - e) * (1.0 - e))
    Man = Ms * L
    dMan = Ms / a * dL
    D = Man - M
    den = (1.0 - c) * delta * k - alpha * D
    irr = 0.0
    if pinning and delta * D > 0 and delta * den > 0:
        irr = (1.0 - c) * D / den
    return (irr + c * dMan) / (1.0 - alpha * c * dMan), delta * D


@jit
def _rk4(H, M, dH, k1, delta, th, pinning):
    k2 = _slope(H + 0.5 * dH, M + 0.5 * dH * k1, delta, th, pinning)[0]
    k3 = _slope(H + 0.5 * dH, M + 0.5 * dH * k2, delta, th, pinning)[0]
    k4 = _slope(H + dH, M + dH * k3, delta, th, pinning)[0]
    return M + dH / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@jit
def simulate_loop(th, Ar, H, h, substeps, Phi, G, y_out):
    """Fill y_out (len(H)) with the displacement; th = the ten parameters."""
    Ms, lam_s, E, Mz = th[0], th[1], th[6], th[8]
    gain = Ar * E / Mz
    M = 0.0
    y = 0.0
    v = 0.0
    y_out[0] = 0.0
    for i in range(len(H) - 1):
        dH = (H[i + 1] - H[i]) / substeps
        delta = 1.0 if H[i + 1] >= H[i] else -1.0
        rate = dH / h
        Hc = H[i]
        k1 = _slope(Hc, M, delta, th, True)[0]
        for _ in range(substeps):
            Mn = _rk4(Hc, M, dH, k1, delta, th, True)
            d0 = _slope(Hc, M, delta, th, True)[1]
            d1 = _slope(Hc + dH, Mn, delta, th, True)[1]
            if d0 <= 0 and d1 > 0:
                theta = min(max(d0 / (d0 - d1), 0.0), 1.0)
                kr = _slope(Hc, M, delta, th, False)[0]
                Mm = _rk4(Hc, M, theta * dH, kr, delta, th, False)
                Hm = Hc + theta * dH
                km = _slope(Hm, Mm, delta, th, True)[0]
                Mn = _rk4(Hm, Mm, (1.0 - theta) * dH, km, delta, th, True)
            Hc = Hc + dH
            ke = _slope(Hc, Mn, delta, th, True)[0]
            l0 = 1.5 * lam_s * (M / Ms) ** 2
            l1 = 1.5 * lam_s * (Mn / Ms) ** 2
            dl0 = 3.0 * lam_s * (M / Ms) * (k1 * rate / Ms)
            dl1 = 3.0 * lam_s * (Mn / Ms) * (ke * rate / Ms)
            s = (l1 - l0) / h
            c2 = (3.0 * s - 2.0 * dl0 - dl1) / h
            c3 = (dl0 + dl1 - 2.0 * s) / (h * h)
            w0, w1, w2, w3 = gain * l0, gain * dl0, gain * 2.0 * c2, gain * 6.0 * c3
            y, v = (Phi[0, 0] * y + Phi[0, 1] * v + G[0, 0] * w0 + G[0, 1] * w1
                    + G[0, 2] * w2 + G[0, 3] * w3,
                    Phi[1, 0] * y + Phi[1, 1] * v + G[1, 0] * w0 + G[1, 1] * w1
                    + G[1, 2] * w2 + G[1, 3] * w3)  # fmt: skip
            M = Mn
            k1 = ke
        y_out[i + 1] = y


@jit_parallel
def simulate_population(X, Ar, H, h, substeps, Phis, Gs, Y):
    """simulate_loop for every row of X (P, 10); parallel over individuals under Numba."""
    for j in prange(X.shape[0]):
        simulate_loop(X[j], Ar, H, h, substeps, Phis[j], Gs[j], Y[j])


def numba_module():
    """This module compiled by Numba: a fresh namespace executed with jit = numba.njit."""
    import sys
    import types

    import numba

    mod = types.ModuleType("reference_loop_numba")
    mod.__dict__["jit"] = numba.njit
    mod.__dict__["jit_parallel"] = numba.njit(parallel=True)
    mod.__dict__["prange"] = numba.prange
    sys.modules[mod.__name__] = mod  # Numba resolves globals through sys.modules
    with open(__file__) as fh:
        exec(compile(fh.read(), __file__, "exec"), mod.__dict__)
    return mod

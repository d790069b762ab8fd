"""Shared test problems and an *independent* reference solver.

The reference re-implements the model in NumPy from the paper's equations (not importing
jaxhyst's model code) and integrates the coupled system [M, y, ẏ] in time with SciPy's
DOP853 at rtol 1e-12, one sample interval at a time (the drive is piecewise linear and
δ = sign(dH) is constant per interval), so kinks at samples are honoured exactly.
"""

from __future__ import annotations

import numpy as np

import jaxhyst as jh


def np_langevin(x):
    """(L, L') with NumPy in extended precision: a four-term series for |x| < 1e-2, else
    tanh/sinh in long double (cancellation error ~1e-19/x² ≤ 1e-15 there)."""
    x = np.longdouble(x)
    if abs(x) < 1e-2:
        x2 = x * x
        one = np.longdouble(1)
        L = x * (one / 3 - x2 / 45 + 2 * x2 * x2 / 945 - x2 * x2 * x2 / 4725)
        dL = one / 3 - x2 / 15 + 2 * x2 * x2 / 189 - x2 * x2 * x2 / 675
        return float(L), float(dL)
    return float(1 / np.tanh(x) - 1 / x), float(1 / (x * x) - 1 / np.sinh(x) ** 2)


def np_slope(H, M, delta, p, variant="energy"):
    """dM/dH of the paper's energy-based form (SPEC §1, total chain rule), the classic
    1986 form, Venkataraman's bulk form or the sign-continuous form of Pop & Caltun,
    written from the equations independently of jaxhyst."""
    He = H + p["alpha"] * M
    L, dL = np_langevin(He / p["a"])
    Man, dMan = p["Ms"] * L, p["Ms"] / p["a"] * dL
    c, k, al = p["c"], p["k"], p["alpha"]
    if variant == "energy":
        Mirr = (M - c * Man) / (1 - c)
        diff = Man - Mirr
        suppressed = (delta < 0 and Man - M > 0) or (delta > 0 and Man - M < 0)
        chi_irr = 0.0 if suppressed else diff / (delta * k - al * diff)
        return ((1 - c) * chi_irr + c * dMan) / (1 - al * c * dMan)
    if variant == "classic":
        diff = Man - M
        suppressed = (delta < 0 and diff > 0) or (delta > 0 and diff < 0)
        irr = 0.0 if suppressed else diff / (delta * k - al * diff)
        return (irr + c * dMan) / (1 + c)
    if variant == "pop":  # no δM switch; classic χirr in Mirr, constant 1 − αc
        Mirr = (M - c * Man) / (1 - c)
        diff = Man - Mirr
        return ((1 - c) * diff / (delta * k - al * diff) + c * dMan) / (1 - al * c)
    if variant == "venkataraman":  # Venkataraman 1999 eq 30, k in A/m
        diff = Man - M
        suppressed = (delta < 0 and diff > 0) or (delta > 0 and diff < 0)
        X = (0.0 if suppressed else diff / (delta * k)) + c * dMan
        return X / (1 - al * X)
    raise ValueError(variant)


def reference_simulation(params: jh.Parameters, actuator: jh.Actuator, drive: jh.Drive,
                         variant="energy", rtol=1e-12):
    """Return (M, y) at the drive samples from a tight DOP853 solve. Units SI."""
    from scipy.integrate import solve_ivp

    p = params.to_dict()
    t = np.asarray(drive.t)
    H = np.asarray(drive.H)
    Ar = float(actuator.Ar)
    state = np.zeros(3)
    Ms, ls = p["Ms"], p["lambda_s"]
    out = np.zeros((len(t), 3))
    for i in range(len(t) - 1):
        dHdt = (H[i + 1] - H[i]) / (t[i + 1] - t[i])
        delta = 1.0 if H[i + 1] >= H[i] else -1.0

        def rhs(tau, s, i=i, dHdt=dHdt, delta=delta):
            Hc = H[i] + dHdt * (tau - t[i])
            dM = np_slope(Hc, s[0], delta, p, variant) * dHdt
            lam = 1.5 * ls * (s[0] / Ms) ** 2
            acc = (Ar * p["E"] * lam - p["Cz"] * s[2] - p["Kz"] * s[1]) / p["Mz"]
            return [dM, s[2], acc]

        sol = solve_ivp(rhs, (t[i], t[i + 1]), state, method="DOP853", rtol=rtol,
                        atol=[1e-9 * Ms, 1e-18, 1e-14])
        state = sol.y[:, -1]
        out[i + 1] = state
    return out[:, 0], out[:, 1]


def reversing_drive(f=100.0, spp=200, periods=2, base=2.0e4, ripple=3.0e3, harmonic=13):
    """A field that reverses often: a sinusoid with a strong high harmonic (minor loops on
    every major-loop branch), starting at H = 0."""
    n = int(periods * spp) + 1
    t = np.arange(n) / (f * spp)
    H = base * np.sin(2 * np.pi * f * t) + ripple * np.sin(2 * np.pi * harmonic * f * t)
    return jh.Drive(t, H)


def minor_loop_drive(f=10.0, spp=400, bias=16e3):
    """A biased major loop followed by a small minor loop inside it (field, A/m)."""
    t1 = np.arange(spp) / (f * spp)
    H1 = bias + 8e3 * np.sin(2 * np.pi * f * t1)
    t2 = t1[-1] + (np.arange(1, spp + 1)) / (f * spp)
    H2 = bias + 1.5e3 * np.sin(2 * np.pi * f * (t2 - t2[0]))
    ramp_t = -np.arange(spp // 4, 0, -1) / (f * spp)
    ramp_H = bias * (1 + ramp_t * f * 4)
    t = np.concatenate([ramp_t, t1, t2])
    H = np.concatenate([ramp_H, H1, H2])
    return jh.Drive(t, H, run_in=spp // 4)


def cases():
    """(name, params, actuator, drive) of the accuracy cases of issue 2."""
    a2 = jh.ACTUATOR2
    return [
        ("table1_100Hz", jh.TABLE1_TRUE, jh.ACTUATOR1,
         jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1)),
        ("act2_10Hz", jh.TABLE3[10], a2, jh.sinusoidal_field(10.0, 8e3, a2.Hb)),
        ("act2_1000Hz", jh.TABLE3[1000], a2, jh.sinusoidal_field(1000.0, 8e3, a2.Hb)),
        ("minor_loop", jh.TABLE3[10], a2, minor_loop_drive()),
        ("reversing", jh.TABLE1_TRUE, jh.ACTUATOR1, reversing_drive()),
    ]


def table1_problem(spp=100, **kwargs):
    """The paper's simulation study (Table 1 truth and ranges, Actuator1, 100 Hz current),
    sampled coarser than the paper study so that tests run quickly; noise-free."""
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
    return jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS, **kwargs)


def identifiable_combinations(p: dict) -> dict:
    """The seven combinations that displacement data determine (docs/theory.md):
    α·Ms, a, k, c, λs·E/Kz, Mz/Kz, Cz/Kz."""
    return {
        "alpha*Ms": p["alpha"] * p["Ms"], "a": p["a"], "k": p["k"], "c": p["c"],
        "lambda_s*E/Kz": p["lambda_s"] * p["E"] / p["Kz"], "Mz/Kz": p["Mz"] / p["Kz"],
        "Cz/Kz": p["Cz"] / p["Kz"],
    }


def max_combination_error(p: dict, truth: dict) -> float:
    a, b = identifiable_combinations(p), identifiable_combinations(truth)
    return max(abs(a[k] / b[k] - 1) for k in a)


MU0 = 4e-7 * np.pi


def _rate_field(rate, k_e, k_x):
    return k_e * rate + k_x * np.sign(rate) * np.sqrt(np.abs(rate))


def reference_flux(params: jh.Parameters, t, B, variant="energy", k_e=0.0, k_x=0.0,
                   run_in=0, rtol=1e-11):
    """The B-driven model written independently: dM/dB = χ/(μ0(1 + χ)), χ the form's
    dM/dH (`np_slope`) at H_hyst = B/μ0 − M, integrated by DOP853 over each sample
    interval (B linear in time there) together with ∫ H_hyst dB. Returns (M, H at the
    samples with the loss fields of the centred rate, the energy ∮ H dB over the samples
    after ``run_in``)."""
    from scipy.integrate import solve_ivp

    p = params.to_dict()
    t, B = np.asarray(t, float), np.asarray(B, float)
    M = np.zeros_like(B)
    energy = 0.0
    for i in range(len(t) - 1):
        dB = B[i + 1] - B[i]
        delta = 1.0 if dB >= 0 else -1.0

        def rhs(b, s, delta=delta):
            chi = np_slope(b / MU0 - s[0], s[0], delta, p, variant)
            return [chi / (MU0 * (1.0 + chi)), b / MU0 - s[0]]

        if dB == 0:
            M[i + 1] = M[i]
            continue
        sol = solve_ivp(rhs, (B[i], B[i + 1]), [M[i], 0.0], method="DOP853", rtol=rtol,
                        atol=[1e-9 * p["Ms"], 1e-12])
        M[i + 1] = sol.y[0, -1]
        if i >= run_in:
            dt = t[i + 1] - t[i]
            energy += sol.y[1, -1] + k_e * dB * dB / dt + k_x * abs(dB) ** 1.5 / np.sqrt(dt)
    rate = np.diff(B) / np.diff(t)
    centred = np.concatenate([rate[:1], 0.5 * (rate[:-1] + rate[1:]), rate[-1:]])
    return M, B / MU0 - M + _rate_field(centred, k_e, k_x), energy


def reference_dynamic(params: jh.Parameters, t, H, variant="energy", k_e=0.0, k_x=0.0,
                      rtol=1e-10, lag=0.0):
    """The H-driven rate-dependent model as the ODE it discretizes, written independently:
    state (h, M) with H(t) − h = k_e·Ḃ + k_x·sign(Ḃ)·|Ḃ|^(1/2) + lag·ḣ, Ḃ = μ0(1 + χ)·ḣ,
    Ṁ = χ·ḣ (ḣ from the closed-form root of that balance), H linear in time per sample
    interval, DOP853. Returns (h, M) at the samples."""
    from scipy.integrate import solve_ivp

    p = params.to_dict()
    t, H = np.asarray(t, float), np.asarray(H, float)
    state = np.array([H[0], 0.0])
    out = np.zeros((len(t), 2))
    out[0] = state
    for i in range(len(t) - 1):
        slope = (H[i + 1] - H[i]) / (t[i + 1] - t[i])

        def rhs(tau, s, i=i, slope=slope):
            R = H[i] + slope * (tau - t[i]) - s[0]
            if R == 0.0:
                return [0.0, 0.0]
            delta = 1.0 if R > 0 else -1.0
            chi = np_slope(s[0], s[1], delta, p, variant)
            c = MU0 * (1.0 + chi)
            a, b = k_e * c + lag, k_x * np.sqrt(c)
            if a == 0.0 and b == 0.0:
                raise ValueError("the static model has no time scale")
            root = (2 * abs(R) / (b + np.sqrt(b * b + 4 * a * abs(R)))) if b > 0 else \
                np.sqrt(abs(R) / a)
            g = delta * root * root
            return [g, chi * g]

        sol = solve_ivp(rhs, (t[i], t[i + 1]), state, method="DOP853", rtol=rtol,
                        atol=[1e-9 * max(1.0, np.max(np.abs(H))), 1e-9 * p["Ms"]])
        state = sol.y[:, -1]
        out[i + 1] = state
    return out[:, 0], out[:, 1]


def reference_relaxed(params: jh.Parameters, t, H, k_e=0.0, k_x=0.0, lag=0.0, relax=1e-4):
    """The H-driven model with the after-effect (relax·dM/dt = M_s − M) as the ODE it
    discretizes, written independently: state (h, M_s, M), Ṁ_s = χ(h, M_s)·ḣ, and ḣ from
    H − h = k_e·Ḃ + k_x·sign(Ḃ)·|Ḃ|^(1/2) + lag·ḣ with Ḃ = μ0·(ḣ + Ṁ) (Ṁ does not depend
    on ḣ: a root by Brent's method; h = H without loss fields), H linear in time per
    sample interval, Radau (the field balance is stiff: its time scale is k_e·μ0). Returns
    (h, M) at the samples."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    p = params.to_dict()
    t, H = np.asarray(t, float), np.asarray(H, float)
    fields = bool(k_e or k_x or lag)
    state = np.array([H[0], 0.0, 0.0])
    out = [state]
    for i in range(len(t) - 1):
        slope = (H[i + 1] - H[i]) / (t[i + 1] - t[i])

        def rhs(tau, s, i=i, slope=slope):
            mdot = (s[1] - s[2]) / relax
            u = slope
            if fields:
                R = H[i] + slope * (tau - t[i]) - s[0]

                def balance(u):
                    return (k_e * MU0 + lag) * u + k_e * MU0 * mdot + \
                        _rate_field(MU0 * (u + mdot), 0.0, k_x) - R

                u = brentq(balance, -1e15, 1e15, xtol=1e-12, rtol=1e-15)
            chi = np_slope(s[0], s[1], 1.0 if u >= 0 else -1.0, p)
            return [u, chi * u, mdot]

        sol = solve_ivp(rhs, (t[i], t[i + 1]), state, method="Radau" if fields else "DOP853",
                        rtol=1e-10, atol=[1e-9 * max(1.0, np.max(np.abs(H))),
                                          1e-9 * p["Ms"], 1e-9 * p["Ms"]])
        state = sol.y[:, -1]
        out.append(state)
    out = np.array(out)
    return out[:, 0], out[:, 2]


def reference_relaxed_by_flux(params: jh.Parameters, t, B, relax=1e-4, variant="energy",
                              smooth=None):
    """The B-driven model with the after-effect as the ODE it discretizes, written
    independently: state (M_s, M) with h = B/μ0 − M, Ṁ = (M_s − M)/relax,
    ḣ = Ḃ/μ0 − Ṁ and Ṁ_s = χ(h, M_s)·ḣ, B linear in time per sample interval — or
    ``smooth(t) = (B, dB/dt)`` (T, T/s) between the samples: the kinks of a
    piecewise-linear B each start a transient of M of time constant relax/(1 + χ),
    which a smooth B has not — DOP853. Returns (h, M) at the samples."""
    from scipy.integrate import solve_ivp

    p = params.to_dict()
    t, B = np.asarray(t, float), np.asarray(B, float)
    state, out = np.array([0.0, 0.0]), [np.array([0.0, 0.0])]
    for i in range(len(t) - 1):
        rate = (B[i + 1] - B[i]) / (t[i + 1] - t[i])

        def rhs(tau, s, i=i, rate=rate):
            b, db = (B[i] + rate * (tau - t[i]), rate) if smooth is None else smooth(tau)
            mdot = (s[0] - s[1]) / relax
            h = b / MU0 - s[1]
            hdot = db / MU0 - mdot
            chi = np_slope(h, s[0], 1.0 if hdot >= 0 else -1.0, p, variant)
            return [chi * hdot, mdot]

        sol = solve_ivp(rhs, (t[i], t[i + 1]), state, method="DOP853", rtol=1e-11,
                        atol=1e-9 * p["Ms"])
        state = sol.y[:, -1]
        out.append(state)
    out = np.array(out)
    return B / MU0 - out[:, 1], out[:, 1]


def reference_play(params: jh.Parameters, spread: float, cells: int, H, a_rev=None):
    """M (A/m) at the samples of the field H (A/m) for a form of pinning cells, written
    from its equations independently of jaxhyst: N play operators of widths
    k·exp(s·z_i) (z_i the normal quantiles at (i − ½)/N, from SciPy) on He = H + α̃·M,
    M = Ms·[c·L(He/a_r) + (1 − c)·mean L(h_i/a)] (a_r = ``a_rev``, or a), the implicit M
    of each sample found by Brent's method to 1e-13 of Ms."""
    from scipy.optimize import brentq
    from scipy.stats import norm

    p = {n: float(getattr(params, n)) for n in ("Ms", "a", "k", "alpha", "c")}
    a_r = p["a"] if a_rev is None else float(a_rev)
    chi = p["k"] * np.exp(spread * norm.ppf((np.arange(cells) + 0.5) / cells))
    h = np.zeros(cells)

    def state(He):
        cells_h = np.clip(h, He - chi, He + chi)
        M = p["Ms"] * (p["c"] * np_langevin(He / a_r)[0]
                       + (1 - p["c"]) * np.mean([np_langevin(x / p["a"])[0]
                                                 for x in cells_h]))
        return M, cells_h

    out = [0.0]
    for Hn in np.asarray(H, float)[1:]:
        g = lambda M, Hn=Hn: M - state(Hn + p["alpha"] * M)[0]  # noqa: E731
        M = brentq(g, -p["Ms"], p["Ms"], xtol=1e-13 * p["Ms"], rtol=1e-15)
        _, h = state(Hn + p["alpha"] * M)
        out.append(M)
    return np.asarray(out)


def exponential_problem(sigma):
    """y = exp(b·t) + m on 8 points, t in [0, 3], b = 0.5, m = 0, noise σ (declared)."""
    import jax.numpy as jnp

    t = jnp.linspace(0.0, 3.0, 8)

    def residuals(theta, data):
        return {"y": jnp.exp(theta["b"] * t) + theta["m"] - data["y"]}

    space = jh.ParameterSpace.for_tree(lower={"b": -3.0, "m": -30.0},
                                       upper={"b": 3.0, "m": 30.0})
    y = np.exp(0.5 * np.asarray(t)) + sigma * np.random.default_rng(1).standard_normal(8)
    return jh.ResidualProblem(residuals, space, {"y": jnp.asarray(y)},
                              groups={"y": {"sigma": sigma}}), y

"""Measured loops as they come: turning points, loop features, default bounds, sampling.

**Turning points (the documented rule).** A record's field H is walked sample by sample,
keeping the extreme reached since the last turning point. A turning point is declared at
that extreme once the field has moved back from it by more than ``REVERSAL_FRACTION``
(5 %) of the record's whole range max H − min H. Reversals smaller than that are noise of
the measurement or of the digitizer, never a branch end; a minor loop larger than that is
a turning point like any other. A record *holds a loop* when, after its first turning
point, the field sweeps back over at least 90 % of the range (a closed loop, whether it
starts at a tip or mid-branch).

**Digitizing noise.** Within each branch (between two turning points) a field that steps
backwards by less than the threshold is replaced by its least-squares monotone fit
(pool-adjacent-violators), so the model never sees a reversal that is only noise: a real
JA model would answer each with a tiny minor loop. The measured B or M is not changed.

**Default bounds for magnetization-only data.** From the loop's features (`LoopFeatures`:
field amplitude Hmax, magnetization amplitude Mmax, coercive field Hc, remanence Mr), see
`default_loop_bounds` for the box and why.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..params import MU0, NAMES, Bounds, Parameters

#: A reversal of the field counts as a turning point once it exceeds this fraction of the
#: record's range (smaller ones are noise).
REVERSAL_FRACTION = 0.05
#: After its first turning point a record must sweep back over this fraction of its range
#: to hold a loop.
LOOP_FRACTION = 0.9


def turning_points(H, fraction: float = REVERSAL_FRACTION) -> np.ndarray:
    """Indices of the turning points of the field record ``H`` (A/m) by the rule of the
    module docstring: the extremes from which the field moved back by more than
    ``fraction`` of its range. Sorted; empty for a monotone (or constant) record."""
    H = np.asarray(H, dtype=np.float64)
    span = float(np.ptp(H)) if H.size else 0.0
    if span == 0.0:
        return np.zeros(0, dtype=int)
    tol = fraction * span
    turns = []
    direction = 0  # +1 rising, -1 falling, 0 not yet known
    ext_i = 0
    lo_i = hi_i = 0  # before the direction is known: running min and max
    for i in range(1, H.shape[0]):
        h = H[i]
        if direction == 0:
            if h > H[hi_i]:
                hi_i = i
            if h < H[lo_i]:
                lo_i = i
            if H[hi_i] - H[lo_i] > tol:  # the first clear movement sets the direction
                direction = 1 if hi_i > lo_i else -1
                ext_i = hi_i if direction > 0 else lo_i
            continue
        if direction * (h - H[ext_i]) > 0:
            ext_i = i
        elif direction * (H[ext_i] - h) > tol:
            turns.append(ext_i)
            direction = -direction
            ext_i = i
    return np.asarray(turns, dtype=int)


def holds_loop(H) -> bool:
    """True if the record ``H`` sweeps back over ≥ 90 % of its range after its first
    turning point (`turning_points`): it determines a closed hysteresis loop."""
    H = np.asarray(H, dtype=np.float64)
    turns = turning_points(H)
    if turns.size == 0:
        return False
    r = int(turns[0])
    span = float(np.ptp(H))
    return float(np.max(np.abs(H[r:] - H[r]))) >= LOOP_FRACTION * span


def _monotone_fit(y, increasing: bool) -> np.ndarray:
    """Least-squares monotone (non-decreasing, or non-increasing) fit of ``y``: pool
    adjacent violators."""
    s = 1.0 if increasing else -1.0
    vals, counts = [], []
    for v in s * np.asarray(y, dtype=np.float64):
        vals.append(v)
        counts.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            n = counts[-2] + counts[-1]
            vals[-2] = (vals[-2] * counts[-2] + vals[-1] * counts[-1]) / n
            counts[-2] = n
            vals.pop()
            counts.pop()
    return s * np.repeat(vals, counts)


def monotone_branches(H) -> np.ndarray:
    """``H`` with each branch between turning points replaced by its least-squares
    monotone fit (see the module docstring); unchanged where a branch is monotone."""
    H = np.asarray(H, dtype=np.float64)
    if H.shape[0] < 3:
        return H.copy()
    edges = [0, *turning_points(H).tolist(), H.shape[0] - 1]
    out = H.copy()
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b <= a:
            continue
        seg = H[a:b + 1]
        out[a:b + 1] = _monotone_fit(seg, increasing=seg[-1] >= seg[0])
    return out


@dataclass(frozen=True)
class LoopFeatures:
    """Features of a measured M(H) loop (SI): field amplitude ``Hmax`` = max|H| (A/m),
    magnetization amplitude ``Mmax`` = max|M| (A/m), coercive field ``Hc`` (A/m; median
    |H| where M changes sign) and remanence ``Mr`` (A/m; median |M| where H changes
    sign). ``Hc``/``Mr`` are ``None`` when the loop never crosses that axis (a biased
    minor loop)."""

    Hmax: float
    Mmax: float
    Hc: float | None
    Mr: float | None

    def to_dict(self) -> dict:
        return {"Hmax": self.Hmax, "Mmax": self.Mmax, "Hc": self.Hc, "Mr": self.Mr}


def _crossings(x, y) -> np.ndarray:
    """|y| interpolated where x changes sign."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    i = np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)
    w = x[i] / (x[i] - x[i + 1])
    return np.abs(y[i] + w * (y[i + 1] - y[i]))


def loop_features(H, M) -> LoopFeatures:
    """`LoopFeatures` of the loop H (A/m), M (A/m)."""
    H, M = np.asarray(H, float), np.asarray(M, float)
    hc, mr = _crossings(M, H), _crossings(H, M)
    return LoopFeatures(Hmax=float(np.max(np.abs(H))), Mmax=float(np.max(np.abs(M))),
                        Hc=float(np.median(hc)) if hc.size else None,
                        Mr=float(np.median(mr)) if mr.size else None)


def magnetization_of(data, H, output: str) -> np.ndarray:
    """M (A/m) from observed ``data``: itself for ``magnetization``, B/μ0 − H for
    ``flux_density`` (B in T, H in A/m)."""
    data = np.asarray(data, float)
    if output == "flux_density":
        return data / MU0 - np.asarray(H, float)
    if output == "magnetization":
        return data
    raise ValueError(f"output {output!r} is not a magnetization (use magnetization or "
                     "flux_density).")


#: Placeholder box of the structural parameters of a magnetization-only problem (they
#: never affect M or B and are fixed at their centre).
_STRUCTURAL_BOX = {"lambda_s": (0.0, 1e-3), "E": (1e10, 5e10), "Kz": (1e7, 5e7),
                   "Mz": (0.1, 1.0), "Cz": (0.0, 1e4)}


def default_loop_bounds(features: LoopFeatures | list[LoopFeatures]) -> Bounds:
    """A box for the five JA parameters derived from measured loops (several: the union
    of their features), in SI units:

    - Ms ∈ [Mmax, 10·Mmax]: the magnetization never exceeds Ms, and an unsaturated loop
      may be far below it;
    - k ∈ [Hc/10, 30·Hc]: k sets the coercive field (Hc ≈ (1 − c)·k for small α, so
      k may be many times Hc when c is near 1);
    - a ∈ [Hmin/100, 10·Hmax] with Hmin = min(Hc, Hmax/10): the anhysteretic width lies
      between a fraction of the coercive field and a multiple of the field swept;
    - α ∈ [−Hmax/Mmax, Hmax/Mmax]: the mean-field term α·M stays of the order of the
      applied field (larger values make the loop unstable or shear it beyond the data);
    - c ∈ [0, 1] (its physical range).

    Without a coercive field (a loop that does not cross M = 0) Hc is taken as Hmax/10.
    The structural parameters get a placeholder box (they do not affect M or B).
    """
    feats = features if isinstance(features, (list, tuple)) else [features]
    Hmax = max(f.Hmax for f in feats)
    Mmax = max(f.Mmax for f in feats)
    if not (Hmax > 0 and Mmax > 0):
        raise ValueError("The loop has no field or no magnetization (max|H| or max|M| is "
                         "0); it cannot set default bounds.")
    hcs = [f.Hc for f in feats if f.Hc]
    hc_lo = min(hcs) if hcs else 0.1 * Hmax
    hc_hi = max(hcs) if hcs else 0.1 * Hmax
    h_small = min(hc_lo, 0.1 * Hmax)
    if Mmax > 1e7:
        raise ValueError(f"The loop's magnetization reaches {Mmax:.3g} A/m, beyond any "
                         "material (Ms <= 1e7 A/m; Fe–Co's is 1.95e6): check the unit and "
                         "the column of B or M, and look for a spike sample.")
    clip = lambda lo, hi, a, b: (min(max(lo, a), b), min(max(hi, a), b))  # noqa: E731
    alpha = min(Hmax / Mmax, 10.0)
    box = {  # (each inside the physical range of `jaxhyst.params.PHYSICAL_RULES`)
        "Ms": (Mmax, min(10.0 * Mmax, 1e7)),
        "a": clip(h_small / 100.0, 10.0 * Hmax, 1e-6, 1e9),
        "k": clip(hc_lo / 10.0, 30.0 * hc_hi, 1e-6, 1e9),
        "alpha": (-alpha, alpha),
        "c": (0.0, 1.0),
        **_STRUCTURAL_BOX,
    }
    return Bounds.from_dict(box)


def merge_bounds(base: Bounds, changes: dict) -> Bounds:
    """``base`` with the parameters in ``changes`` ({name: (lower, upper)}, SI) replaced."""
    unknown = sorted(set(changes) - set(NAMES))
    if unknown:
        raise ValueError(f"bounds for unknown parameters {unknown}; the parameters are "
                         f"{list(NAMES)}.")
    lo, hi = base.lower.to_dict(), base.upper.to_dict()
    for n, (l_, h_) in changes.items():
        lo[n], hi[n] = float(l_), float(h_)
    return Bounds(Parameters.from_dict(lo), Parameters.from_dict(hi))


def loop_bounds(Hs, datas, output: str, bounds=None) -> Bounds:
    """The box of a magnetization-only fit of the loops (``Hs``, ``datas``: one array or
    a list of them; ``output`` ``flux_density`` or ``magnetization``): `Bounds` as given,
    or — for ``None`` or a dict ``{name: (lower, upper)}`` of changes — the data-derived
    `default_loop_bounds` with those changes."""
    if isinstance(bounds, Bounds):
        return bounds
    if bounds is not None and not isinstance(bounds, dict):
        raise TypeError(f"bounds must be jaxhyst.Bounds, a dict {{name: (lower, upper)}} of "
                        f"changes to the data-derived box, or None; got "
                        f"{type(bounds).__name__}.")
    if not isinstance(Hs, (list, tuple)):
        Hs, datas = [Hs], [datas]
    feats = []
    for i, (H, d) in enumerate(zip(Hs, datas, strict=True)):
        where = f"loop {i}: " if len(Hs) > 1 else ""
        for what, a in (("H", H), ("data", d)):
            bad = np.flatnonzero(~np.isfinite(np.asarray(a, dtype=float)))
            if bad.size:
                raise ValueError(f"{where}{what} contain NaN or inf at samples "
                                 f"{bad[:5].tolist()}; remove or repair them.")
        for what, a, unit in (("H", H, "A/m"), ("the data", d, "T" if output ==
                                                  "flux_density" else "A/m")):
            spike = find_spike(a)
            if spike is not None:
                k, jump, step = spike
                raise ValueError(
                    f"{where}sample {k} of {what} ({float(np.asarray(a)[k]):g} {unit}) is a "
                    f"spike: {jump:.3g} {unit} off its neighbours, whose steps are "
                    f"~{step:.2g} {unit}; it would set the box (and the fit) — remove or "
                    "repair that sample.")
        M = magnetization_of(d, H, output)
        Mmax = np.max(np.abs(M))
        if Mmax <= 1e7:  # (beyond, the box's error names the unit or column alone)
            _warn_about(H, d, Mmax, where, "T" if output == "flux_density" else "A/m")
        feats.append(loop_features(H, M))
    return merge_bounds(default_loop_bounds(feats), dict(bounds or {}))


class LoopWarning(UserWarning):
    """Something in a measured loop that keeps the model from fitting it (named)."""


def _warn_about(H, d, Mmax, where: str, unit: str) -> None:
    """A `LoopWarning` for each offset (of the field, of the data) and for a
    permeability no material has (a field read 1000× small) in the loop (H, d)."""
    offset = field_offset(H, d)
    if offset is not None:
        warnings.warn(f"{where}the field looks offset by {offset:.4g} A/m: the loop's "
                      "data are symmetric about 0 but its field tips are not; a DC "
                      "offset of H (a zero error of the field measurement) keeps a "
                      "symmetric model from fitting — subtract it from H.", LoopWarning,
                      stacklevel=4)
    offset = data_offset(H, d)
    if offset is not None:
        warnings.warn(f"{where}the data look offset by {offset:.4g} {unit}: the loop's "
                      "field is symmetric about 0 but its data's tips are not; the "
                      "model, started demagnetized, draws a centred loop — a DC offset "
                      "(the integration constant of a fluxmeter, say) keeps it from "
                      "fitting: subtract it.", LoopWarning, stacklevel=4)
    chi = Mmax / max(np.max(np.abs(H)), 1e-300)
    if chi > 2e6:
        warnings.warn(f"{where}the magnetization reaches {chi:.3g} times the field (the "
                      "relative permeability at the tips), beyond the most permeable "
                      "alloys (~1e6): is H in A/m (a column in kA/m without its unit "
                      "reads 1000× small)?", LoopWarning, stacklevel=4)


#: A sample this many times the loop's typical step away from its running median, and
#: more than `SPIKE_FRACTION` of the loop's range, is a spike.
SPIKE_STEPS, SPIKE_FRACTION = 30.0, 0.2


def find_spike(x) -> tuple[int, float, float] | None:
    """(index, distance from its neighbours' median, typical step) of the worst isolated
    spike of the record ``x`` (a sample far from both neighbours while they agree), or
    None. A loop is a continuous curve in sample order, so a good sample lies within a
    few steps of its neighbours."""
    x = np.asarray(x, float)
    if x.size < 8:
        return None
    step = float(np.median(np.abs(np.diff(x))))
    pad = np.concatenate([x[:1], x, x[-1:]])
    neighbours = 0.5 * (pad[:-2] + pad[2:])
    jump = np.abs(x - neighbours)
    k = int(np.argmax(jump))
    rest = np.delete(x, k)
    span = float(np.ptp(rest)) if rest.size else 0.0
    if span > 0 and jump[k] > SPIKE_STEPS * max(step, 1e-300) and \
            jump[k] > SPIKE_FRACTION * span and abs(pad[k] - pad[k + 2]) < 0.5 * jump[k]:
        return k, float(jump[k]), step
    return None


def data_offset(H, data) -> float | None:
    """The DC offset of a loop's data, (max + min)/2, where the field is symmetric about
    0 (|Hmax + Hmin| within 5 % of its range) but the data's tips are not (offset above
    10 % of their range); else None."""
    return field_offset(data, H)


def field_offset(H, data) -> float | None:
    """The DC offset of a loop's field, (Hmax + Hmin)/2, where the data are symmetric
    about 0 (|max + min| within 5 % of their range) but the field tips are not (offset
    above 10 % of the field's range); else None."""
    H, d = np.asarray(H, float), np.asarray(data, float)
    if not (np.ptp(H) > 0 and np.ptp(d) > 0):
        return None
    d_sym = abs(d.max() + d.min()) / np.ptp(d)
    offset = 0.5 * (H.max() + H.min())
    if d_sym < 0.05 and abs(offset) > 0.1 * np.ptp(H):
        return float(offset)
    return None

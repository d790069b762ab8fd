"""Figures (matplotlib is an optional dependency: ``pip install jaxhyst[plots]``).

Every function writes one PNG and closes its figure. Axes carry units; signals are shown
in engineering units (kA/m, μm, ppm) chosen per quantity.
"""

from __future__ import annotations

import io
import os

import numpy as np

from ._files import write_bytes
from .model.simulate import Simulation

#: How each observed output is displayed: (label, factor from SI, unit shown).
DISPLAY = {
    "displacement": ("y", 1e6, "μm"),
    "strain": ("ε", 1e6, "ppm"),
    "magnetostriction": ("λ", 1e6, "ppm"),
    "magnetization": ("M", 1e-3, "kA/m"),
    "flux_density": ("B", 1.0, "T"),
}


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "Plots need matplotlib: pip install 'jaxhyst[plots]' (or pip install matplotlib)."
        ) from err
    return plt


#: Figure formats by file extension (anything else — a device, a FIFO — gets PNG).
FIGURE_FORMATS = ("png", "pdf", "svg")


def figure_format(path) -> str | None:
    """The format a figure at ``path`` is written in: its extension's where it is one of
    `FIGURE_FORMATS`, PNG without an extension; None for another extension."""
    suffix = os.path.splitext(str(path))[1].lower().lstrip(".")
    if not suffix:
        return "png"
    return suffix if suffix in FIGURE_FORMATS else None


def _save(fig, path) -> None:
    """Write ``fig`` in the format of its extension (`figure_format`; PNG for a path
    without one) through the package's file writer (atomic for a regular file, in place
    for a device or FIFO) and close it."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format=figure_format(path) or "png", dpi=120)
    finally:
        _pyplot().close(fig)
    write_bytes(path, buf.getvalue())


def _field_axis(H):
    H = np.asarray(H)
    return (H / 1e3, "H (kA/m)") if np.max(np.abs(H)) >= 1e3 else (H, "H (A/m)")


def plot_simulation(sim: Simulation, path, title: str = "") -> None:
    """Three loops of the observed part against H: M (kA/m), λ (ppm), y (μm)."""
    plt = _pyplot()
    H, hlabel = _field_axis(sim.observed("H"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    axes[0].plot(H, np.asarray(sim.observed("M")) / 1e3)
    axes[0].set(xlabel=hlabel, ylabel="M (kA/m)", title="magnetization loop")
    axes[1].plot(H, np.asarray(sim.observed("lam")) * 1e6)
    axes[1].set(xlabel=hlabel, ylabel="λ (ppm)", title="magnetostriction")
    axes[2].plot(H, np.asarray(sim.observed("y")) * 1e6)
    axes[2].set(xlabel=hlabel, ylabel="y (μm)", title="displacement loop")
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    _save(fig, path)


def _join(parts):
    """Concatenate per-loop arrays with a NaN between loops (breaks the plotted line)."""
    if isinstance(parts, (list, tuple)):
        out = []
        for p in parts:
            out += [np.asarray(p, dtype=float), [np.nan]]
        return np.concatenate(out[:-1])
    return np.asarray(parts, dtype=float)


def plot_fit(H, data, model, output: str, path, t=None, title: str = "") -> None:
    """Measured vs fitted loop against H, with the error below (the paper's Fig 6).
    ``H`` in A/m, ``data``/``model`` in the output's SI unit, ``t`` in s (or sample index);
    each may be a list with one array per loop (a joint fit)."""
    plt = _pyplot()
    label, f, unit = DISPLAY[output]
    Hs, hlabel = _field_axis(_join(H))
    data, model = _join(data) * f, _join(model) * f
    x = np.arange(len(data)) if t is None else (np.asarray(t) - np.asarray(t)[0]) * 1e3
    xlabel = "sample" if t is None else "t (ms)"
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 7), height_ratios=[2, 1],
                                 constrained_layout=True)
    a1.plot(Hs, data, ".", ms=3, color="0.35", label="measured")
    a1.plot(Hs, model, "-", lw=1.4, color="C3", label="model")
    a1.set(xlabel=hlabel, ylabel=f"{label} ({unit})", title=title or "measured and fitted loop")
    a1.legend()
    err = model - data
    a2.plot(x, err, lw=1.0)
    a2.axhline(0, color="0.6", lw=0.8)
    rms = float(np.sqrt(np.nanmean(err**2)))
    a2.set(xlabel=xlabel, ylabel=f"model − measured ({unit})",
           title=f"error: rms {rms:.3g} {unit}, max {np.nanmax(np.abs(err)):.3g} {unit}")
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
    _save(fig, path)


def plot_predictions(loops, output: str, path, title: str = "") -> None:
    """Predicted loops against their data: ``loops`` is a list of (label, H (A/m),
    predicted, data or None) in the output's SI unit; one colour per loop, the data as
    dots, the prediction as a line."""
    plt = _pyplot()
    label, f, unit = DISPLAY[output]
    scale = 1e-3 if max(float(np.max(np.abs(H))) for _, H, _, _ in loops) >= 1e3 else 1.0
    hlabel = "H (kA/m)" if scale != 1.0 else "H (A/m)"
    fig, ax = plt.subplots(figsize=(7, 5.5), constrained_layout=True)
    for i, (name, H, predicted, data) in enumerate(loops):
        H = np.asarray(H) * scale
        if data is not None:
            ax.plot(H, np.asarray(data) * f, ".", ms=3, color=f"C{i % 10}", alpha=0.6)
        ax.plot(H, np.asarray(predicted) * f, "-", lw=1.3, color=f"C{i % 10}", label=name)
    ax.set(xlabel=hlabel, ylabel=f"{label} ({unit})",
           title=title or "predicted (lines) and measured (dots)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    _save(fig, path)


def plot_history(history: list[dict], names, lower, upper, path, title: str = "") -> None:
    """GA history: best and mean fitness per generation (the paper's Fig 3) and the best
    individual's parameters, scaled to their search box (Fig 4)."""
    plt = _pyplot()
    del lower, upper  # (the history stores box coordinates)
    g = np.array([h["generation"] for h in history])
    best = np.array([h["best_fitness"] for h in history])
    mean = np.array([h["mean_fitness"] for h in history])
    u = np.array([h["best_u"] for h in history])  # position in the box, order of names
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 4.5), constrained_layout=True)
    a1.semilogy(g, best, label="best F")
    a1.semilogy(g, np.where(mean > 0, mean, np.nan), label="mean F")
    t1 = next((h["generation"] for h in history if h["phase"] == "FCGA"), None)
    if t1 is not None:
        a1.axvline(t1 - 0.5, color="0.6", ls="--", lw=0.8)
        a1.text(t1, best.min(), " FCGA", color="0.4", va="bottom")
    a1.set(xlabel="generation", ylabel="fitness F = 1/√(c1 + E)", title="fitness (Fig 3)")
    a1.legend()
    for j, n in enumerate(names):
        a2.plot(g, u[:, j], label=n)
    a2.set(xlabel="generation", ylabel="position in search box (0 = lower, 1 = upper)",
           title="best parameters (Fig 4)", ylim=(-0.02, 1.02))
    a2.legend(ncol=2, fontsize=8)
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    _save(fig, path)


def plot_frequency_response(freq, G, path, title: str = "", marks=None) -> None:
    """Magnitude |ε/λ| and phase lag (degrees) of the structural response (Fig 8).
    ``marks``: optional (frequencies, G) drawn as labelled points (e.g. the drive
    frequencies of a study)."""
    plt = _pyplot()
    freq, G = np.asarray(freq), np.asarray(G)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, constrained_layout=True)
    a1.loglog(freq, np.abs(G))
    a1.set(ylabel="|ε/λ|", title=title or "structural frequency response (eq 13)")
    a2.semilogx(freq, -np.degrees(np.unwrap(np.angle(G))))
    if marks is not None:
        fm, Gm = np.asarray(marks[0]), np.asarray(marks[1])
        lag = -np.degrees(np.angle(Gm)) % 360
        a1.plot(fm, np.abs(Gm), "o", color="C3")
        a2.plot(fm, lag, "o", color="C3")
        for f_, l_ in zip(fm, lag, strict=True):
            a2.annotate(f"{l_:.1f}°", (f_, l_), textcoords="offset points", xytext=(-28, 6),
                        fontsize=8)
    a2.set(xlabel="frequency (Hz)", ylabel="phase lag (°)")
    for ax in (a1, a2):
        ax.grid(alpha=0.3, which="both")
    _save(fig, path)


def plot_table3_loops(loops: dict, path, title: str = "") -> None:
    """Fig 7: the magnetostriction λ(H) and strain ε(H) loops of the Table 3 study
    (``loops``: frequency → {"H", "lam", "strain", "data_strain"}), one colour per
    frequency; the noisy synthetic strain the identification saw as dots."""
    plt = _pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
    for i, (f, lp) in enumerate(sorted(loops.items(), key=lambda kv: float(kv[0]))):
        H = np.asarray(lp["H"]) / 1e3
        a1.plot(H, np.asarray(lp["lam"]) * 1e6, color=f"C{i}", label=f"{f} Hz")
        a2.plot(H, np.asarray(lp["strain"]) * 1e6, color=f"C{i}", label=f"{f} Hz")
        a2.plot(H, np.asarray(lp["data_strain"]) * 1e6, ".", color=f"C{i}", ms=2)
    a1.set(xlabel="H (kA/m)", ylabel="λ (ppm)", title="magnetostriction")
    a2.set(xlabel="H (kA/m)", ylabel="ε (ppm)", title="strain (lines: model, dots: data)")
    for ax in (a1, a2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    _save(fig, path)


def plot_identifiability(report, path, title: str = "") -> None:
    """Relative singular values of the Jacobian (log scale, null directions marked) and
    the correlation matrix of the identifiable parameters."""
    plt = _pyplot()
    s = np.asarray(report.singular_values)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    colors = ["C3" if v < 1e-8 else "C0" for v in s]
    a1.bar(np.arange(1, len(s) + 1), np.maximum(s, 1e-17), color=colors)
    a1.set_yscale("log")
    a1.set(xlabel="index", ylabel="σ / σ1", title=f"singular values (rank {report.rank}, "
           f"red: null)", xticks=np.arange(1, len(s) + 1))
    a1.grid(alpha=0.3, axis="y")
    corr = np.asarray(report.correlation, dtype=float)
    im = a2.imshow(np.ma.masked_invalid(corr), vmin=-1, vmax=1, cmap="RdBu_r")
    n = len(report.names)
    a2.set_xticks(range(n), report.names, rotation=60, fontsize=8)
    a2.set_yticks(range(n), report.names, fontsize=8)
    for i in range(n):
        for j in range(n):
            if np.isfinite(corr[i, j]):
                a2.text(j, i, f"{corr[i, j]:.2f}", ha="center", va="center", fontsize=6,
                        color="white" if abs(corr[i, j]) > 0.6 else "black")
    a2.set_title("correlation (blank: not identifiable)")
    fig.colorbar(im, ax=a2, shrink=0.8)
    if title:
        fig.suptitle(title)
    _save(fig, path)


def plot_compensation(result, path, title: str = "") -> None:
    """A compensation (`jaxhyst.control.Compensation`): the displacement against time —
    reference, uncompensated and compensated (μm) — the tracking errors (% of the
    reference's peak-to-peak), and the inputs with their limits."""
    plt = _pyplot()
    t = np.asarray(result.t) * 1e3
    r = np.asarray(result.reference.displacement)
    scale = result.reference.scale
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), constrained_layout=True)
    axes[0].plot(t, r * 1e6, "k", lw=2.5, alpha=0.35, label="reference")
    axes[0].plot(t, result.uncompensated_displacement * 1e6, label="uncompensated")
    axes[0].plot(t, result.displacement * 1e6, "--", label="compensated")
    axes[0].set(xlabel="t (ms)", ylabel="y (μm)", title="displacement")
    axes[1].plot(t, 100 * (result.uncompensated_displacement - r) / scale,
                 label=f"uncompensated, rms {100 * result.uncompensated_error:.2g} %")
    axes[1].plot(t, 100 * (result.displacement - r) / scale,
                 label=f"compensated, rms {100 * result.error:.2g} %")
    axes[1].set(xlabel="t (ms)", ylabel="y − reference (% of peak-to-peak)",
                title="tracking error")
    axes[2].plot(t, result.uncompensated_input, label="uncompensated")
    axes[2].plot(t, result.input, label="compensated")
    for bound in (result.limits.lower, result.limits.upper):
        axes[2].axhline(bound, color="0.5", ls=":", lw=1)
    what = "current" if result.unit == "A" else "AC field"
    axes[2].set(xlabel="t (ms)", ylabel=f"{what} ({result.unit})", title=f"input ({what})")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    _save(fig, path)

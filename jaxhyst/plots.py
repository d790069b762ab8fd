"""Figures (matplotlib is an optional dependency: ``pip install jaxhyst[plots]``)."""

from __future__ import annotations

import numpy as np

from .model.simulate import Simulation


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


def plot_simulation(sim: Simulation, path, title: str = "") -> None:
    """Three loops of the observed part against H (kA/m): M (kA/m), λ (ppm), y (μm)."""
    plt = _pyplot()
    H = np.asarray(sim.observed("H")) / 1e3
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    axes[0].plot(H, np.asarray(sim.observed("M")) / 1e3)
    axes[0].set(xlabel="H (kA/m)", ylabel="M (kA/m)", title="magnetization loop")
    axes[1].plot(H, np.asarray(sim.observed("lam")) * 1e6)
    axes[1].set(xlabel="H (kA/m)", ylabel="λ (ppm)", title="magnetostriction")
    axes[2].plot(H, np.asarray(sim.observed("y")) * 1e6)
    axes[2].set(xlabel="H (kA/m)", ylabel="y (μm)", title="displacement loop")
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=120)
    plt.close(fig)

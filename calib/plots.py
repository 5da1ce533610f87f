"""Pictures of a calibration: the fitted curves with their samples, and estimate-vs-truth plots."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from optitact.io.files import atomic_write_png_figure

__all__ = ["plot_fit", "plot_errors"]

#: One element per ring of the default sensor (apex, 22.5, 45 and 67.5 degrees).
RING_EXAMPLES = (0, 1, 9, 25)


def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    from optitact._optional import require

    return require("matplotlib.figure", purpose="plots").Figure(figsize=size, layout="constrained")


def plot_fit(cal, readings, forces, path: str | os.PathLike) -> Path:
    """Save the fitted g(G) and shear curves of one element per ring, with samples and residuals.

    Parameters
    ----------
    cal : Calibration
    readings : Readings
        Stack readings the calibration was fitted to (or any others).
    forces : (T, E, 3) array_like
        True element-local forces of those readings (N).
    path : path-like
        PNG to write.
    """
    f = np.asarray(forces, dtype=np.float64)
    est, _ = cal.forces(readings)
    fig = _figure(2, 2, (11, 8))
    axes = fig.subplots(2, 2)
    ax = axes[0, 0]
    elements = [e for e in RING_EXAMPLES if e < readings.n_elements]
    for e in elements:
        ok = readings.contact[:, e]
        line = ax.plot(readings.G[ok, e], f[ok, e, 2], ".", ms=3, alpha=0.5)[0]
        grid = np.linspace(0, cal.g_max[e], 100)
        s = grid / cal.g_scale[e]
        ax.plot(grid, np.stack([np.ones_like(s), s, s**2, s**3], -1) @ cal.g[e], "-",
                color=line.get_color(), label=f"element {e}")
    ax.set(xlabel="G (grey level x mm$^2$)", ylabel="Fz (N)", title=f"g(G), model {cal.model}")
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    for e in elements:
        ok = readings.contact[:, e]
        ax.plot(readings.u[ok, e, 0], f[ok, e, 0], ".", ms=3, alpha=0.5, label=f"element {e}")
    ax.set(xlabel="ux (mm)", ylabel="Fx (N)", title="shear samples (x)")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    for k, name in enumerate(("Fx", "Fy", "Fz")):
        ax.plot(f[..., k].ravel(), est[..., k].ravel(), ".", ms=2, alpha=0.4, label=name)
    lim = [min(f.min(), est.min()), max(f.max(), est.max())]
    ax.plot(lim, lim, "k-", lw=0.8)
    ax.set(xlabel="true force (N)", ylabel="estimated force (N)", title="estimate vs truth")
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    for k, name in enumerate(("Fx", "Fy", "Fz")):
        ax.hist((est[..., k] - f[..., k]).ravel(), bins=60, histtype="step", label=name)
    ax.set(xlabel="estimate - truth (N)", ylabel="samples", title="residuals")
    ax.legend(fontsize=8)
    return atomic_write_png_figure(fig, path, dpi=100)


def plot_errors(truth, estimates: dict, path: str | os.PathLike) -> Path:
    """Save estimated vs true forces for several models side by side (held-out set)."""
    t = np.asarray(truth, dtype=np.float64)
    fig = _figure(1, len(estimates), (5 * len(estimates), 4.5))
    axes = np.atleast_1d(fig.subplots(1, len(estimates)))
    for ax, (model, est) in zip(axes, estimates.items(), strict=True):
        for k, name in enumerate(("Fx", "Fy", "Fz")):
            rmse = float(np.sqrt(np.mean((est[..., k] - t[..., k]) ** 2)))
            ax.plot(t[..., k].ravel(), est[..., k].ravel(), ".", ms=2, alpha=0.4,
                    label=f"{name} (RMSE {rmse:.3f} N)")
        lim = [min(t.min(), est.min()), max(t.max(), est.max())]
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.set(xlabel="true force (N)", ylabel="estimated force (N)", title=f"model {model}")
        ax.legend(fontsize=8)
    return atomic_write_png_figure(fig, path, dpi=100)

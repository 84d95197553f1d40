"""Figures of FE model updating: the MAC after the update, frequency errors before /
after, and predicted vs measured FRFs at sensors (held out or not).

Object API on the Agg canvas through :mod:`workbench.plotting` (no pyplot, no
global backend); every file written atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from workbench.plotting import frequency_grid, lean_axes, new_figure, save_png

__all__ = ["plot_update", "plot_prediction", "plot_mode_shapes"]


def plot_update(folder: str | os.PathLike, res) -> list[Path]:
    """``update_mac.png`` and ``update_frequencies.png`` of an :class:`UpdateResult`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    fig = new_figure(6, 4.5, dpi=110)
    ax = fig.subplots()
    im = ax.imshow(res.mac, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xlabel("FE mode")
    ax.set_ylabel("measured mode")
    ax.set_title("MAC of residues after the update")
    fig.colorbar(im, ax=ax)
    save_png(fig, folder / "update_mac.png")

    fig = new_figure(6, 4, dpi=110)
    ax = fig.subplots()
    im_, kf = [i for i, _ in res.pairs], [k for _, k in res.pairs]
    fm = res.freq_measured_hz[im_]
    ax.semilogx(fm, 100 * (res.freq_before_hz[kf] / fm - 1), "o-", label="before")
    ax.semilogx(fm, 100 * (res.freq_after_hz[kf] / fm - 1), "s-", label="after")
    for i in res.unpaired:
        ax.axvline(res.freq_measured_hz[i], color="0.6", ls=":", lw=0.8)
    ax.set_xlabel("measured frequency (Hz)  (dotted: unpaired measured modes)")
    ax.set_ylabel("FE - measured (%)")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    save_png(fig, folder / "update_frequencies.png")
    return [folder / "update_mac.png", folder / "update_frequencies.png"]


def plot_prediction(
    path: str | os.PathLike,
    freq_hz: np.ndarray,
    G_meas: np.ndarray,
    G_var: np.ndarray | None,
    predictions: dict[str, np.ndarray],
    *,
    input_names,
    output_names,
) -> None:
    """Magnitude per element: measured, its noise level (sqrt G_var), and each prediction.

    Parameters
    ----------
    freq_hz : (n_f,) array, Hz
    G_meas : (n_f, n_y, n_u) complex array, m/N
    G_var : (n_f, n_y, n_u) array or None
    predictions : label -> (n_f, n_y, n_u) complex array (e.g. "prior", "updated")
    """
    n_f, n_y, n_u = G_meas.shape
    fig = new_figure(2.8 * n_u + 1, 2.3 * n_y + 1, dpi=90)
    axes = frequency_grid(fig, n_y, n_u, freq_hz)
    colors = ("tab:red", "tab:blue", "tab:green", "tab:orange")
    for i in range(n_y):
        for j in range(n_u):
            ax = axes[i, j]
            ax.loglog(freq_hz, np.abs(G_meas[:, i, j]), "k", lw=0.8, label="measured")
            if G_var is not None:
                ax.loglog(freq_hz, np.sqrt(G_var[:, i, j]), color="0.6", lw=0.6, label="noise")
            for (label, G), col in zip(predictions.items(), colors):
                err = np.abs(G[:, i, j] - G_meas[:, i, j])
                ax.loglog(freq_hz, err, color=col, lw=0.6, ls=":", label=f"|error| {label}")
                ax.loglog(freq_hz, np.abs(G[:, i, j]), color=col, lw=0.8, label=label)
            ax.set_title(f"{output_names[i]} / {input_names[j]}", fontsize=8)
            ax.tick_params(labelsize=6)
            lean_axes(ax)
            if i == n_y - 1:
                ax.set_xlabel("Hz", fontsize=7)
            if j == 0:
                ax.set_ylabel("|G|, m/N", fontsize=7)
    axes[0, 0].legend(fontsize=5)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.08, top=0.93, hspace=0.4, wspace=0.3)
    save_png(fig, path)


def plot_mode_shapes(path: str | os.PathLike, fe, alpha, ext, pairs) -> None:
    """Mass-normalized shapes per paired mode: FE (updated) at every sensor and actuator of
    the file, and the measured shapes that Theorem 2 scaled at the measured channels.

    Parameters
    ----------
    fe : FEModel; alpha : (p,) parameters to evaluate it at
    ext : workbench.modal.scaling.ExtendedModes (measured; rows = fitted modes)
    pairs : sequence of (i_measured, k_fe)
    """
    from .eigen import solve_modes

    pairs = [(i, k) for i, k in pairs if i < ext.phi_sensors.shape[0]]
    if not pairs:
        return
    modes = solve_modes(*fe.matrices(alpha), min(fe.n_dof, max(k for _, k in pairs) + 1))
    names = list(fe.output_names) + list(fe.input_names)
    meas_names = list(ext.model.output_names) + list(ext.model.input_names)
    n = len(pairs)
    cols = min(3, n)
    rows = -(-n // cols)
    fig = new_figure(3.2 * cols + 0.5, 2.4 * rows + 0.6, dpi=90)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    x = np.arange(len(names))
    for ax, (i, k) in zip(axes, pairs):
        phi = np.concatenate([fe.C @ modes.Phi[:, k], fe.B.T @ modes.Phi[:, k]])
        meas = np.concatenate([ext.phi_sensors[i], ext.phi_actuators[i]])
        idx = [names.index(m) for m in meas_names]
        if np.all(np.isfinite(meas)):
            phi = phi * np.sign(phi[idx] @ meas)
        # channels, not positions along the structure: markers, no line between them
        ax.plot(x, phi, "o", color="tab:blue", ms=4, label="FE (updated)")
        ax.axvline(len(fe.output_names) - 0.5, color="0.6", lw=0.6, ls=":")
        ax.plot(idx, meas, "x", color="k", ms=7, label="measured (Thm 2)")
        ax.axhline(0, color="0.7", lw=0.5)
        ax.set_xticks(x)
        ax.set_xticklabels(names, fontsize=6)
        ax.tick_params(labelsize=6)
        ax.set_title(f"{modes.freq_hz[k]:.1f} Hz", fontsize=8)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].set_ylabel("phi, 1/sqrt(kg)", fontsize=7)
    axes[0].legend(fontsize=6)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.08, top=0.93, hspace=0.55, wspace=0.3)
    save_png(fig, path)

"""Plot helpers shared by the commands: Bode overlay with a noise band, a
channel x frequency error map, time overlays, residual spectra and residual
cross-correlations. Every figure is written atomically as PNG.

Figures are built with matplotlib's object API on the Agg canvas
(``matplotlib.figure.Figure`` + ``FigureCanvasAgg``): no pyplot, no global
backend switch, nothing happens at import time, and it works headless. This
is the effect of ``matplotlib.use('Agg')`` without changing the backend of a
user's interactive session that imports the workbench.
"""

from __future__ import annotations

import os

import numpy as np

from workbench.core.atomic import atomic_path

__all__ = [
    "new_figure",
    "save_png",
    "save_bode_overlay",
    "draw_noise_level",
    "save_error_map",
    "save_time_overlay",
    "save_residual_spectra",
    "save_xcorr",
]


def new_figure(width: float, height: float, *, dpi: int = 80):
    """A matplotlib Figure on its own Agg canvas (inches): no pyplot, no global backend."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def lean_axes(ax) -> None:
    """Few ticks, no minor ticks: a grid of dozens of log axes draws in a second, not ten."""
    from matplotlib.ticker import LogLocator, MaxNLocator, NullLocator

    for axis in (ax.xaxis, ax.yaxis):
        axis.set_minor_locator(NullLocator())
        if axis.get_scale() == "log":
            axis.set_major_locator(LogLocator(numticks=4))
        else:
            axis.set_major_locator(MaxNLocator(4))


def frequency_grid(fig, n_rows: int, n_cols: int, freq_hz) -> np.ndarray:
    """(n_rows, n_cols) axes over one frequency range, x tick labels on the bottom row.

    Not ``sharex``: on a grid of dozens of axes every limit change propagates to all the
    others (quadratic; on the 12 x 6 Bode overlay most of the figure's time). The same
    range set on each axes looks the same.
    """
    axes = fig.subplots(n_rows, n_cols, squeeze=False)
    f = np.asarray(freq_hz, float)
    pos = f[f > 0]
    for k, ax in enumerate(axes.flat):
        if pos.size:
            ax.set_xlim(pos.min(), pos.max())
        if k < (n_rows - 1) * n_cols:
            ax.tick_params(labelbottom=False)
    return axes


def save_png(fig, path: str | os.PathLike) -> None:
    """Write ``fig`` as PNG atomically (temporary file in the same folder, then rename)."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png")


def save_bode_overlay(
    path: str | os.PathLike,
    freq_hz: np.ndarray,
    G_meas: np.ndarray,
    G_model: np.ndarray,
    G_var: np.ndarray | None,
    *,
    input_names,
    output_names,
) -> None:
    """Magnitude and phase per element, measured vs model, with the noise level.

    Parameters
    ----------
    freq_hz : (n_f,) array, Hz
    G_meas, G_model : (n_f, n_y, n_u) complex arrays
    G_var : (n_f, n_y, n_u) array or None
        Variance of G_meas; sigma = sqrt(G_var). The magnitude band is
        |G| +- 2 sigma, the phase band +- arcsin(min(1, 2 sigma / |G|)); the
        noise level sigma itself is drawn (dotted) beside the misfit
        |G_meas - G_model| (thin blue): where the measured curve sits at the
        noise level it is noise, and a misfit at the noise level is no misfit.
    """
    n_f, n_y, n_u = G_meas.shape
    fig = new_figure(2.6 * n_u + 1, 2.6 * n_y + 1)
    axes = frequency_grid(fig, 2 * n_y, n_u, freq_hz)
    for i in range(n_y):
        for j in range(n_u):
            am, ap = axes[2 * i, j], axes[2 * i + 1, j]
            g, gm = G_meas[:, i, j], G_model[:, i, j]
            mag = np.abs(g)
            if G_var is not None:
                sig = 2 * np.sqrt(G_var[:, i, j])
                lo = np.maximum(mag - sig, mag * 1e-3)
                am.fill_between(freq_hz, lo, mag + sig, color="0.8", lw=0, label="±2σ")
                dph = np.degrees(np.arcsin(np.minimum(1.0, sig / np.maximum(mag, 1e-300))))
                ph = np.degrees(np.angle(g))
                ap.fill_between(freq_hz, ph - dph, ph + dph, color="0.8", lw=0)
            am.loglog(freq_hz, mag, "k", lw=0.8, label="measured")
            am.loglog(freq_hz, np.abs(gm), "r", lw=0.8, label="model")
            if G_var is not None:
                draw_noise_level(am, freq_hz, G_var[:, i, j], misfit=np.abs(g - gm))
            ap.semilogx(freq_hz, np.degrees(np.angle(g)), "k", lw=0.8)
            ap.semilogx(freq_hz, np.degrees(np.angle(gm)), "r", lw=0.8)
            ap.set_ylim(-185, 185)
            am.set_title(f"{output_names[i]} / {input_names[j]}", fontsize=8)
            am.tick_params(labelsize=6)
            ap.tick_params(labelsize=6)
            lean_axes(am)
            lean_axes(ap)
            if j == 0:
                am.set_ylabel("|G|", fontsize=7)
                ap.set_ylabel("phase, deg", fontsize=7)
            if i == n_y - 1:
                ap.set_xlabel("Hz", fontsize=7)
    axes[0, 0].legend(fontsize=6)
    # tight_layout costs seconds on a 12 x 6 grid; fixed margins do
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.05, top=0.96, hspace=0.45, wspace=0.35)
    save_png(fig, path)


def draw_noise_level(ax, freq_hz, g_var, *, misfit=None) -> None:
    """The noise level sqrt(G_var) (dotted grey) and, optionally, the misfit (thin blue).

    Shared by every FRF figure that shows measured data, so noise is drawn the
    same way everywhere and not read as misfit.
    """
    sigma = np.sqrt(np.maximum(np.asarray(g_var, float), 0.0))
    ax.loglog(
        freq_hz, np.where(sigma > 0, sigma, np.nan), ":", color="0.45", lw=0.8, label="noise σ"
    )
    if misfit is not None:
        ax.loglog(
            freq_hz,
            np.where(misfit > 0, misfit, np.nan),
            color="tab:blue",
            lw=0.5,
            alpha=0.7,
            label="|meas - model|",
        )


def save_error_map(
    path: str | os.PathLike,
    freq_hz: np.ndarray,
    stat: np.ndarray,
    *,
    channel_labels,
    threshold: float,
    title: str,
) -> None:
    """Channel x frequency image of log10 of a per-line statistic.

    Parameters
    ----------
    freq_hz : (n_f,) array, Hz
    stat : (n_f, n_ch) array
        Non-negative statistic per line and channel (z or a ratio).
    threshold : float
        Drawn as the colour bar's mark when finite.
    """
    n_f, n_ch = stat.shape
    fig = new_figure(10, 1.2 + 0.28 * n_ch)
    ax = fig.subplots()
    data = np.log10(np.maximum(stat.T, 1e-12))
    edges = np.r_[freq_hz[0], 0.5 * (freq_hz[1:] + freq_hz[:-1]), freq_hz[-1]]
    mesh = ax.pcolormesh(edges, np.arange(n_ch + 1), data, cmap="magma", shading="flat")
    ax.set_xscale("log" if freq_hz[0] > 0 else "linear")
    ax.set_yticks(np.arange(n_ch) + 0.5)
    ax.set_yticklabels(channel_labels, fontsize=6)
    ax.invert_yaxis()
    ax.set_xlabel("frequency, Hz")
    ax.set_title(title, fontsize=9)
    cb = fig.colorbar(mesh, ax=ax)
    cb.set_label("log10", fontsize=8)
    if np.isfinite(threshold) and threshold > 0:
        cb.ax.axhline(np.log10(threshold), color="c", lw=2)
    fig.tight_layout()
    save_png(fig, path)


def save_time_overlay(
    path: str | os.PathLike,
    t: np.ndarray,
    y: np.ndarray,
    y_model: np.ndarray,
    *,
    output_names,
    model_label: str = "model",
) -> None:
    """Measured vs simulated output and the residual per output. t (N,) s, y (N, n_y) m."""
    n_y = y.shape[1]
    fig = new_figure(10, 1.8 * n_y + 1)
    axes = fig.subplots(n_y, 2, squeeze=False, sharex=True)
    for i in range(n_y):
        axes[i, 0].plot(t, y[:, i], "k", lw=0.6, label="measured")
        axes[i, 0].plot(t, y_model[:, i], "r", lw=0.6, label=model_label)
        axes[i, 1].plot(t, y[:, i] - y_model[:, i], "b", lw=0.6)
        axes[i, 0].set_ylabel(output_names[i], fontsize=8)
        for ax in axes[i]:
            ax.tick_params(labelsize=6)
    axes[0, 0].set_title("output", fontsize=9)
    axes[0, 1].set_title("residual y - y_model", fontsize=9)
    axes[0, 0].legend(fontsize=6)
    axes[-1, 0].set_xlabel("time, s")
    axes[-1, 1].set_xlabel("time, s")
    fig.tight_layout()
    save_png(fig, path)


def save_residual_spectra(
    path: str | os.PathLike, freq_hz, psd_residual, psd_output, *, output_names
) -> None:
    """Welch PSD of the residual vs of y per output, (n_w,) and (n_w, n_y), m^2/Hz."""
    n_y = psd_output.shape[1]
    cols = min(3, n_y)
    rows = int(np.ceil(n_y / cols))
    fig = new_figure(4 * cols, 2.6 * rows + 0.5)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    f = freq_hz[1:]
    for i in range(n_y):
        axes[i].loglog(f, psd_output[1:, i], "k", lw=0.7, label="y")
        axes[i].loglog(f, psd_residual[1:, i], "r", lw=0.7, label="residual")
        axes[i].set_title(output_names[i], fontsize=8)
        axes[i].tick_params(labelsize=6)
    for ax in axes[n_y:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    save_png(fig, path)


def save_xcorr(
    path: str | os.PathLike, lags, xcorr, bound: float, *, input_names, output_names, against: str
) -> None:
    """Residual/excitation cross-correlation per pair with the +-bound. xcorr (n_lag, n_y, n_u)."""
    _, n_y, n_u = xcorr.shape
    fig = new_figure(2.2 * n_u + 1, 1.6 * n_y + 1)
    axes = fig.subplots(n_y, n_u, squeeze=False, sharex=True, sharey=True)
    for i in range(n_y):
        for j in range(n_u):
            ax = axes[i, j]
            ax.vlines(lags, 0, xcorr[:, i, j], color="b", lw=0.8)
            ax.axhline(bound, color="r", lw=0.6, ls="--")
            ax.axhline(-bound, color="r", lw=0.6, ls="--")
            ax.tick_params(labelsize=5)
            if i == 0:
                ax.set_title(f"{against}: {input_names[j]}", fontsize=7)
            if j == 0:
                ax.set_ylabel(f"e: {output_names[i]}", fontsize=7)
    fig.suptitle("residual cross-correlation, 99 % bounds (lag in samples)", fontsize=9)
    fig.tight_layout()
    save_png(fig, path)

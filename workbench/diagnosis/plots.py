"""PNG figures for diagnose and augment: error maps and Bode overlays, before and after.

Figures use matplotlib's object API on their own Agg canvas
(:func:`workbench.plotting.new_figure`): no pyplot, no global backend switch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.io.formats import FrfData, TimeData
from workbench.modal.model import ModalModel
from workbench.plotting import new_figure, save_png

__all__ = ["write_plots"]


def _freq(data) -> np.ndarray:
    if isinstance(data, FrfData):
        return data.freq
    return np.geomspace(data.fs / data.n_samples * 2, data.fs / 2 * 0.95, 400)


def write_plots(
    folder: str | Path,
    data: FrfData | TimeData,
    before: ModalModel,
    after: ModalModel,
    *,
    title: str,
) -> list[Path]:
    """Write error_map.png and bode.png (and time_residual.png for time data) into ``folder``.

    Returns the paths written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    f = _freq(data)
    Gb, Ga = before.frf(f), after.frf(f)
    written = []
    n_y, n_u = Gb.shape[1:]
    labels = [f"y{i}/u{j}" for i in range(n_y) for j in range(n_u)]
    if isinstance(data, FrfData):
        nrm = np.linalg.norm(data.G, axis=(1, 2))[:, None, None]
        maps = [np.abs(data.G - G) / nrm for G in (Gb, Ga)]
        fig = new_figure(12, 5, dpi=110)
        axes = fig.subplots(1, 2, sharey=True)
        vmax = np.log10(max(m.max() for m in maps))
        for ax, m, name in zip(axes, maps, ("before", "after")):
            im = ax.imshow(
                np.log10(m.reshape(f.size, -1).T + 1e-12),
                aspect="auto",
                origin="lower",
                extent=(f[0], f[-1], -0.5, n_y * n_u - 0.5),
                vmin=vmax - 4,
                vmax=vmax,
                cmap="viridis",
            )
            ax.set_title(f"{name}: log10 |G_meas - G_model| / ||G_meas||")
            ax.set_xlabel("frequency (Hz)")
        axes[0].set_yticks(range(n_y * n_u))
        axes[0].set_yticklabels(labels, fontsize=6)
        fig.colorbar(im, ax=axes)
        fig.suptitle(title)
        written.append(_save(fig, folder / "error_map.png"))
    # Bode overlay of the diagonal (or first) channels
    chans = [(i, i) for i in range(min(n_y, n_u))][:4] or [(0, 0)]
    fig = new_figure(4 * len(chans), 6, dpi=110)
    axes = fig.subplots(2, len(chans), squeeze=False)
    for k, (i, j) in enumerate(chans):
        ax_m, ax_p = axes[0, k], axes[1, k]
        if isinstance(data, FrfData):
            ax_m.loglog(f, np.abs(data.G[:, i, j]), "k.", ms=2, label="measured")
            ax_p.semilogx(f, np.degrees(np.angle(data.G[:, i, j])), "k.", ms=2)
        ax_m.loglog(f, np.abs(Gb[:, i, j]), "C0", label="model before")
        ax_m.loglog(f, np.abs(Ga[:, i, j]), "C3--", label="model after")
        ax_p.semilogx(f, np.degrees(np.angle(Gb[:, i, j])), "C0")
        ax_p.semilogx(f, np.degrees(np.angle(Ga[:, i, j])), "C3--")
        ax_m.set_title(f"y{i}/u{j}")
        ax_p.set_xlabel("frequency (Hz)")
    axes[0, 0].set_ylabel("magnitude (m/N)")
    axes[1, 0].set_ylabel("phase (deg)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title)
    written.append(_save(fig, folder / "bode.png"))
    if isinstance(data, TimeData):
        from workbench.diagnosis.problem import TimeProblem

        prob = TimeProblem(data)
        t = data.t
        fig = new_figure(12, 4, dpi=110)
        axes = fig.subplots(1, 2, sharey=True)
        for ax, m, name in zip(axes, (before, after), ("before", "after")):
            e = data.y - prob.predict(m)
            ax.plot(t, e, lw=0.5)
            ax.set_title(
                f"{name}: residual y - y_model (error "
                f"{np.linalg.norm(e) / np.linalg.norm(data.y):.3g})"
            )
            ax.set_xlabel("time (s)")
        axes[0].set_ylabel("m")
        fig.suptitle(title)
        written.append(_save(fig, folder / "time_residual.png"))
    return written


def _save(fig, path: Path) -> Path:
    save_png(fig, path)
    return path

"""Figures of a :class:`~workbench.validate.compare.Comparison`: error map, Bode or time overlays.

Library code (the ``compare`` command and the scenario loop stages both call
:func:`write_plots`); matplotlib is imported only when a figure is drawn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.core.atomic import check_not_input, check_output
from workbench.validate.compare import Comparison

__all__ = ["write_plots"]


def write_plots(res: Comparison, folder: Path, inputs) -> list[Path]:
    """The figures of a comparison, into ``folder``; returns the paths written."""
    from workbench import plotting

    check_output(folder, inputs, folder=True)
    folder.mkdir(parents=True, exist_ok=True)
    written = []

    def target(name):
        p = folder / name
        check_not_input(p, inputs)
        written.append(p)
        return p

    if res.kind == "frf":
        labels = [f"{y}/{u}" for y in res.output_names for u in res.input_names]
        stat = res.error_map.reshape(res.error_map.shape[0], -1)
        f = res.frf
        plotting.save_bode_overlay(
            target("bode_overlay.png"),
            f.freq_hz,
            f.G_meas,
            f.G_model,
            f.G_var,
            input_names=res.input_names,
            output_names=res.output_names,
        )
    else:
        labels = list(res.output_names)
        stat = res.error_map
        t = res.time
        tt = np.arange(t.y.shape[0]) / t.fs
        x0 = t.y_model_x0 is not None
        plotting.save_time_overlay(
            target("time_overlay.png"),
            tt,
            t.y,
            t.y_model_x0 if x0 else t.y_model,
            output_names=res.output_names,
            model_label="model, estimated start" if x0 else "model, from rest",
        )
        plotting.save_residual_spectra(
            target("residual_spectra.png"),
            t.psd_freq_hz,
            t.psd_residual,
            t.psd_output,
            output_names=res.output_names,
        )
        plotting.save_xcorr(
            target("residual_xcorr.png"),
            t.xcorr_lags,
            t.xcorr,
            t.xcorr_bound,
            input_names=res.input_names,
            output_names=res.output_names,
            against=t.xcorr_against,
        )
    plotting.save_error_map(
        target("error_map.png"),
        res.map_freq_hz,
        stat,
        channel_labels=labels,
        threshold=res.threshold,
        title=res.map_label,
    )
    return written

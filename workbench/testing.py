"""Closed-loop regression assertions for pytest: stability, margins, bandwidth, tracking.

Each assertion takes a plant and a controller and raises ``AssertionError``
naming the figure, its value, the bound and the DOF (loop) that fails, every
failing DOF in one message::

    import workbench.testing as wt

    def test_my_controller():
        wt.assert_stable("wafer_stage", "K.npz")
        wt.assert_margins("wafer_stage", "K.npz", phase_margin_deg=30, s_peak_max=2.0)
        wt.assert_bandwidth("wafer_stage", "K.npz", crossover_hz=150)
        wt.assert_tracking("wafer_stage", "K.npz", profile, dof="y", ma_max=5e-9, msd_max=5e-9)

The plant is

* a true plant of ``plants/`` (an object, or its registry name): the frequency
  figures use its linear model with its own delay (which holds the real-time
  system's delay), the time simulation the object itself (noise, quantization,
  nonlinear effects);
* a model (:class:`~workbench.core.model.LTIModel`, python-control
  ``StateSpace``, or a model file): noise-free, with its ``delay_s``;
* a measured FRF (:class:`~workbench.io.formats.FrfData` or an FRF file):
  frequency-domain figures only (stability by the Nyquist count).

The controller is a :class:`controllers.Controller`, a discrete python-control
``StateSpace`` e -> u, or a spec-5 controller file. The figures are those of
:func:`workbench.loop.analyze_loop` (loop-at-a-time, the other loops closed)
and :func:`workbench.scan.tracking_figures`; ``loop_delay_samples`` adds
computation delay in the loop as there.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from workbench.core.errors import InputError

__all__ = ["assert_stable", "assert_margins", "assert_bandwidth", "assert_tracking"]


# ------------------------------------------------------------------ inputs
def _is_plant_object(obj) -> bool:
    return hasattr(obj, "step") and hasattr(obj, "linear_model") and hasattr(obj, "delay_s")


def _plant(plant):
    """(frequency-domain plant: model or FrfData, time-domain plant or None)."""
    from workbench.core.model import LTIModel

    if isinstance(plant, (str, os.PathLike)):
        import plants

        key = {"stage": "wafer_stage"}.get(str(plant), str(plant))
        if key in plants.PLANTS:
            plant = plants.get_plant(key)
        else:
            from workbench.io.formats import TimeData, load_any

            if not os.path.isfile(plant):
                raise InputError(
                    f"plant: expected a plant name ({', '.join(plants.PLANTS)}), a model or FRF "
                    f"file, got {str(plant)!r}"
                )
            plant = load_any(plant)
            if isinstance(plant, TimeData):
                raise InputError("plant: expected a model or a measured FRF, got time data")
    if _is_plant_object(plant):
        model = LTIModel.from_statespace(plant.linear_model(), delay_s=float(plant.delay_s))
        return model, plant
    from workbench.io.formats import FrfData

    if isinstance(plant, FrfData):
        return plant, None
    from workbench.core.model import as_model

    return as_model(plant), plant


def _controller(controller):
    """A :class:`controllers.Controller` from a Controller, a discrete StateSpace or a file."""
    from controllers.protocol import StateSpaceController

    if isinstance(controller, (str, os.PathLike)):
        return StateSpaceController.read(controller)
    if hasattr(controller, "step") and hasattr(controller, "fs"):
        return controller
    dt = getattr(controller, "dt", None)
    if dt is None or not dt or dt is True:
        raise InputError(
            "controller: expected a Controller, a discrete StateSpace (dt = 1/fs) or a "
            f"controller file, got {type(controller).__name__}"
        )
    return StateSpaceController(
        A=controller.A, B=controller.B, C=controller.C, D=controller.D, fs=1.0 / float(dt)
    )


def _analysis(plant, controller, loop_delay_samples: int):
    from workbench.loop import analyze_loop

    fplant, _ = _plant(plant)
    return analyze_loop(fplant, _controller(controller), loop_delay_samples=loop_delay_samples)


def _select(loops, dofs: Sequence[str | int] | None):
    """The LoopFigures of the DOFs named (names or indices); all when None."""
    if dofs is None:
        return list(loops)
    names = [lp.name for lp in loops]
    out = []
    for d in dofs:
        if isinstance(d, (int, np.integer)) and 0 <= d < len(loops):
            out.append(loops[int(d)])
        elif d in names:
            out.append(loops[names.index(d)])
        else:
            raise InputError(f"dofs: expected loop names in {names} or indices, got {d!r}")
    return out


def _index(d, names: list[str], what: str) -> int:
    """Index of an output given by name or index (one-line InputError otherwise)."""
    if isinstance(d, (int, np.integer)) and 0 <= d < len(names):
        return int(d)
    if d in names:
        return names.index(d)
    raise InputError(f"{what}: expected an output name in {names} or an index, got {d!r}")


def _fail(what: str, problems: list[str]) -> None:
    if problems:
        raise AssertionError(f"{what}: " + "; ".join(problems))


def _db(x: float) -> float:
    return float(20 * np.log10(x)) if x > 0 else float("-inf")


# ------------------------------------------------------------------ assertions
def assert_stable(plant, controller, *, loop_delay_samples: int = 0) -> None:
    """The closed loop is stable (eigenvalues on a model, Nyquist count on FRF data).

    Raises
    ------
    AssertionError
        Unstable (largest closed-loop pole radius, or the unstable loops and
        their Nyquist counts), or undecided.
    """
    a = _analysis(plant, controller, loop_delay_samples)
    if a.stable:
        return
    if a.stable is None:
        raise AssertionError(f"closed-loop stability undecided ({a.stability_note})")
    if a.max_pole_radius is not None:
        raise AssertionError(
            f"closed loop unstable: largest pole radius {a.max_pole_radius:.6f} >= bound 1 "
            f"(all loops)"
        )
    bad = [
        f"loop {lp.name}: {lp.unstable_poles} unstable poles" for lp in a.loops if lp.unstable_poles
    ]
    _fail("closed loop unstable (Nyquist, bound 0 unstable poles)", bad)


def assert_margins(
    plant,
    controller,
    *,
    gain_margin_db: float | None = None,
    phase_margin_deg: float | None = None,
    disk_margin: float | None = None,
    s_peak_max: float | None = None,
    dofs: Sequence[str | int] | None = None,
    loop_delay_samples: int = 0,
) -> None:
    """Every loop (or those of ``dofs``) meets the margins given (None = not checked).

    Parameters
    ----------
    gain_margin_db : float
        Lower bound on the gain margin, dB.
    phase_margin_deg : float
        Lower bound on the phase margin, degrees.
    disk_margin : float
        Lower bound on the (balanced) disk margin alpha, -.
    s_peak_max : float
        Upper bound on |S_i|inf, ratio (2.0 = 6 dB).
    """
    if all(b is None for b in (gain_margin_db, phase_margin_deg, disk_margin, s_peak_max)):
        raise InputError("assert_margins: expected at least one bound, got none")
    a = _analysis(plant, controller, loop_delay_samples)
    bad = []
    for lp in _select(a.loops, dofs):
        if gain_margin_db is not None and not _db(lp.gain_margin) >= gain_margin_db:
            bad.append(
                f"loop {lp.name}: gain margin {_db(lp.gain_margin):.2f} dB < bound "
                f"{gain_margin_db:g} dB"
            )
        if phase_margin_deg is not None and not lp.phase_margin_deg >= phase_margin_deg:
            bad.append(
                f"loop {lp.name}: phase margin {lp.phase_margin_deg:.2f} deg < bound "
                f"{phase_margin_deg:g} deg"
            )
        if disk_margin is not None and not lp.disk_margin >= disk_margin:
            bad.append(f"loop {lp.name}: disk margin {lp.disk_margin:.4f} < bound {disk_margin:g}")
        if s_peak_max is not None and not lp.s_peak <= s_peak_max:
            bad.append(
                f"loop {lp.name}: |S|inf {lp.s_peak:.4f} ({_db(lp.s_peak):.2f} dB) > bound "
                f"{s_peak_max:g} at {lp.s_peak_hz:.1f} Hz"
            )
    _fail("margins not met", bad)


def assert_bandwidth(
    plant,
    controller,
    *,
    crossover_hz: float | None = None,
    bandwidth_hz: float | None = None,
    dofs: Sequence[str | int] | None = None,
    loop_delay_samples: int = 0,
) -> None:
    """Every loop (or those of ``dofs``) reaches the crossover / -3 dB bandwidth given (Hz).

    ``crossover_hz``: lower bound on the |L_i| = 1 crossover; ``bandwidth_hz``:
    lower bound on the frequency where |S_i| rises through -3 dB. A loop
    without such a crossing (nan) fails.
    """
    if crossover_hz is None and bandwidth_hz is None:
        raise InputError("assert_bandwidth: expected crossover_hz or bandwidth_hz, got neither")
    a = _analysis(plant, controller, loop_delay_samples)
    bad = []
    for lp in _select(a.loops, dofs):
        if crossover_hz is not None and not lp.crossover_hz >= crossover_hz:
            bad.append(
                f"loop {lp.name}: crossover {lp.crossover_hz:.2f} Hz < bound {crossover_hz:g} Hz"
            )
        if bandwidth_hz is not None and not lp.bandwidth_hz >= bandwidth_hz:
            bad.append(
                f"loop {lp.name}: -3 dB bandwidth {lp.bandwidth_hz:.2f} Hz < bound "
                f"{bandwidth_hz:g} Hz"
            )
    _fail("bandwidth not reached", bad)


def assert_tracking(
    plant,
    controller,
    profile,
    *,
    dof: str | int,
    ma_max: float | None = None,
    msd_max: float | None = None,
    rms_max: float | None = None,
    window_s: float,
    feedforward: np.ndarray | None = None,
    dofs: Sequence[str | int] | None = None,
    loop_delay_samples: int = 0,
    rng: np.random.Generator | None = None,
) -> None:
    """The scan ``profile`` on ``dof``, simulated in closed loop, tracks within the bounds.

    Parameters
    ----------
    profile : workbench.scan.ScanProfile
        The setpoint (position, m or rad) applied to output ``dof``; sampled at
        the controller's fs.
    dof : str or int
        Output that follows the profile (name or index).
    ma_max, msd_max, rms_max : float
        Upper bounds on max |MA|, max MSD and the rms of the error over the
        constant-velocity part (units of the output), checked on every loop of
        ``dofs`` (default all).
    window_s : float
        Exposure window, s.
    feedforward : (N, n_u) array, optional
        Added at the plant input (e.g. mass x acceleration), N.
    rng : numpy.random.Generator
        The plant's noise (required for a plant object; default a fixed seed 0,
        so that a regression test is repeatable).
    """
    from workbench.scan import tracking_figures
    from workbench.sim import closed_loop

    if all(b is None for b in (ma_max, msd_max, rms_max)):
        raise InputError("assert_tracking: expected at least one of ma_max, msd_max, rms_max")
    fplant, tplant = _plant(plant)
    if tplant is None:
        raise InputError("plant: a measured FRF has no time response; give a plant or a model")
    K = _controller(controller)
    names = [str(n) for n in getattr(fplant, "output_names", ()) or ()]
    if len(names) != K.n_y:
        names = [f"y{i}" for i in range(K.n_y)]
    k = _index(dof, names, "dof")
    if abs(profile.fs - K.fs) > 1e-9 * K.fs:
        raise InputError(
            f"profile: expected fs = {K.fs:g} Hz like the controller, got {profile.fs:g}"
        )
    r = profile.reference(K.n_y, k)
    rng = np.random.default_rng(0) if rng is None else rng
    _u, y = closed_loop(tplant, K, r=r, d=feedforward, rng=rng, delay_samples=loop_delay_samples)
    fig = tracking_figures(r - y, K.fs, window_s=window_s, during=profile.constant_velocity_s)
    idx = range(K.n_y) if dofs is None else [_index(d, names, "dofs") for d in dofs]
    bad = []
    for i in idx:
        for label, value, bound in (
            ("max |MA|", fig.ma_max[i], ma_max),
            ("max MSD", fig.msd_max[i], msd_max),
            ("rms error", fig.rms[i], rms_max),
        ):
            if bound is not None and not value <= bound:
                bad.append(f"loop {names[i]}: {label} {value:.4g} > bound {bound:.4g}")
    _fail(f"tracking of the scan on {names[k]} not met (window {fig.window_s:g} s)", bad)

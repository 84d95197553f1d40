"""Scenario stages of controller design: ``[design]`` on the model, ``[evaluate]`` on the truth.

Data flow::

    [modes] modal model (identified + refined, with the identified delay)
        ─► minimality check ─► [design] one controller per method, tuned for the
           highest crossover at |S_ii| <= ms_max on the MODEL (controller_<method>.npz)
        ─► [evaluate] each controller on the TRUE plant of [plant] (its delay,
           residual modes, extra effects in the loop figures; noise and
           quantization in the time simulation):
             workbench.loop.analyze_loop  per DOF crossover, -3 dB bandwidth, |S|inf,
                                          GM / PM / disk margins, stability
             workbench.sim.closed_loop    a 4th-order scan (workbench.scan) on one DOF,
                                          max |MA|, max MSD, rms of the error
           ─► evaluation.json, evaluation.txt (the table), plots, and the
              bandwidth gain of each design over the baseline, per DOF.

The loop delay: a design assumes the model's own ``delay_s`` plus
``[design] loop_delay_samples`` (give it when the model was identified from
the plant input u, which comes after the real-time system's delay); the true
plant's ``delay_s`` already holds that delay, so ``[evaluate]
loop_delay_samples`` defaults to 0 (the same rule as ``workbench loop``).

Fixed controllers on a varied plant (``workbench sweep``)::

    [design]
    controllers = { pid-notch = "../results/wafer_stage_bandwidth/controller_pid-notch.npz" }
    [evaluate]
    scan = false     # loop figures only: no scan simulation (it needs [modes] for its
                     # feedforward; or keep [evaluate.scan] with feedforward = false)
    plots = false    # no per-run PNGs (loop_<design>/, evaluate_*.png)

reads each design from its spec-5 controller file (paths relative to the
scenario file; the loop delay the design assumed is the file's
``delay_samples``), so ``[plant]`` + ``[design]`` + ``[evaluate]`` runs
without ``[identify]`` / ``[modes]``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from workbench.cli.pipeline import RunState
from workbench.core.errors import InputError
from workbench.io.scenario import refuse_leftovers, take

#: design methods the [design] stage offers (one module of controllers/ each)
METHODS = ("pid-notch", "modal-sf", "hinf", "youla")
#: the methods of a [design] table without ``methods`` (youla takes minutes on the stage)
DEFAULT_METHODS = ("pid-notch", "modal-sf", "hinf")

__all__ = ["Design", "METHODS", "stage_design", "stage_evaluate"]


@dataclass(frozen=True)
class Design:
    """One controller designed by ``[design]`` (the controller e -> u and what it assumed)."""

    method: str
    controller: Any  # a controllers.Controller (StateSpaceController)
    loop_delay_samples: int
    settings: dict = field(default_factory=dict)


def _tune(method: str, model, fs: float, ms_max: float, m: int, measured=None):
    """(controller, settings) of ``method`` on ``model``; InputError when it cannot.

    ``measured`` (the [frf] stage's FRF, or None) is used by youla only: its programs
    then hold |S| on the measured loop (robust to what the model lacks and the FRF shows).
    """
    if method == "pid-notch":
        from controllers.pid_notch import tune_pid_notch

        K, report = tune_pid_notch(model, fs, ms_max=ms_max, loop_delay_samples=m)
        return K.controller, {"crossover_hz": report.crossover_hz, "notch_hz": report.notch_hz}
    if method == "modal-sf":
        from controllers.modal_sf import tune_modal_sf

        d = tune_modal_sf(model, ms_max=ms_max, loop_delay_samples=m, fs=fs)
        rep = d.report
        settings = {} if rep is None else {"kept": rep.settings, "tried": rep.tried}
        return d.controller, settings
    if method == "hinf":
        from controllers.hinf import tune_hinf

        d = tune_hinf(model, ms_max=ms_max, loop_delay_samples=m, fs=fs)
        return d.controller, {
            "target_hz": d.target_hz,
            "crossover_hz": d.crossover_hz,
            "gamma": d.gamma,
        }
    if method == "youla":
        from controllers.youla import tune_youla

        d = tune_youla(model, ms_max=ms_max, loop_delay_samples=m, fs=fs, measured=measured)
        return d.controller, {
            "measured": "none" if measured is None else f"frf ({len(measured.freq)} lines)",
            "template_hz": d.report.template_hz,
            "crossover_hz": d.report.crossover_hz,
            "n_basis": d.report.n_basis,
            "programs": d.report.solves,
            "orders": d.report.orders,
        }
    raise InputError(
        f"[design] key 'methods': expected some of {', '.join(METHODS)}, got {method!r}"
    )


def stage_design(st: RunState, table: dict) -> None:
    """Design every method of ``[design] methods`` on the identified modal model.

    With ``[design] controllers = { name = "controller.npz", ... }`` the designs are
    read from spec-5 controller files instead (:func:`_load_designs`): no model, no
    tuning, so ``[plant]`` + ``[design]`` + ``[evaluate]`` judges fixed controllers on a
    (varied) true plant.
    """
    from workbench.io import formats
    from workbench.loop import analyze_loop
    from workbench.modal.minimality import check_minimality

    files = take(table, "controllers", None, where="design", kind=dict)
    if files is not None:
        _load_designs(st, files, table)
        return
    methods = take(table, "methods", list(DEFAULT_METHODS), where="design", kind=list)
    ms_max = float(take(table, "ms_max", 2.0, where="design", kind=(int, float)))
    m = take(table, "loop_delay_samples", 0, where="design", kind=int)
    refuse_leftovers(table, where="design")
    bad = [x for x in methods if x not in METHODS]
    if bad or not methods:
        raise InputError(
            f"[design] key 'methods': expected some of {', '.join(METHODS)}, got {methods!r}"
        )
    if not np.isfinite(ms_max) or ms_max <= 1.0:
        raise InputError(f"[design] key 'ms_max': expected a bound > 1 on |S|, got {ms_max}")
    if m < 0:
        raise InputError(f"[design] key 'loop_delay_samples': expected an integer >= 0, got {m}")
    if st.modal is None or st.modal_model is None:
        raise InputError("[design] needs a modal model: [identify] and [modes] tables")
    model = st.modal_model
    fs = float(st.plant.fs if st.plant is not None else st.data.fs)
    # minimality first: a mode the actuators / sensors cannot reach is refused by the modal
    # design (one line naming mode, lemma and margin), recorded here, not raised
    report = check_minimality(st.modal)
    out: dict[str, Any] = {
        "model": "modal model of [modes] (identified + refined), identified delay",
        "model_delay_s": model.delay_s,
        "fs_hz": fs,
        "ms_max": ms_max,
        "loop_delay_samples": m,
        "minimal": report.minimal,
        "minimality_failures": [str(f) for f in report.failures],
        "designs": {},
    }
    for method in methods:
        try:
            controller, settings = _tune(method, model, fs, ms_max, m, st.frf)
        except InputError as exc:
            out["designs"][method] = {"status": "refused", "reason": str(exc)}
            continue
        analysis = analyze_loop(model, controller, loop_delay_samples=m)
        formats.save_controller(st.path(f"controller_{method}.npz"), controller, delay_samples=m)
        st.designs[method] = Design(method, controller, m, settings)
        out["designs"][method] = {
            "status": "designed",
            "n_x": int(np.asarray(controller.statespace().A).shape[0]),
            "settings": settings,
            "on_model": analysis.summary(),
        }
    st.write_json("design.json", out)
    st.summary["design"] = {
        "minimal": report.minimal,
        "designs": {
            k: (
                v["status"]
                if v["status"] != "designed"
                else {"crossover_hz": [lp["crossover_hz"] for lp in v["on_model"]["loops"]]}
            )
            for k, v in out["designs"].items()
        },
    }


def _load_designs(st: RunState, files: dict, table: dict) -> None:
    """``[design] controllers``: each design read from its spec-5 controller file.

    Paths resolve against the scenario's folder (:meth:`Scenario.resolve`). The loop
    delay a design assumed is the file's ``delay_samples``. The tuning keys
    (``methods``, ``ms_max``, ``loop_delay_samples``) have no meaning here and are
    refused. A missing file is one line naming the run that writes it.
    """
    from controllers.protocol import StateSpaceController

    for key in ("methods", "ms_max", "loop_delay_samples"):
        if key in table:
            raise InputError(
                f"[design] key '{key}': not with 'controllers' (designs read from files are "
                "not tuned); give one of the two"
            )
    refuse_leftovers(table, where="design")
    if not files:
        raise InputError(
            "[design] key 'controllers': expected { name = \"controller.npz\", ... }, got {}"
        )
    out: dict[str, Any] = {"source": "controller files ([design] controllers)", "designs": {}}
    for name, given in files.items():
        if not isinstance(given, str):
            raise InputError(
                f"[design] key 'controllers.{name}': expected a controller file path, got {given!r}"
            )
        path = st.scenario.resolve(given)
        if not path.is_file():
            raise InputError(
                f"[design] key 'controllers.{name}': no such file {path}; {_writer_of(st, path)}"
            )
        controller = StateSpaceController.read(path)
        if st.plant is not None and (controller.n_y, controller.n_u) != (
            st.plant.n_y,
            st.plant.n_u,
        ):
            raise InputError(
                f"[design] key 'controllers.{name}': {path} has {controller.n_y} inputs "
                f"(errors) and {controller.n_u} outputs, expected {st.plant.n_y} and "
                f"{st.plant.n_u} for the plant of [plant]"
            )
        m = int(controller.delay_samples)
        st.designs[name] = Design(name, controller, m, {"file": str(path)})
        out["designs"][name] = {
            "status": "read",
            "file": str(path),
            "n_x": int(controller.n_x),
            "loop_delay_samples": m,
        }
    st.write_json("design.json", out)
    st.summary["design"] = {"designs": {k: v["file"] for k, v in out["designs"].items()}}


def _writer_of(st: RunState, path) -> str:
    """Which run writes the controller file ``path``, as a sentence for an error message.

    A scenario in the same folder as this one (or in ``studies/`` under it) whose
    results folder is the file's folder and that has a ``[design]`` table: that
    scenario's ``workbench run`` writes ``controller_<method>.npz`` there.
    """
    import tomllib
    from pathlib import Path

    generic = (
        "a controller_<method>.npz is written by `workbench run` of a scenario with a "
        "[design] table (into its results folder) or by `workbench design`"
    )
    here = st.scenario.path
    if here is None:
        return generic
    folder = Path(path).parent.resolve()
    for candidate in sorted([*here.parent.glob("*.toml"), *here.parent.glob("studies/*.toml")]):
        if candidate.resolve() == here:
            continue
        try:
            raw = tomllib.loads(candidate.read_text())
        except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
            continue
        head = raw.get("scenario", {})
        results = head.get("results", f"results/{head.get('name', candidate.stem)}")
        if "design" in raw and Path(results).resolve() == folder:
            shown = os.path.relpath(candidate)
            method = Path(path).stem.removeprefix("controller_")
            methods = raw["design"].get("methods", list(METHODS))
            if method in methods:
                return f"`workbench run {shown}` writes it (into {results}/)"
            return (
                f"`workbench run {shown}` writes its controllers into {results}/, but its "
                f"[design] methods {methods} do not include {method!r}"
            )
    return generic


# ------------------------------------------------------------------ evaluation
_SCAN_KEYS = {
    # key: (default, meaning); SI units. Defaults: a y scan at 0.1 m/s over 5 mm, short-stroke
    # limits, a 5 ms exposure window (slit / scan speed)
    "dof": ("y", "scanning DOF (output name)"),
    "velocity": (0.1, "scan velocity, m/s"),
    "length": (0.005, "constant-velocity length, m"),
    "acceleration": (10.0, "m/s^2"),
    "jerk": (2000.0, "m/s^3"),
    "snap": (1e6, "m/s^4"),
    "window_s": (0.005, "exposure window, s"),
    "lead_s": (0.002, "rest before the move, s"),
    "settle_s": (0.05, "rest after the move, s"),
    "feedforward": (True, "rigid-body acceleration feedforward from the design model"),
}


def _scan_settings(table: dict) -> dict | None:
    """The ``[evaluate.scan]`` settings; None for ``[evaluate] scan = false`` (no scan)."""
    raw = take(table, "scan", {}, where="evaluate", kind=(dict, bool))
    if raw is False:
        return None
    raw = {} if raw is True else dict(raw)
    out = {}
    for key, (default, _meaning) in _SCAN_KEYS.items():
        kind = type(default) if not isinstance(default, float) else (int, float)
        out[key] = take(raw, key, default, where="evaluate.scan", kind=kind)
    refuse_leftovers(raw, where="evaluate.scan")
    return out


def _feedforward(st: RunState, profile, dof: int, n_u: int, enabled: bool) -> np.ndarray | None:
    """u_ff (N, n_u) = pinv(N0) a_ref, N0 the identified rigid-body residue, advanced by the delay.

    The rigid body of the modal model is N0 / s^2 (m/N), so the force that gives
    the reference acceleration is pinv(N0) a (a: the mean over each hold interval); the
    model's delay (whole samples)
    is compensated by applying it that much earlier. The same feedforward for
    every design: the comparison stays one of the feedback loops.
    """
    if not enabled:
        return None
    if st.modal is None:
        raise InputError(
            "[evaluate.scan] key 'feedforward': needs the identified modal model ([identify] "
            "and [modes]); with [design] controllers from files set feedforward = false, or "
            "[evaluate] scan = false"
        )
    N0, _ = st.modal.rigid_residue()
    if not np.any(N0):
        raise InputError("[evaluate.scan] feedforward: the modal model has no rigid-body modes")
    acc = np.zeros((profile.t.size, N0.shape[0]))
    # the mean acceleration over each hold interval, (v[k+1] - v[k]) fs: behind the ZOH
    # it gives the rigid body the setpoint's velocity at every sample (a[k] itself would
    # lag half a sample and leave an error proportional to the jerk)
    acc[:-1, dof] = np.diff(profile.velocity) * profile.fs
    u = acc @ np.linalg.pinv(N0).T
    shift = int(round(st.modal_model.delay_s * profile.fs))
    if shift:
        u = np.vstack([u[shift:], np.zeros((shift, n_u))])
    return u


def stage_evaluate(st: RunState, table: dict) -> None:
    """Every design of ``[design]`` on the true plant: loop figures, scan tracking, gains."""
    from workbench.core.model import LTIModel
    from workbench.loop import analyze_loop, save_loop_plots
    from workbench.scan import ScanLimits, scan, tracking_figures
    from workbench.sim import closed_loop

    baseline = take(table, "baseline", "pid-notch", where="evaluate", kind=str)
    m = take(table, "loop_delay_samples", 0, where="evaluate", kind=int)
    sc = _scan_settings(table)
    # plots = false: figures only (a sweep's runs need no per-run PNGs, ~1 s per design)
    plots = take(table, "plots", True, where="evaluate", kind=bool)
    refuse_leftovers(table, where="evaluate")
    if st.plant is None:
        raise InputError("[evaluate] needs the true plant: a [plant] table")
    if not st.designs:
        raise InputError("[evaluate] needs designed controllers: a [design] table")
    if m < 0:
        raise InputError(f"[evaluate] key 'loop_delay_samples': expected an integer >= 0, got {m}")
    plant = st.plant
    names = list(plant.output_names)
    if sc is not None and sc["dof"] not in names:
        raise InputError(
            f"[evaluate.scan] key 'dof': expected one of {', '.join(names)}, got {sc['dof']!r}"
        )
    # the true machine's linear part with its own delay (residual / extra modes included)
    truth = LTIModel.from_statespace(plant.linear_model(), delay_s=float(plant.delay_s))
    if sc is not None:
        dof = names.index(sc["dof"])
        limits = ScanLimits(sc["velocity"], sc["acceleration"], sc["jerk"], sc["snap"])
        profile = scan(
            sc["velocity"], sc["length"], limits, plant.fs,
            lead_s=sc["lead_s"], settle_s=sc["settle_s"],
        )  # fmt: skip
        r = profile.reference(plant.n_y, dof)
        d = _feedforward(st, profile, dof, plant.n_u, sc["feedforward"])
    # one noise realization for every design: the comparison is of the controllers
    noise_seed = int(st.rng.integers(2**63 - 1))
    results: dict[str, Any] = {}
    errors: dict[str, np.ndarray] = {}
    analyses = {}
    for method, design in st.designs.items():
        analysis = analyze_loop(truth, design.controller, loop_delay_samples=m)
        analyses[method] = analysis
        entry: dict[str, Any] = {"analysis": analysis.summary(), "tracking": None}
        if plots:
            for p in save_loop_plots(analysis, st.out / f"loop_{method}"):
                st.files.append(os.path.relpath(p, st.out))
        if sc is None:
            entry["note"] = "[evaluate] scan = false: no time simulation"
        elif analysis.stable:
            u, y = closed_loop(
                plant, design.controller, r=r, d=d,
                rng=np.random.default_rng(noise_seed), delay_samples=m,
            )  # fmt: skip
            e = r - y
            errors[method] = e
            fig = tracking_figures(
                e, plant.fs, window_s=sc["window_s"], during=profile.constant_velocity_s
            )
            entry["tracking"] = fig.as_dict(names)
            entry["u_peak"] = {n: float(v) for n, v in zip(plant.input_names, np.abs(u).max(0))}
        else:
            entry["note"] = "unstable on the true plant: no time simulation"
        results[method] = entry
    gains = _bandwidth_gains(analyses, baseline, names)
    payload = {
        "plant": plant.name if hasattr(plant, "name") else str(plant),
        "loop_delay_samples": m,
        "baseline": baseline,
        "scan": None
        if sc is None
        else {
            **sc,
            "durations_s": profile.durations_s,
            "constant_velocity_s": profile.constant_velocity_s,
            "distance_m": profile.distance,
        },
        "designs": results,
        "bandwidth_gain": gains,
    }
    text = _table(analyses, results, gains, baseline, "-" if sc is None else sc["dof"])
    st.write_json("evaluation.json", payload)
    from workbench.core import atomic

    atomic.write_text(st.path("evaluation.txt"), text + "\n")
    if plots:
        _plot_sensitivity(st.path("evaluate_sensitivity.png"), analyses, names)
    if errors and plots:
        _plot_scan_error(
            st.path("evaluate_scan_error.png"), profile, errors, dof, sc["dof"], sc["window_s"]
        )
    st.summary["evaluate"] = {
        "text": text,
        "baseline": baseline,
        "bandwidth_gain": gains,
        "stable": {k: a.stable for k, a in analyses.items()},
    }


def _bandwidth_gains(analyses: dict, baseline: str, names: list[str]) -> dict:
    """Per design and DOF: crossover and -3 dB bandwidth over the baseline's (ratios)."""
    if baseline not in analyses:
        return {}
    base = analyses[baseline].loops
    out = {}
    for method, a in analyses.items():
        if method == baseline:
            continue
        out[method] = {
            "crossover": {
                n: float(lp.crossover_hz / b.crossover_hz)
                for n, lp, b in zip(names, a.loops, base, strict=True)
            },
            "bandwidth": {
                n: float(lp.bandwidth_hz / b.bandwidth_hz)
                for n, lp, b in zip(names, a.loops, base, strict=True)
            },
        }
    return out


def _table(analyses, results, gains, baseline: str, scan_dof: str) -> str:
    """The one printed table: a block per design (loop figures per DOF + scan tracking)."""
    rows = []
    for method, a in analyses.items():
        rows.append(f"== {method} on the true plant (stable = {a.stable})")
        rows.append(a.table().splitlines()[0] + f" {'MA n':>8} {'MSD n':>8}")
        tr = results[method]["tracking"]
        for line, lp in zip(a.table().splitlines()[1:], a.loops):
            extra = ""
            if tr is not None:
                extra = f" {tr['ma_max'][lp.name] * 1e9:8.3f} {tr['msd_max'][lp.name] * 1e9:8.3f}"
            rows.append(line + extra)
        rows.append(a.table().splitlines()[-1])
    rows.append(
        "MA n, MSD n: max |moving average| and max moving std of the scan error over the "
        "exposure windows in the constant-velocity part, nm (nrad for rotations)"
    )
    if gains:
        rows.append(
            f"bandwidth gain over {baseline} (crossover ratio per DOF; scan in {scan_dof}):"
        )
        for method, g in gains.items():
            rows.append(
                f"  {method:>10}: "
                + " ".join(f"{n} {v:.2f}" for n, v in g["crossover"].items())
                + f"  (min {min(g['crossover'].values()):.2f})"
            )
    return "\n".join(rows)


# ------------------------------------------------------------------ plots
def _plot_sensitivity(path, analyses: dict, names: list[str]) -> None:
    """|S_ii| (solid) and |T_ii| (dashed) per DOF, one colour per design, 6 dB line."""
    from workbench.plotting import lean_axes, new_figure, save_png

    n = len(names)
    cols = min(n, 3)
    rows = int(np.ceil(n / cols))
    fig = new_figure(3.2 * cols + 1, 2.4 * rows + 1)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False, sharex=True)).ravel()
    for i, name in enumerate(names):
        ax = axes[i]
        for k, (method, a) in enumerate(analyses.items()):
            color = f"C{k}"
            ax.semilogx(a.freq_hz, 20 * np.log10(np.abs(a.S[:, i, i])), color=color, label=method)
            ax.semilogx(
                a.freq_hz, 20 * np.log10(np.abs(a.T[:, i, i]) + 1e-300), color=color, ls="--"
            )
        ax.axhline(6.0, color="r", lw=0.5)
        ax.set_ylim(-60, 20)
        ax.set_title(f"{name}: |S| (solid), |T| (dashed), dB", fontsize=7)
        ax.tick_params(labelsize=6)
        lean_axes(ax)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=6)
    fig.suptitle("designs on the true plant", fontsize=9)
    save_png(fig, path)


def _plot_scan_error(path, profile, errors: dict, dof: int, dof_name: str, window_s) -> None:
    """Setpoint, error and its moving average / std (exposure window) on the scanning DOF."""
    from workbench.plotting import lean_axes, new_figure, save_png
    from workbench.scan import moving_average_std

    fig = new_figure(8, 7)
    ax_r, ax_e, ax_m = (fig.add_subplot(3, 1, k) for k in (1, 2, 3))
    t = profile.t
    ax_r.plot(t, profile.position * 1e3, "k")
    ax_r.set_ylabel(f"r {dof_name} (mm)")
    n_w = max(int(round(window_s * profile.fs)), 1)
    for k, (method, e) in enumerate(errors.items()):
        ax_e.plot(t, e[:, dof] * 1e9, color=f"C{k}", lw=0.7, label=method)
        ma, msd = moving_average_std(e[:, [dof]], n_w)
        tw = t[n_w - 1 :]
        ax_m.plot(tw, ma[:, 0] * 1e9, color=f"C{k}", lw=0.8)
        ax_m.plot(tw, msd[:, 0] * 1e9, color=f"C{k}", lw=0.8, ls="--")
    for ax in (ax_r, ax_e, ax_m):
        for edge in profile.constant_velocity_s:
            ax.axvline(edge, color="0.6", lw=0.5)
        lean_axes(ax)
    ax_e.set_ylabel("error (nm)")
    ax_e.legend(fontsize=7)
    ax_m.set_ylabel("MA (solid), MSD (dashed), nm")
    ax_m.set_xlabel("time (s); grey: constant-velocity part")
    save_png(fig, path)

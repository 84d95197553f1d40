"""``workbench run``: a scenario file, executed stage by stage.

Data flow::

    [plant] ─► [experiment] ─► time record (measurement.npz)
                                  │
                 [frf] ◄──────────┤──────────► [identify] ─► model (discrete)
                   │                                 │
                   ▼                                 ▼
            FRF (frf.npz, plots)          [modes] modal model ─► [minimality]
                   │                                 │
                   └────────► identified-vs-measured FRF plot ◄┘

    [model] (a user's model file, or the nominal plant model) ─► [compare] ─►
    [diagnose] ─► [augment] ─► compare again

    FRF ─► [modalfit] modal model ─► [update] FE file (spec 4) ─► updated FE ─►
    [predict] held-out sensors (workbench.cli.beam_stages)

    modal model ─► [design] controllers (pid-notch, modal-sf, ...) ─► [evaluate] on the
    TRUE plant: loop figures per DOF, scan tracking (MA / MSD), bandwidth gain

Every stage writes JSON figures and PNG plots into the results folder,
atomically, and returns what later stages consume. The run draws all its
randomness from one generator seeded by ``[scenario] seed``.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from workbench.core import atomic, lti
from workbench.core.errors import InputError
from workbench.core.jsonutil import jsonable
from workbench.io.scenario import Scenario, refuse_leftovers, take


@dataclass
class RunState:
    """What the stages of one run hand to each other (and the summary they build)."""

    scenario: Scenario
    out: Path
    rng: np.random.Generator
    plant: Any = None
    data: Any = None  # TimeData
    frf: Any = None  # FrfData
    ident: Any = None  # SubspaceResult
    modal: Any = None  # ModalModel
    modal_model: Any = None  # the modal model as an LTIModel with the identified delay
    model: Any = None  # the user's model (LTIModel, with its delay) for compare/diagnose
    diagnosis: Any = None  # workbench.diagnosis.Diagnosis
    designs: dict[str, Any] = field(default_factory=dict)  # [design]: name -> Design
    plant_config: Any = None  # the plant's configuration as the scenario set it (or None)
    modal_fit: Any = None  # [modalfit]: workbench.modal.fit.ModalFit
    fit_data: Any = None  # the FRF the modal fit used (the sensors kept for fitting)
    extended: Any = None  # [modalfit] collocated: workbench.modal.scaling.ExtendedModes
    fe: Any = None  # [update]: the FE model given (workbench.fe.FEModel)
    fe_updated: Any = None  # [update]: the updated FE model
    summary: dict[str, Any] = field(default_factory=dict)
    files: list[str] = field(default_factory=list)

    def write_json(self, name: str, payload: dict) -> Path:
        path = self.out / name
        atomic.write_text(path, json.dumps(jsonable(payload), indent=2) + "\n")
        self.files.append(name)
        return path

    def path(self, name: str) -> Path:
        self.files.append(name)
        return self.out / name


# --------------------------------------------------------------------- stages
def stage_plant(st: RunState, table: dict) -> None:
    import plants

    name = take(table, "name", None, where="plant", kind=str)
    if name is None:
        raise InputError(f"[plant]: missing key 'name' (one of {', '.join(plants.PLANTS)})")
    effects = take(table, "effects", {}, where="plant", kind=dict)
    config = take(table, "config", None, where="plant", kind=dict)
    refuse_leftovers(table, where="plant")
    if config is not None:
        # machine parameters (BeamConfig / StageConfig fields); TOML arrays become tuples
        fields = {k: tuple(v) if isinstance(v, list) else v for k, v in config.items()}
        st.plant_config = plants.plant_config(name, **fields)
        st.plant = plants.get_plant(name, config=st.plant_config, **effects)
    else:
        st.plant = plants.get_plant(name, **effects)
    st.summary["plant"] = {
        "name": name,
        "fs_hz": st.plant.fs,
        "n_u": st.plant.n_u,
        "n_y": st.plant.n_y,
    }


def stage_experiment(st: RunState, table: dict) -> None:
    from workbench.experiments import ExperimentConfig, run_experiment
    from workbench.io import formats

    if st.plant is None:
        raise InputError("[experiment] needs a [plant] table")
    config = ExperimentConfig.from_table(table)
    st.data = run_experiment(st.plant, config, rng=st.rng)
    formats.save_measurement(st.path("measurement.npz"), st.data)
    d = st.data
    st.summary["experiment"] = {
        "kind": config.kind,
        "loop": d.loop,
        "n_samples": d.n_samples,
        "fs_hz": d.fs,
        "period": d.period,
        "u_rms": np.sqrt(np.mean(d.u**2, axis=0)),
        "y_rms": np.sqrt(np.mean(d.y**2, axis=0)),
    }


def stage_frf(st: RunState, table: dict) -> None:
    from workbench.io import formats
    from workbench.signals.frf import estimate_frf

    if st.data is None:
        raise InputError("[frf] needs recorded data: an [experiment] table")
    method = take(table, "method", "auto", where="frf", kind=str)
    mark_hz = take(table, "mark_hz", [], where="frf", kind=list)
    # periods dropped at the start of every block: a lightly damped low mode (the beam's
    # 3 Hz suspension, time constant 3 s) leaks its transient into many periods
    n_transient = take(table, "n_transient", 1, where="frf", kind=int)
    refuse_leftovers(table, where="frf")
    est = estimate_frf(st.data, method=method, n_transient=n_transient)
    st.frf = est.frf
    formats.save_measurement(st.path("frf.npz"), st.frf)
    _plot_frf_grid(st.path("frf_measured.png"), st.frf, mark_hz=mark_hz, title="measured FRF")
    st.summary["frf"] = {
        "method": est.method,
        "reference": est.reference,
        "n_transient": n_transient,
        "n_lines": st.frf.n_f,
        "band_hz": [st.frf.freq[0], st.frf.freq[-1]],
        "mark_hz": mark_hz,
        "median_relative_std": float(
            np.median(np.sqrt(st.frf.G_var) / np.maximum(np.abs(st.frf.G), 1e-300))
        )
        if st.frf.G_var is not None
        else None,
    }


def stage_identify(st: RunState, table: dict) -> None:
    from workbench.ident.order import plot_singular_values
    from workbench.ident.subspace import identify_subspace

    if st.data is None:
        raise InputError("[identify] needs recorded data: an [experiment] table")
    method = take(table, "method", "cl-moesp", where="identify", kind=str)
    order = take(table, "order", None, where="identify", kind=int)
    block_rows = take(table, "block_rows", 20, where="identify", kind=int)
    input_delay = take(table, "input_delay", 0, where="identify", kind=int)
    refuse_leftovers(table, where="identify")
    res = identify_subspace(
        st.data, method=method, order=order, block_rows=block_rows, input_delay=input_delay
    )
    st.ident = res
    res.lti_model.write(st.path("model_identified.npz"))  # the delay exact in 'delay_s'
    plot_singular_values(
        res.singular_values,
        st.path("singular_values.png"),
        order=res.order,
        suggested=res.suggested_order,
        title=f"{res.method}: singular values",
    )
    st.summary["identify"] = {
        "method": res.method,
        "order": res.order,
        "suggested_order": res.suggested_order,
        "gap": res.gap,
        "block_rows": res.block_rows,
        "input_delay_samples": res.input_delay,
        "singular_values": res.singular_values[: 3 * max(res.order, 1)],
        "notes": list(res.notes),
    }


def stage_modes(st: RunState, table: dict) -> None:
    from workbench.core.model import LTIModel
    from workbench.modal.model import ModalModel, plot_mode_superposition, plot_model_bode
    from workbench.plotting import save_bode_overlay

    if st.ident is None:
        raise InputError("[modes] needs an identified model: an [identify] table")
    threshold = take(table, "rigid_threshold_hz", 5.0, where="modes", kind=(int, float))
    superpose = take(table, "superposition", [[2, 2]], where="modes", kind=list)
    refine = take(table, "refine", False, where="modes", kind=bool)
    refuse_leftovers(table, where="modes")
    st.modal = ModalModel.from_statespace(st.ident.model, rigid_threshold_hz=float(threshold))
    refined = None
    if refine:  # maximum-likelihood refinement on the periodic record (workbench.ident.refine)
        from workbench.ident.refine import refine_modal_model

        refined = refine_modal_model(st.modal, st.data, input_delay=st.ident.input_delay)
        st.modal = refined.model
    # the modal model is the identified model's rational part: it takes the same delay
    modal_model = LTIModel.from_statespace(st.modal.to_statespace(), delay_s=st.ident.delay_s)
    st.modal_model = modal_model
    modal_model.write(st.path("model_modal.npz"))
    st.write_json("modes.json", json.loads(st.modal.to_json()))
    plot_model_bode(st.modal, st.path("modal_model_bode.png"), title="identified modal model")
    for out_idx, in_idx in superpose:
        plot_mode_superposition(
            st.modal,
            st.path(f"mode_superposition_y{out_idx}_u{in_idx}.png"),
            output=int(out_idx),
            input=int(in_idx),
        )
    flexible = st.modal.modes_of_kind("flexible")
    st.summary["modes"] = {
        "text": st.modal.table_text(),
        "n_rigid": len(st.modal.modes_of_kind("rigid")),
        "flexible": [{"freq_hz": m.freq_hz, "damping": m.damping} for m in flexible],
    }
    if refined is not None:
        st.summary["modes"]["refined"] = {
            "freq_std_hz": refined.freq_std_hz,
            "damping_std": refined.damping_std,
            "misfit": refined.misfit,
            "success": refined.success,
        }
    if st.frf is not None:
        G_model = modal_model.frf(st.frf.freq)
        save_bode_overlay(
            st.path("frf_identified_vs_measured.png"),
            st.frf.freq,
            st.frf.G,
            G_model,
            st.frf.G_var,
            input_names=st.frf.input_names,
            output_names=st.frf.output_names,
        )
        _plot_frf_grid(
            st.path("frf_identified_vs_measured_magnitude.png"),
            st.frf,
            G_model=G_model,
            mark_hz=[m.freq_hz for m in flexible],
            title="measured (black) vs identified (red)",
        )
        st.summary["modes"]["frf_relative_error"] = lti.relative_error_frf(st.frf.G, G_model)


def stage_minimality(st: RunState, table: dict) -> None:
    from workbench.modal.minimality import check_minimality

    if st.modal is None:
        raise InputError("[minimality] needs a modal model: a [modes] table")
    refuse_leftovers(table, where="minimality")
    report = check_minimality(st.modal)
    st.write_json("minimality.json", json.loads(report.to_json()))
    atomic.write_text(st.path("minimality.txt"), report.text() + "\n")
    st.summary["minimality"] = {
        "minimal": report.minimal,
        "controllable": report.controllable,
        "observable": report.observable,
        "failures": [str(f) for f in report.failures],
    }


def stage_model(st: RunState, table: dict) -> None:
    from workbench.core.model import LTIModel
    from workbench.io import formats

    source = take(table, "file", None, where="model", kind=str)
    nominal_of = take(table, "nominal_plant", None, where="model", kind=dict)
    refuse_leftovers(table, where="model")
    if (source is None) == (nominal_of is None):
        raise InputError("[model]: give exactly one of 'file' (a model file) or 'nominal_plant'")
    if source is not None:
        st.model = formats.read_model(st.scenario.resolve(source))  # with its delay_s
    else:
        # The engineer's model: the plant as designed, without the effects the
        # scenario hides in the true system. It is built from the nominal
        # configuration named here, never from the [plant] table's effects.
        import plants

        name = nominal_of.pop("name", None)
        if name is None:
            raise InputError("[model] key 'nominal_plant': missing key 'name'")
        nominal = plants.get_plant(name, **nominal_of)
        st.model = LTIModel.from_statespace(nominal.linear_model(), delay_s=nominal.delay_s)
    formats.save_model(st.path("model_nominal.npz"), st.model)  # delay exact in 'delay_s'


# ---------------------------------------------------------------- plotting
def _plot_frf_grid(path: Path, frf, *, mark_hz=(), title: str = "", G_model=None) -> None:
    """Magnitude of every element on one page, modes marked by vertical lines."""
    from workbench.plotting import (
        draw_noise_level,
        frequency_grid,
        lean_axes,
        new_figure,
        save_png,
    )

    n_y, n_u = frf.n_y, frf.n_u
    fig = new_figure(2.2 * n_u + 1, 1.8 * n_y + 1)
    axes = frequency_grid(fig, n_y, n_u, frf.freq)
    for i in range(n_y):
        for j in range(n_u):
            ax = axes[i, j]
            ax.loglog(frf.freq, np.abs(frf.G[:, i, j]), "k", lw=0.6)
            if G_model is not None:
                ax.loglog(frf.freq, np.abs(G_model[:, i, j]), "r", lw=0.6)
            if frf.G_var is not None:  # the noise level: lines at it are noise, not misfit
                draw_noise_level(ax, frf.freq, frf.G_var[:, i, j])
            for f in mark_hz:
                ax.axvline(f, color="tab:blue", lw=0.6, ls="--")
            ax.set_title(f"{frf.output_names[i]} / {frf.input_names[j]}", fontsize=7)
            ax.tick_params(labelsize=6)
            lean_axes(ax)
    fig.suptitle(
        title
        + (f" (dashed: {', '.join(f'{f:g} Hz' for f in mark_hz)})" if mark_hz else "")
        + ("; dotted grey: noise level sqrt(G_var)" if frf.G_var is not None else ""),
        fontsize=9,
    )
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.05, top=0.92, hspace=0.5, wspace=0.35)
    save_png(fig, path)


def stage_functions() -> dict:
    """Every stage a scenario can name -> the function that runs it.

    Built on each call, explicitly: no registry filled as a side effect of an import. The
    model-versus-measurement stages live in :mod:`workbench.cli.loop_stages`, the design and
    evaluation stages in :mod:`workbench.cli.design_stages`; both import :class:`RunState`
    from here, hence the import inside the function.
    """
    from workbench.cli import beam_stages, design_stages, inferential_stages, loop_stages

    return {
        "plant": stage_plant,
        "experiment": stage_experiment,
        "frf": stage_frf,
        "identify": stage_identify,
        "modes": stage_modes,
        "minimality": stage_minimality,
        "model": stage_model,
        "compare": loop_stages.stage_compare,
        "diagnose": loop_stages.stage_diagnose,
        "augment": loop_stages.stage_augment,
        "modalfit": beam_stages.stage_modalfit,
        "update": beam_stages.stage_update,
        "predict": beam_stages.stage_predict,
        "design": design_stages.stage_design,
        "evaluate": design_stages.stage_evaluate,
        "inferential": inferential_stages.stage_inferential,
    }


def _stage_bar(stages: list[str], progress: bool):
    """A tqdm bar over the stages on stderr: drawn only when asked and stderr is a terminal."""
    from tqdm import tqdm

    return tqdm(
        total=len(stages),
        desc="run",
        unit="stage",
        file=sys.stderr,
        disable=None if progress else True,  # None: off when stderr is not a terminal
        bar_format="{desc}: {n}/{total} stages |{bar}| {elapsed} {postfix}",
    )


def run_scenario(scenario: Scenario, *, progress: bool = True) -> dict[str, Any]:
    """Run every stage the scenario names, in pipeline order; return the summary."""
    from workbench.io.scenario import STAGES

    out = Path(scenario.results)
    out.mkdir(parents=True, exist_ok=True)
    st = RunState(scenario=scenario, out=out, rng=np.random.default_rng(scenario.seed))
    stages = [s for s in STAGES if scenario.has(s)]
    timings = {}
    functions = stage_functions()
    bar = _stage_bar(stages, progress)
    for stage in stages:
        bar.set_postfix_str(stage, refresh=True)
        t0 = time.perf_counter()
        functions[stage](st, scenario.table(stage))
        timings[stage] = time.perf_counter() - t0
        bar.update(1)
    bar.set_postfix_str("done", refresh=True)
    bar.close()
    st.summary["scenario"] = {
        "name": scenario.name,
        "seed": scenario.seed,
        "file": str(scenario.path) if scenario.path else None,
        "description": scenario.description,
        "stage_seconds": timings,
    }
    st.write_json("summary.json", st.summary)
    st.summary["files"] = sorted(set(st.files))
    return st.summary

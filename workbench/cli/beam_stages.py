"""Scenario stages of seed 001's pipeline: modal fit, FE model updating, prediction.

Data flow::

    [frf] measured FRF (every sensor) ──outputs──► FRF of the sensors used
        │                                              │
        │ held-out sensors                      [modalfit] fit_modal (+ Theorem 2 with a
        │                                              │       collocated pair)
        │                                     [update] FE file (spec 4) ─► update_fe ─►
        │                                              │       updated FE file
        └──────────────────► [predict] prior and updated FE at the held-out sensors:
                                error against their measurement vs its noise level

The FE file is the user's model: a path, or ``"plant_prior"`` for the plant's
design-stage FE model (the prior, written to the results folder and read back
from there like any user file). No stage reads the plant's true parameters.
"""

from __future__ import annotations

import numpy as np

from workbench.cli.pipeline import RunState
from workbench.core.errors import InputError
from workbench.io.formats import FrfData
from workbench.io.scenario import refuse_leftovers, take

__all__ = ["stage_modalfit", "stage_update", "stage_predict", "select_outputs"]


def select_outputs(data: FrfData, outputs, *, where: str) -> FrfData:
    """The FRF of the named outputs only (order as given); unknown names refused in one line."""
    missing = [o for o in outputs if o not in data.output_names]
    if missing or not outputs:
        raise InputError(
            f"[{where}] key 'outputs': expected names among {list(data.output_names)}, "
            f"got {list(outputs)}"
        )
    idx = [data.output_names.index(o) for o in outputs]
    return FrfData(
        freq=data.freq,
        G=data.G[:, idx],
        G_var=None if data.G_var is None else data.G_var[:, idx],
        fs=data.fs,
        input_names=data.input_names,
        output_names=tuple(outputs),
    )


def stage_modalfit(st: RunState, table: dict) -> None:
    from workbench.io.formats import save_model
    from workbench.modal.fit import fit_modal, plot_fit_overlay, plot_stabilization
    from workbench.modal.scaling import channel_index, scale_modes

    if st.frf is None:
        raise InputError("[modalfit] needs a measured FRF: an [frf] table")
    outputs = take(table, "outputs", list(st.frf.output_names), where="modalfit", kind=list)
    band = take(table, "band_hz", None, where="modalfit", kind=list)
    n_modes = take(table, "modes", None, where="modalfit", kind=int)
    collocated = take(table, "collocated", None, where="modalfit", kind=str)
    refuse_leftovers(table, where="modalfit")
    data = select_outputs(st.frf, outputs, where="modalfit")
    if band is not None and len(band) != 2:
        raise InputError(f"[modalfit] key 'band_hz': expected [F1, F2] in Hz, got {band!r}")
    pair = None
    if collocated is not None:
        pair = collocated.split(":")
        if len(pair) != 2 or not all(pair):
            raise InputError(
                f"[modalfit] key 'collocated': expected 'SENSOR:ACTUATOR' (e.g. 's1:F1'), "
                f"got {collocated!r}"
            )
        channel_index(data.output_names, pair[0], "[modalfit] collocated sensor")
        channel_index(data.input_names, pair[1], "[modalfit] collocated actuator")
    fit = fit_modal(data, n_modes=n_modes, band_hz=None if band is None else tuple(band))
    st.modal_fit = fit
    st.fit_data = data
    extra = fit.arrays()
    model = fit.model
    summary = fit.summary()
    if pair is not None:
        ext = scale_modes(model, sensor=pair[0], actuator=pair[1])
        st.extended = ext
        model = ext.model
        extra["modal_phi_sensors"] = np.asarray(ext.phi_sensors)
        extra["modal_phi_actuators"] = np.asarray(ext.phi_actuators)
        extra["modal_collocated"] = np.array([ext.sensor, ext.actuator])
        summary["collocated"] = [ext.sensor, ext.actuator]
    save_model(st.path("modal_fit_model.npz"), model.to_statespace(), **extra)
    plot_stabilization(fit, st.path("stabilization.png"))
    plot_fit_overlay(fit, data, st.path("modal_fit_overlay.png"))
    st.write_json("modal_fit.json", summary)
    st.summary["modalfit"] = {
        "outputs": list(outputs),
        "n_modes": fit.n_modes,
        "freq_hz": fit.freq_hz,
        "damping": fit.damping,
        "error": fit.error,
        "sigma2": fit.result.sigma2,
        "status": fit.status,
    }


def _fe_source(st: RunState, source: str):
    """The FE model a scenario names: a spec-4 path, or the plant's prior (written, then read)."""
    from workbench.fe.model import read_fe, save_fe

    if source == "plant_prior":
        if st.plant is None or st.plant.name != "beam":
            raise InputError("[update] fe = 'plant_prior' needs [plant] name = 'beam'")
        from plants.beam import beam_fe_file, beam_prior_config

        # the design-stage model of the machine: what a user brings as an FE file
        path = st.path("fe_prior.npz")
        save_fe(path, beam_fe_file(beam_prior_config(st.plant_config), damping=0.01))
        return read_fe(path)
    return read_fe(source)


def _shape_check(ext, fe, res) -> list[dict]:
    """Theorem 2's scaled shapes at the sensors against the updated FE's mass-normalized ones."""
    from workbench.fe.eigen import solve_modes

    modes = solve_modes(*fe.matrices(res.alpha), min(fe.n_dof, 40))
    out_idx = fe.output_index(ext.model.output_names, "extended model")
    rows = []
    for i, k in res.pairs:
        if i >= ext.phi_sensors.shape[0]:
            continue
        v = np.asarray(ext.phi_sensors[i], float)
        phi = fe.C[out_idx] @ modes.Phi[:, k]
        if not np.all(np.isfinite(v)):
            rows.append({"measured_index": i, "fe_index": k, "relative_error": None})
            continue
        phi = phi * np.sign(phi @ v)
        rows.append(
            {
                "measured_index": i,
                "fe_index": k,
                "freq_hz": float(res.freq_measured_hz[i]),
                "relative_error": float(np.linalg.norm(v - phi) / np.linalg.norm(phi)),
            }
        )
    return rows


def stage_update(st: RunState, table: dict) -> None:
    from workbench.fe.model import fe_arrays, fe_from_arrays
    from workbench.fe.plots import plot_mode_shapes, plot_update
    from workbench.fe.update import MeasuredModes, update_fe
    from workbench.io.formats import read_npz

    if st.modal_fit is None:
        raise InputError("[update] needs measured modes: a [modalfit] table")
    source = take(table, "fe", "plant_prior", where="update", kind=str)
    prior_rel = take(table, "prior_rel", 0.5, where="update", kind=(int, float))
    refuse_leftovers(table, where="update")
    fe = _fe_source(st, source)
    st.fe = fe
    fs = st.fit_data.fs
    res = update_fe(fe, MeasuredModes.from_fit(st.modal_fit), prior_rel=float(prior_rel), fs=fs)
    original = read_npz(st.out / "fe_prior.npz" if source == "plant_prior" else source)
    arrays = fe_arrays(fe, alpha=res.alpha, damping=res.damping, original=original)
    st.fe_updated = fe_from_arrays(arrays, src="updated FE model")
    from workbench.core.atomic import save_npz

    save_npz(st.path("fe_updated.npz"), **arrays)
    plot_update(st.out, res)
    st.files += ["update_mac.png", "update_frequencies.png"]
    report = res.report(fe.parameter_names)
    if st.extended is not None:
        report["extended_shapes"] = _shape_check(st.extended, fe, res)
        plot_mode_shapes(st.path("mode_shapes.png"), fe, res.alpha, st.extended, res.pairs)
    st.write_json("update.json", report)
    st.summary["update"] = {
        "text": res.table_text(fe.parameter_names),
        "parameters": {
            p["name"]: {"before": p["before"], "after": p["after"], "std": p["std"]}
            for p in report["parameters"]
        },
        "paired": len(res.pairs),
        "unpaired_measured_hz": [u["freq_hz"] for u in report["unpaired_measured"]],
        "aliased_measured": [
            {"freq_hz": a["freq_hz"], "fe_freq_hz": a["fe_freq_hz"], "damping": a["damping"]}
            for a in report["aliased_measured"]
        ],
    }
    if "extended_shapes" in report:
        errs = [r["relative_error"] for r in report["extended_shapes"] if r["relative_error"]]
        st.summary["update"]["extended_shape_error_max"] = max(errs) if errs else None


def stage_predict(st: RunState, table: dict) -> None:
    from workbench.fe.plots import plot_prediction
    from workbench.fe.predict import predict_frf, prediction_error
    from workbench.io import formats

    if st.fe_updated is None:
        raise InputError("[predict] needs an updated FE model: an [update] table")
    outputs = take(table, "outputs", None, where="predict", kind=list)
    f_max = take(table, "f_max_hz", None, where="predict", kind=(int, float))
    # the run's own experiment samples the plant behind a ZOH with no anti-aliasing filter:
    # predict what it measures (modes above Nyquist folded back), not the continuous FRF
    sampled = take(table, "sampled", True, where="predict", kind=bool)
    refuse_leftovers(table, where="predict")
    if not outputs:
        raise InputError("[predict] key 'outputs': expected the sensors to predict, e.g. ['s3']")
    st.fe_updated.output_index(outputs, "[predict] outputs")
    if f_max is None and st.fit_data is not None:
        f_max = float(st.fit_data.freq[-1])
    freq, inputs = st.frf.freq, st.frf.input_names
    models = {"prior": st.fe, "updated": st.fe_updated}
    fs = st.frf.fs if sampled else None
    if sampled and fs is None:
        raise InputError("[predict] sampled = true: the FRF has no 'fs' (sampling frequency)")
    predictions = {
        k: predict_frf(m, freq, outputs=outputs, inputs=inputs, fs=fs) for k, m in models.items()
    }
    G_up = predictions["updated"]
    formats.save_measurement(
        st.path("prediction.npz"),
        FrfData(freq, G_up, None, st.frf.fs, inputs, tuple(outputs)),
    )
    errors = {
        k: prediction_error(G, outputs, st.frf, f_max_hz=f_max) for k, G in predictions.items()
    }
    result = {"outputs": list(outputs), "f_max_hz": f_max, "sampled_fs_hz": fs}
    if errors["updated"] is not None:
        result.update({k: e.summary() for k, e in errors.items()})
        if sampled:  # what the continuous prediction would have scored: the aliasing's share
            G_c = predict_frf(st.fe_updated, freq, outputs=outputs, inputs=inputs)
            result["updated_continuous"] = prediction_error(
                G_c, outputs, st.frf, f_max_hz=f_max
            ).summary()
        measured = select_outputs(st.frf, list(errors["updated"].outputs), where="predict")
        keep = measured.freq <= (np.inf if f_max is None else f_max)
        plot_prediction(
            st.path("prediction_held_out.png"),
            measured.freq[keep],
            measured.G[keep],
            None if measured.G_var is None else measured.G_var[keep],
            {
                k: G[keep][:, [list(outputs).index(o) for o in measured.output_names]]
                for k, G in predictions.items()
            },
            input_names=inputs,
            output_names=measured.output_names,
        )
    st.write_json("prediction.json", result)
    st.summary["predict"] = {
        k: v
        for k, v in result.items()
        if k in ("outputs", "f_max_hz", "sampled_fs_hz") or not isinstance(v, dict)
    }
    for k in ("prior", "updated", "updated_continuous"):
        if k in result:
            st.summary["predict"][k] = {
                "error": result[k]["mean"],
                "ratio_to_noise": result[k]["ratio_to_noise"],
            }

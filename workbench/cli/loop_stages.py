"""Scenario stages of the model-versus-measurement loop: compare, diagnose, augment.

``[compare]`` -> where the model fails; ``[diagnose]`` -> which effect is
missing; ``[augment]`` -> add it, fit it, and compare again, so the results
folder holds the error map and Bode overlays before and after side by side.
"""

from __future__ import annotations

from workbench.cli.pipeline import RunState
from workbench.core.errors import InputError
from workbench.io import formats
from workbench.io.scenario import refuse_leftovers, take


def _loop_data(st: RunState, table: dict, where: str):
    kind = take(table, "data", "frf" if st.frf is not None else "time", where=where, kind=str)
    if kind not in ("frf", "time"):
        raise InputError(f"[{where}] key 'data': expected 'frf' or 'time', got {kind!r}")
    data = st.frf if kind == "frf" else st.data
    if data is None:
        raise InputError(f"[{where}] needs {kind} data: an [experiment] (and [frf]) table")
    if st.model is None:
        raise InputError(f"[{where}] needs a model: a [model] table")
    return data


def _compare_into(st: RunState, model, data, name: str) -> dict:
    """Compare ``model`` (an LTIModel: its delay is part of it) with ``data``; JSON and plots."""
    from workbench.validate.compare import compare
    from workbench.validate.plots import write_plots

    res = compare(model, data)
    st.write_json(f"{name}.json", res.as_dict())
    for p in write_plots(res, st.out / name, []):
        st.files.append(str(p.relative_to(st.out)))
    return {
        "error": res.error,
        "within_noise": res.within_noise,
        "failing_bands": len(res.failing_bands),
    }


def stage_compare(st: RunState, table: dict) -> None:
    data = _loop_data(st, table, "compare")
    refuse_leftovers(table, where="compare")
    st.summary["compare"] = _compare_into(st, st.model, data, "compare_before")


def stage_diagnose(st: RunState, table: dict) -> None:
    from workbench.diagnosis import diagnose

    data = _loop_data(st, table, "diagnose")
    max_effects = take(table, "max_effects", 3, where="diagnose", kind=int)
    refuse_leftovers(table, where="diagnose")
    result = diagnose(st.model, data, max_effects=max_effects)
    payload = result.to_json()
    st.write_json("findings.json", payload)
    st.summary["diagnose"] = {
        "error_before": payload["error_before"],
        "findings": [
            {k: f[k] for k in ("effect", "parameters", "error_after")} for f in payload["findings"]
        ],
    }
    if "remaining" in payload:  # compare's verdict on the diagnosed model: within noise or not
        rem = payload["remaining"]
        st.summary["diagnose"]["remaining"] = {
            k: rem[k] for k in ("within_noise", "z_mean", "n_failing_bands", "explanation")
        }
    st.diagnosis = result


def stage_augment(st: RunState, table: dict) -> None:
    """Add effects to the model: the diagnosis's findings (jointly fitted), or the named ones."""
    from workbench.diagnosis.augment import augment

    data = _loop_data(st, table, "augment")
    effects = take(table, "effects", None, where="augment", kind=list)
    refuse_leftovers(table, where="augment")
    steps = []
    if effects is None:  # the diagnosis's findings: its last model holds them all, fitted jointly
        diagnosis = st.diagnosis
        if diagnosis is None:
            raise InputError("[augment]: give 'effects' or run a [diagnose] table first")
        found = [f for f in diagnosis.findings if f.effect != "none" and f.model is not None]
        if not found:
            st.summary["augment"] = {"steps": [], "note": "diagnose found nothing to add"}
            return
        model = found[-1].model.to_lti()  # a ModalModel: its realization with its delay
        steps = [
            {"effect": f.effect, "parameters": f.parameters, "error_after": f.error_after}
            for f in found
        ]
    else:  # one effect after the other; the model's delay rides along, exact
        model = st.model
        for effect in effects:
            out = augment(model, data, effect)
            steps.append(
                {
                    "effect": effect,
                    "parameters": out.parameters,
                    "error_before": out.error_before,
                    "error_after": out.error_after,
                }
            )
            model = out.model
    formats.save_model(st.path("model_augmented.npz"), model)  # delay exact in 'delay_s'
    after = _compare_into(st, model, data, "compare_after")
    st.write_json("augment.json", {"steps": steps, "compare_after": after})
    st.summary["augment"] = {"steps": steps, "compare_after": after}


__all__ = ["stage_compare", "stage_diagnose", "stage_augment"]

"""Which physical effect does the model miss? Screen, fit, rank, explain, repeat.

Each round: every applicable structure is screened on its grid with the
projected cost, the most promising are fitted (fit.py), and the candidates
are ranked by the Bayesian information criterion with the noise scale
estimated from the data, BIC = n ln(cost / n) + k ln n (k = all parameters,
linear ones included, so a flexible effect does not win by fitting noise).
The best is accepted when its BIC is lower and it lowers the spec error by at
least 15 % (or the weighted misfit by 30 %, or it brings the model within
noise by compare's criterion); a candidate whose spec error does not fall is
never a finding (it is listed under alternatives with its numbers). An
accepted effect is added to the model, the linear parts of the added modes are
refitted jointly (backfit / polish), and the next round looks for a second
effect on top of it.

The loop ends when compare (:func:`workbench.validate.compare.compare`, its
own noise test) finds the model within noise, when no effect is significant,
or after ``max_effects`` rounds. The final verdict is ``Diagnosis.remaining``:
within noise, or the bands that still fail; 'none' is reported only when
compare finds the model within noise (or, without a noise reference, when no
effect lowers the error). A nonlinearity is a finding only with a fitted port
element (friction, cubic spring, saturation) whose nonlinear simulation model
lowers the error (:func:`workbench.diagnosis.nonlinear.fit_port_element`). The
ports are the outputs of a square model (for the modes it sees as its inputs drive them;
a mode seen with another shape enters the ports with a gain fitted with the element,
:func:`workbench.diagnosis.nonlinear.square_ports`); on a model that is not square, a
sensor collocated with an input fixes the mode shapes at every input
(:func:`workbench.diagnosis.nonlinear.with_ports`, the extended modal model), and
each pair that may be collocated is a hypothesis the record decides. Without
ports friction and a spring cannot be fitted; a saturation of the inputs needs none
(the linear model driven by the clipped recorded input,
:func:`workbench.diagnosis.nonlinear.fit_saturation`) and is tried alone; when it does
not explain the record, only distortion on the lines the excitation leaves empty makes
a nonlinearity a finding (a periodic residual the linear search left is what a linear
effect it missed leaves too). The evidence that sends the search to an element: that
distortion, a period-synchronous residual no linear effect removed, or (the steady state
right) an error of the from-rest simulation above ``DRIFT_RATIO`` times the noise floor
estimated from the record's periods (:func:`workbench.diagnosis.detect.noise_floor`): a
drift, the twice-integrated mean of a force the linear model does not apply (a closed
loop's slightly clipped command). The finding's ``level`` is the spec's, the share of the
output power the fitted element adds to the linear model's response
(:attr:`workbench.diagnosis.nonlinear.ElementFit.level`); the detector's estimate is its
``evidence_level``. A modal mismatch or a suspension may be
only what a port element linearizes to (friction's equivalent damping, a
spring's equivalent stiffness): when the search accepts one on a time record,
the element on the model as given is tried at once, and it replaces the linear
finding when it explains the record better by the factor a finding must.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import re
from contextvars import ContextVar
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from workbench.core.blas import limited_blas
from workbench.core.errors import InputError
from workbench.core.jsonutil import jsonable
from workbench.core.lti import as_matrices, frf, relative_error_frf, relative_error_time
from workbench.diagnosis import detect
from workbench.diagnosis.effects import (
    AliasedMode,
    CoupledSuspension,
    MissingMode,
    ModalMismatch,
    UpperResidual,
    _rank_one,
    backfit,
    candidate_structures,
    polish,
    refinements,
)
from workbench.diagnosis.explain import (
    _chan,
    _hz,
    damping_floor_note,
    explain,
    modes_moved,
    own_modes,
)
from workbench.diagnosis.fit import (
    MAX_NFEV,
    NUMERICAL_FAILURES,
    FitResult,
    coupling_added,
    fit,
    fit_budget,
    fit_joint,
    screen,
)
from workbench.diagnosis.modal import decompose
from workbench.diagnosis.problem import make_problem, moving_start
from workbench.io.formats import FrfData, TimeData, check_model_matches
from workbench.modal.model import ModalModel
from workbench.sim import simulate_zoh
from workbench.validate.compare import estimated_start, right_model_z_mean, variance_dof

__all__ = ["Finding", "Diagnosis", "diagnose"]

#: a finding must lower the spec error by at least this factor
ERROR_RATIO = 0.85
#: a mode's image above Nyquist is reported when its fit is this close to the mode's
IMAGE_TIE = 1.01
#: an image chain is refined only where a short joint fit comes this close to the chain's error
IMAGE_SCREEN = 1.1
#: lighter images are not tried: no structure is that lightly damped
IMAGE_MIN_DAMPING = 2e-3
#: a resonance in the band damped more than this many times the model's most damped flexible
#: mode, whose image above Nyquist is damped no more than that, is a truncated mode above
#: Nyquist where the record also shows residual compliance (:func:`_truncated_images`)
IMAGE_DAMPING_RATIO = 2.0
#: a found mode's images above Nyquist are looked for up to this multiple of the band's top,
#: the range of a compliance's pseudo-mode (:class:`~workbench.diagnosis.effects.UpperResidual`)
IMAGE_REACH = 10.0
#: the structure's damping ratio where the model has no flexible mode to tell it
Z_STRUCTURAL = 0.02
#: ... or the weighted misfit by at least this factor
COST_RATIO = 0.7
#: a later round's held joint fit (a coupled suspension's coupling held) is refitted with
#: every parameter free only where it lowers the record cost below this factor of the
#: current model's, or the error below HELD_NEAR_ERROR of it (:func:`_joint_candidates`):
#: well short of COST_RATIO and ERROR_RATIO, what the freed coupling adds
HELD_NEAR = 0.9
HELD_NEAR_ERROR = 0.95
#: the error counts as at the noise floor below this multiple of it
FLOOR_RATIO = 1.1
#: periodic time data: the period-synchronous residual within this multiple of its noise is noise
PERIODIC_F = 1.25
#: periodic power on unexcited lines above this multiple of the noise is distortion
NL_F = 4.0
#: ... the same on a raw closed-loop record, tested before any fit (stricter: no model help)
NL_F_RAW = 8.0
#: periodic residual left by the best linear model beyond this multiple of its noise: not linear
PERIODIC_NL = 2.5
#: a time-domain error beyond this multiple of the noise floor estimated from the record's
#: periods (:func:`workbench.diagnosis.detect.noise_floor`) is a misfit, even with the
#: period-synchronous residual at the noise (a drift); the benchmarks' pass mark
DRIFT_RATIO = 2.0
#: a periodic record whose periods' spread exceeds its white-noise estimate this many times
#: has not settled into a periodic response (:func:`_unrepeated_periods`)
UNREPEATED_RATIO = 3.0
#: raw-record distortion is stationary: last period's unexcited-line power over the first kept
#: one within these bounds (a transient decays, a lightly damped closed-loop mode may grow)
NL_STATIONARY = (0.5, 1.2)
#: candidates refitted jointly with the earlier findings each round
JOINT_CANDIDATES = 3
#: an FRF without G_var: the search stops when at most this share of the residual's power is
#: more than noise (detect.frf_structure_share), a third of what a finding must remove
FRF_QUIET = 0.1
#: the lags' effects: every structure of theirs is fitted, whatever the screen (:func:`_diagnose`)
LAG_EFFECTS = ("actuator_dynamics", "sensor_dynamics")
#: every pair of effects is fitted jointly in the first round (:func:`_pair_chain`) on an
#: FRF with G_var whose best single effect leaves the misfit above this many noise floors,
#: and the best pair taken there when it comes within as many; a diagnosis that ends above
#: the noise by compare's test (FRF with G_var, periodic records) is run again with the
#: best pair taken in its first round (:func:`diagnose`). Greedy selection misses a pair whose
#: members alone each explain little of the noise-weighted misfit (an indepgen beam FRF with
#: a one-sample delay and a missing mode at 28 Hz: alone 37x / 204x the floor, a sensor lag
#: at 0.2-2 Hz 146x ranked first on the weighted cost; the pair jointly 1.00x)
PAIR_RATIO = 3.0
#: ... and in the first round of an FRF's greedy search only where that best single effect
#: leaves more than this share of the error (a strong first step is rarely wrong: there the
#: pairs, about 3 s on a 6x6 stage, would only repeat what the next round finds)
PAIR_WEAK = 0.5
#: evaluations of each pair's joint fit in that search (the best pair is then refined to
#: convergence): from the singles' fits, the right pair is found in a few steps
PAIR_NFEV = 8
#: a spring on a mode's coordinate is tried on the flexible modes within this factor of the
#: excited band either way (a hardening spring on a mode just above the band still moves
#: what the band shows of it)
MODAL_BAND = 1.25
#: whether friction on a square model's rigid-body motion
#: (:class:`~workbench.diagnosis.nonlinear.RigidPorts`) is a hypothesis beside the ports'
RIGID_FRICTION = True
#: linear effects a port element's describing function is: friction's equivalent viscous
#: damping (4 F_c / (pi omega A)) and the equivalent stiffness of stiction or a hardening
#: spring move the modes their port moves (a modal mismatch) or suspend a rigid body
LINEARIZED_ELEMENT = ("modal_mismatch", "suspension_stiffness")
#: a port element hypothesis (the element's ports on one linear model) is fitted only when
#: its first-order signature (the residual's distance from the non-negative span of the
#: element's regressors at level zero, :func:`workbench.diagnosis.nonlinear.first_order_errors`,
#: a few linear simulations) removes at least this share of the residual power the element
#: must remove (:func:`_screen_passes`)
SCREEN_SHARE = 0.1
#: ... and when the linear model's from-rest error is within this factor of its error on the
#: record as the problem measures it (from the estimated start of a record that starts moving)
SCREEN_START = 2.0


@dataclass(frozen=True)
class Finding:
    """One effect found: where it shows, its fitted parameters, the error after adding it."""

    effect: str
    inputs: tuple[int, ...]
    outputs: tuple[int, ...]
    band_hz: tuple[float, float]
    parameters: dict[str, Any]
    parameters_std: dict[str, Any]
    error_after: float
    explanation: str
    model: ModalModel | None = field(default=None, repr=False, compare=False)
    fit_status: str = "ok"
    """"ok" (the search met its stops, or ended within a fraction of a noise variance of its
    optimum: :data:`~workbench.diagnosis.fit.SETTLED_GAIN`), or why the least-squares fit
    stopped without converging."""

    @property
    def undetermined(self) -> tuple[str, ...]:
        """Parameters whose standard deviation the data cannot give (NaN in parameters_std)."""
        return tuple(k for k, v in self.parameters_std.items() if _has_nan(v))

    def to_json(self) -> dict:
        out = {
            "effect": self.effect,
            "inputs": [int(i) for i in self.inputs],
            "outputs": [int(i) for i in self.outputs],
            "band_hz": [float(self.band_hz[0]), float(self.band_hz[1])],
            "parameters": jsonable(self.parameters),
            "parameters_std": jsonable(_mark_undetermined(self.parameters_std)),
            "error_after": float(self.error_after),
            "explanation": self.explanation,
            "fit_status": self.fit_status,
        }
        return out


def _has_nan(v) -> bool:
    try:
        return bool(np.any(np.isnan(np.asarray(v, float))))
    except (TypeError, ValueError):
        return False


def _mark_undetermined(x):
    """NaN standard deviations become the word "undetermined" in JSON (not null, not a number)."""
    if isinstance(x, dict):
        return {k: _mark_undetermined(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_mark_undetermined(v) for v in np.asarray(x, dtype=object).tolist()]
    if isinstance(x, float | np.floating) and math.isnan(x):
        return "undetermined"
    return x


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes
    ----------
    error_before : float
        Spec error of the model as given: simulated from rest, or on a time record that
        starts moving from the initial state compare estimates (``notes`` says which).
    findings : tuple of Finding
        Ranked, most likely first; one ``none`` finding when nothing is missing.
    alternatives : tuple of dict
        Runner-up explanations of the first round (effect, error_after, delta_bic).
    noise_floor : float or None
        Error expected from the noise alone (FRF data with G_var).
    remaining : dict or None
        compare's verdict on the final model: within noise, or the bands that still
        fail (what no finding explains).
    model : ModalModel
        The model with every finding added, in the diagnosis's form
        (:func:`workbench.diagnosis.modal.decompose`: rigid modes merged, added
        modes marked by :attr:`~workbench.modal.model.Mode.effect`); ``.to_lti()``
        realizes it with its delay.
    """

    error_before: float
    findings: tuple[Finding, ...]
    alternatives: tuple[dict, ...] = ()
    noise_floor: float | None = None
    data_kind: str = "frf"
    notes: tuple[str, ...] = ()
    model: ModalModel | None = field(default=None, repr=False, compare=False)
    remaining: dict | None = None
    """compare's verdict on the final model (:func:`workbench.validate.compare.compare`):
    ``within_noise``, ``z_mean``, the worst failing bands and what they mean; None when
    the data carry no noise reference (FRF without G_var, non-periodic time record)."""

    def to_json(self) -> dict:
        out: dict[str, Any] = {
            "error_before": float(self.error_before),
            "findings": [f.to_json() for f in self.findings],
        }
        if self.noise_floor is not None:
            out["noise_floor"] = float(self.noise_floor)
        out["data_kind"] = self.data_kind
        out["alternatives"] = jsonable(list(self.alternatives))
        if self.notes:
            out["notes"] = list(self.notes)
        if self.remaining is not None:
            out["remaining"] = jsonable(self.remaining)
        return out

    @property
    def top(self) -> Finding:
        """The most likely finding; when there is none (compare still fails and no effect of
        the vocabulary lowers the error: ``remaining`` says where), an ``"unexplained"``
        stand-in at ``error_before`` that is not part of ``findings``."""
        if self.findings:
            return self.findings[0]
        why = (self.remaining or {}).get("explanation", "no effect of the vocabulary explains")
        return Finding(
            effect="unexplained",
            inputs=(),
            outputs=(),
            band_hz=(0.0, 0.0),
            parameters={},
            parameters_std={},
            error_after=float(self.error_before),
            explanation=why,
            model=self.model,
        )


def _bic(cost: float, n: int, k: int) -> float:
    return n * math.log(max(cost, 1e-300) / n) + k * math.log(n)


def _spec_error(model, data, delay_s: float = 0.0) -> float:
    """The spec error of a model as given (python-control StateSpace, continuous or discrete)."""
    if isinstance(data, FrfData):
        return relative_error_frf(data.G, frf(model, data.freq, delay_s=delay_s))
    if as_matrices(model)[4] > 0:
        # a discrete model delays by whole samples: the rest of the delay is not representable
        delay_s = round(delay_s * data.fs) / data.fs
    return relative_error_time(data.y, simulate_zoh(model, data.u, data.fs, delay_s=delay_s))


def diagnose(
    model,
    data: FrfData | TimeData,
    *,
    max_effects: int = 3,
    n_full_fits: int | None = None,
    effects: tuple[str, ...] | None = None,
    delay_s: float = 0.0,
    blas_threads: int | None = 1,
    domain: str = "auto",
) -> Diagnosis:
    """Tell which physical effect ``model`` misses to explain ``data``, fit it, rank the findings.

    Parameters
    ----------
    model : LTIModel, control.StateSpace or model file path
        The engineer's model, continuous (dt = 0) or discrete (dt = 1/fs for time data);
        an LTIModel's delay is the delay the model already has.
    data : FrfData or TimeData
    max_effects : int
        Rounds of "find the best effect, add it, look again".
    n_full_fits : int, optional
        Candidates refined by least squares each round, after screening all on their grids
        (default: all for FRF data, the best 5 for time data).
    effects : tuple of str, optional
        Restrict the candidates to these effects.
    delay_s : float
        Input delay added to the model's own, s.
    blas_threads : int or None
        BLAS threads during the call (restored on return); None keeps the caller's setting.
    domain : {"auto", "time", "frequency"}
        Where a time record is fitted (:func:`~workbench.diagnosis.problem.make_problem`):
        "auto" fits a periodic record on its steady-state periods' excited lines and any
        other record as a simulation. Every reported error is the time-domain measure.

    Returns
    -------
    Diagnosis
    """
    from workbench.core.model import as_model

    # the model's own delay travels with it; delay_s adds to it
    lti_model = as_model(model)
    delay_s = lti_model.delay_s + float(delay_s)
    model = lti_model.without_delay().to_statespace()
    # many tiny matrix operations: BLAS threads only add overhead (100x on a loaded machine)
    kw = dict(
        max_effects=max_effects,
        n_full_fits=n_full_fits,
        effects=effects,
        delay_s=delay_s,
        domain=domain,
    )
    # the rerun's first round repeats the greedy search's (same model and record): the model's
    # decomposition, the problem and the first round's screens and fits are shared
    kw["shared"] = {}
    token = _JOINT_FITS.set({})
    try:
        with limited_blas(blas_threads):
            result = _searched(model, data, kw)
            result = _split_by_cause(_springs_from_given(result, kw["shared"]), kw["shared"])
            if isinstance(data, TimeData) and moving_start(data):
                result = _compare_measured(result, model, data, delay_s, kw["shared"])
            return result
    finally:
        _JOINT_FITS.reset(token)


def _searched(model, data, kw: dict) -> Diagnosis:
    """The greedy search, and the reruns where it ended above the noise (:func:`diagnose`)."""
    domain = kw["domain"]
    result = _diagnose(model, data, **kw)
    if _unrepeated_finding(result):
        # the periods do not repeat: no linear model, a pair of effects or one fitted on
        # the whole record, gives a response to a periodic input that is not periodic
        # (an indepgen beam record with a cubic spring: the two reruns, 60 of 96 s, ended
        # on other linear findings no closer to the floor)
        return result
    if (
        result.remaining is not None
        and not result.remaining["within_noise"]
        and not (
            # compare judges the linear model only: an element at the floor is complete
            result.findings
            and result.findings[-1].effect == "nonlinearity"
            and _periodic_floor_reached(result, data, kw["shared"])
        )
    ) or _coloured_chain(result, data):
        # the greedy search ended above the noise (compare's test: FRF with G_var, periodic
        # records): a pair of effects it passed over in its first round (each alone
        # explaining little) may reach it. (An FRF's first round took a pair that reaches
        # its floor already.)
        paired = _diagnose(model, data, pair_first=True, **kw)
        if paired is not None and _better(paired, result):
            result = paired
    if domain == "auto" and _lines_left_above_noise(result, data, kw["shared"]):
        # the excited lines may not hold what the record shows (few lines, a lightly
        # damped mode between them beside a crosstalk: an oracle record on 28 lines
        # ended on a nonlinearity at 1.28x the noise floor, fitted on the whole record
        # crosstalk and the mode at 1.00x)
        timed = _diagnose(model, data, **{**kw, "domain": "time", "shared": {}})
        if timed is not None and _better(timed, result):
            result = replace(
                timed,
                notes=timed.notes
                + (
                    "fitted on the whole record: on the periodic record's excited lines "
                    "the search ended above the noise floor its periods give ("
                    + ", ".join(f.effect for f in result.findings)
                    + f", error {_final_error(result):.4g})",
                ),
            )
    return result


def _springs_from_given(result: Diagnosis, shared: dict) -> Diagnosis:
    """A suspension's springs set anew (:class:`~workbench.diagnosis.effects.SuspensionSprings`)
    reported from the model as given: fitted jointly after a modal mismatch that moved the
    same modes in its first round, its own "model" values are that round's (the FE
    example: 2.811 -> 2.807 Hz, where the model has 2.526 Hz); the mismatch's values for
    those modes move nothing in the joint model (its report leaves them out)."""
    base = shared.get("base")
    if base is None:
        return result
    found = []
    for f in result.findings:
        p = f.parameters
        if f.effect != "suspension_stiffness" or "coupling" not in p or f.model is None:
            found.append(f)
            continue
        if len(f.model.modes) != len(base.modes):
            found.append(f)
            continue
        modes = []
        for m in p["modes"]:
            k = [
                i
                for i, mm in enumerate(f.model.modes)
                if mm.effect == "suspension_stiffness"
                and abs(mm.freq_hz - m["freq_hz"]) <= 1e-9 * m["freq_hz"]
            ]
            if len(k) != 1:
                break
            given = base.modes[k[0]]
            modes.append(
                {**m, "model_freq_hz": float(given.freq_hz), "model_damping": float(given.damping)}
            )
        if len(modes) != len(p["modes"]):
            found.append(f)
            continue
        worst = max(modes, key=lambda m: abs(np.log(m["freq_hz"] / m["model_freq_hz"])))
        text = f.explanation.replace(
            modes_moved(p["modes"], damping="new"), modes_moved(modes, damping="new"), 1
        )
        f = replace(f, parameters={**p, **worst, "modes": modes}, explanation=text)
        if found and found[-1].effect == "modal_mismatch" and found[-1].model is not None:
            # the mismatch before it: its error with the suspension's modes as given
            before = found[-2].error_after if len(found) > 1 else result.error_before
            found[-1], f = _mismatch_without(found[-1], f, base, shared["problem"], before)
        found.append(f)
    return replace(result, findings=tuple(found))


def _mismatch_without(mismatch: Finding, springs: Finding, base: ModalModel, problem, before):
    """(mismatch, springs) with the mismatch's error taken with the modes the springs set put
    back as the model has them (:func:`_springs_from_given`): its model moved them in its
    first round, which the joint fit no longer determines. Unchanged where that does not
    leave each finding lowering the error (from ``before``)."""
    ks = [i for i, m in enumerate(springs.model.modes) if m.effect == "suspension_stiffness"]
    model = mismatch.model
    if len(model.modes) != len(base.modes) or not ks:
        return mismatch, springs
    middle = _put_back(model, base, ks)
    err = problem.error(middle)
    if not before > err > springs.error_after:
        return mismatch, springs
    return _restated(mismatch, before, err, middle), _restated(
        springs, err, springs.error_after, springs.model
    )


def _put_back(model: ModalModel, before: ModalModel, indices) -> ModalModel:
    """``model`` with its modes at ``indices`` as ``before`` has them (the same places)."""
    return replace(
        model,
        modes=tuple(before.modes[i] if i in indices else m for i, m in enumerate(model.modes)),
    )


def _split_by_cause(result: Diagnosis, shared: dict) -> Diagnosis:
    """Each modal mismatch whose modes mostly share one frequency factor while a few in the
    band move each on its own (``pattern["of_modes_hz"]``,
    :func:`~workbench.diagnosis.effects._shared_by_most`) as two findings, one a cause:
    the shared factor (a wrong Young's modulus or density) and the others (a suspension's
    springs, a local stiffness or mass). One joint fit, two errors: its model with only
    the sharing modes moved, then with all (the public FE example, Young's modulus 6 % high
    and the flexures off: 0.496 -> 0.0099 in one step before). Kept whole unless each part
    lowers the error."""
    problem, base = shared.get("problem"), shared.get("base")
    if problem is None or base is None:
        return result
    found: list[Finding] = []
    before_model, before_err = base, result.error_before
    for f in result.findings:
        parts = _cause_parts(f, before_model, before_err, problem)
        found += parts or [f]
        if f.model is not None:
            before_model = f.model
        before_err = f.error_after
    if len(found) == len(result.findings):
        return result
    return replace(result, findings=tuple(found))


def _cause_parts(f: Finding, before: ModalModel, err_before: float, problem) -> list | None:
    """``f`` split by :func:`_split_by_cause`, or None."""
    pattern = f.parameters.get("pattern") or {}
    share = pattern.get("of_modes_hz")
    if f.effect != "modal_mismatch" or share is None or f.model is None:
        return None
    modes, stds = f.parameters["modes"], f.parameters_std.get("modes") or []
    hi = problem.band_hz[1]

    own = own_modes(modes, share, hi)
    if not own or len(own) == len(modes) or len(before.modes) != len(f.model.modes):
        return None
    index = {}
    for j in own:
        f0 = modes[j]["model_freq_hz"]
        k = [i for i, m in enumerate(before.modes) if abs(m.freq_hz - f0) <= 1e-9 * f0]
        if len(k) != 1:
            return None
        index[j] = k[0]
    # the joint fit's model with the modes that move on their own put back
    middle = _put_back(f.model, before, set(index.values()))
    err_mid = problem.error(middle)
    if not err_mid < err_before or not f.error_after < err_mid:
        return None

    def subset(keep: list[int]) -> tuple[dict, dict]:
        in_band = [j for j in keep if modes[j]["model_freq_hz"] <= hi] or keep
        worst = max(
            in_band,
            key=lambda j: (
                abs(np.log(modes[j]["freq_hz"] / modes[j]["model_freq_hz"]))
                / max(modes[j]["model_damping"], 1e-6)
            ),
        )
        params = {**modes[worst], "modes": [modes[j] for j in keep]}
        std = {}
        if len(stds) == len(modes):
            std = {**stds[worst], "modes": [stds[j] for j in keep]}
        return params, std

    rest = [j for j in range(len(modes)) if j not in index]
    p1, s1 = subset(rest)
    p1["pattern"] = pattern
    p2, s2 = subset(own)
    scale = pattern["freq_scale"]
    n_above = sum(1 for j in rest if modes[j]["model_freq_hz"] > hi)
    where = _chan(f.inputs, f.outputs, before.n_u, before.n_y)
    first = replace(
        f,
        parameters=p1,
        parameters_std=s1,
        error_after=float(err_mid),
        model=middle,
        explanation=(
            f"the model's modes from {_hz(min(share))} to {_hz(max(share))} show in the data "
            f"at one factor of their frequencies, {scale:.4g} ({100 * (scale - 1):+.2f} %), "
            + (f"and {n_above} above the band are moved by it; " if n_above else "; ")
            + f"the stiffness-to-mass ratio {scale**2:.4g} times the model's, as a wrong "
            f"Young's modulus or density gives; on {where}; the error falls from "
            f"{err_before:.4g} to {err_mid:.4g}; the modes the factor does not move are the "
            "next finding (fitted jointly with this one)."
        ),
    )
    moved = modes_moved([modes[j] for j in own], damping="both")
    second = replace(
        f,
        parameters=p2,
        parameters_std=s2,
        explanation=(
            f"the model's modes at {_hz([modes[j]['model_freq_hz'] for j in own])} move each "
            f"on its own, not by the factor the others share ({moved}): another cause (a "
            "suspension's or a support's springs, a local stiffness or mass); fitted jointly "
            f"with the previous finding; the error falls from {err_mid:.4g} to "
            f"{f.error_after:.4g}."
        ),
    )
    return [first, second]


def compare_start_error(model, data: TimeData, delay_s: float = 0.0) -> float | None:
    """The error of ``model`` on ``data`` from the start compare estimates, or None.

    compare's measure (:func:`workbench.validate.compare.estimated_start`): one initial
    state for all outputs by least squares on the from-rest residual, then the spec's
    relative error. ``model``: a ModalModel (its own delay) or a python-control
    StateSpace with ``delay_s`` (rounded to whole samples for a discrete one, as
    :func:`_spec_error`). None where the start cannot be estimated (compare then says why).
    """
    if isinstance(model, ModalModel):
        lti, ss = model.to_lti(), model.to_statespace(form="scaled")
        y_rest = simulate_zoh(lti, data.u, data.fs)
    else:
        if as_matrices(model)[4] > 0:
            delay_s = round(delay_s * data.fs) / data.fs
        ss = model
        y_rest = simulate_zoh(model, data.u, data.fs, delay_s=delay_s)
    y_start, _ = estimated_start(ss, data, y_rest)
    return None if y_start is None else relative_error_time(data.y, y_start)


#: the note :func:`_diagnose` gives on a record that starts moving, replaced by
#: :func:`_compare_measured`'s
_PER_OUTPUT_NOTE = "the record does not start at rest: errors are from the estimated start (the "


def _compare_measured(
    result: Diagnosis, model, data: TimeData, delay_s: float, shared: dict
) -> Diagnosis:
    """``result`` with its errors as compare measures them, on a record that starts moving.

    The search fits such a record from a start estimated per output
    (:class:`~workbench.diagnosis.problem.TimeProblem`: each output's own coefficients on
    the model's free responses, and a drift): cheap to project out of every candidate's
    fit, but freer than the model's own free response. A candidate's slow mode adds two
    columns to every output's start, and they take up what no model explains: on the CD
    player arm's record (DaISy) an identified second-order model was given a residual
    compliance and a 0.0027 Hz mode, the search's error falling 0.229 -> 0.177 -> 0.148,
    while compare's went 0.271 -> 0.235 -> 0.266. compare estimates one initial state for
    all outputs (:func:`compare_start_error`), the established measure; so the errors
    reported are compare's, and a linear finding is held to the search's own rule there:
    its error must fall, and on a record without periods (no noise reference) fall by
    :data:`ERROR_RATIO` (or its square by :data:`COST_RATIO`), as the search asks of a
    finding on such a record. One that does not, and the findings fitted after it, become
    alternatives with their numbers; where none is left, the 'none' finding says what the
    best of them reaches. A diagnosis that names a nonlinearity keeps its errors (its
    element's simulation measures them).
    """
    given = compare_start_error(model, data, delay_s)
    if given is None or any(f.effect == "nonlinearity" for f in result.findings):
        return result
    notes = [n for n in result.notes if not n.startswith(_PER_OUTPUT_NOTE)]
    notes.append(
        f"the record does not start at rest: errors are from the estimated start as compare "
        f"computes it (one initial state for all outputs, least squares), {given:.4g} for the "
        f"model as given; from rest {_spec_error(model, data, delay_s):.4g}; the search fits "
        f"each output's start on its own (a freer nuisance, cheap to project out): "
        f"{result.error_before:.4g} for the model as given, the measure of the alternatives "
        "it ranked (those rejected here are in compare's)"
    )
    found: list[Finding] = []
    dropped: list[dict] = []
    before = given
    for f in result.findings:
        if f.effect == "none":
            continue  # said again below, at compare's error
        after = None if f.model is None or dropped else compare_start_error(f.model, data)
        why = _not_a_finding(before, after, data)
        if not dropped and why is None:
            found.append(_reported_on_compare(_restated(f, before, after, f.model)))
            before = after
            continue
        dropped.append(
            {
                "effect": f.effect,
                "error_before": float(before),
                "error_after": None if after is None else float(after),
                "parameters": jsonable(
                    {k: v for k, v in f.parameters.items() if k != "residue_matrix"}
                ),
                "rejected": (
                    f"fitted after {dropped[0]['effect']}, which was not a finding"
                    if dropped
                    else why
                ),
            }
        )
    if not dropped and not any(f.effect == "none" for f in result.findings):
        return replace(result, error_before=given, findings=tuple(found), notes=tuple(notes))
    alternatives = tuple(dropped) + result.alternatives
    model_after = found[-1].model if found else shared.get("base")
    if model_after is None:
        model_after = base_model(model, data, delay_s)
    if not found:
        none = _none_finding(
            shared["problem"], model_after, data, given, given, None, list(alternatives)
        )
        if not dropped:
            # the runner-up the search ranked is in its own measure: said, with its start
            text = _RUNNER_UP_NONE.sub(
                rf"\g<0> from {result.error_before:.4g}, both with the start fitted per output",
                none.explanation,
                count=1,
            )
            none = replace(none, explanation=text)
        found.append(none)
    return replace(
        result,
        error_before=given,
        findings=tuple(found),
        alternatives=alternatives,
        notes=tuple(notes),
        model=model_after,
        remaining=_remaining(model_after, data) if dropped else result.remaining,
    )


def _not_a_finding(before: float, after: float | None, data: TimeData) -> str | None:
    """Why a linear finding whose compare error goes ``before`` -> ``after`` is not one
    (:func:`_compare_measured`), or None."""
    if after is None:
        return "compare cannot estimate the start of the model with it"
    if not after < before:
        return (
            f"from the start compare estimates the error does not fall ({before:.4g} -> "
            f"{after:.4g}); the search's fall came from the start it fits per output"
        )
    if not data.period and after > ERROR_RATIO * before and (after / before) ** 2 > COST_RATIO:
        return (
            f"from the start compare estimates the error falls only from {before:.4g} to "
            f"{after:.4g}: on a record without periods (no noise reference) a finding must "
            f"lower it to {ERROR_RATIO:g}x (its square to {COST_RATIO:g}x)"
        )
    return None


def _reported_on_compare(f: Finding) -> Finding:
    """``f`` whose explanation marks its runner-up's error as the search's measure (the start
    fitted per output, :func:`_compare_measured`): only the finding's own errors are restated."""
    text = _RUNNER_UP.sub(r"\1\2 (start fitted per output)", f.explanation, count=1)
    return replace(f, explanation=text)


def _unrepeated_finding(d: Diagnosis) -> bool:
    """Whether a diagnosis names a nonlinearity on the evidence that the record's periods do
    not repeat (:func:`_unrepeated_evidence`)."""
    return any(
        f.effect == "nonlinearity" and f.parameters.get("periods_repeat") is False
        for f in d.findings
    )


def _final_error(d: Diagnosis) -> float:
    """A diagnosis's error after its last finding (before any, where there is none)."""
    return d.findings[-1].error_after if d.findings else d.error_before


def _lines_left_above_noise(result: Diagnosis, data, shared: dict) -> bool:
    """Whether a periodic record fitted on its excited lines ends above the noise floor its
    periods give (:func:`_periodic_floor_reached`) with a residual that shows no distortion:
    a linear misfit the lines did not resolve, which the whole record may (:func:`diagnose`
    fits it there). Whatever compare's verdict: it tests the steady state's lines, where a
    lightly damped mode between them barely shows, and its transient rings in the record
    (a scipy-ZOH oracle: crosstalk fitted on the lines 1.22x the floor, within noise by
    compare; on the whole record 1.003x). ``shared``: the search's (its problem on the
    lines)."""
    if result.remaining is None:
        return False
    # compare may fail a model at the floor (an indepgen stage record, a delay and a modal
    # mismatch at 1.00x it: the whole record refitted them for 70 s, to the same findings)
    problem = shared.get("problem")
    if not _periodic_record(data) or getattr(problem, "time", None) is None:
        return False
    y = problem.predict(result.model)
    if _periodic_floor_reached(result, data, shared, y):
        return False
    return not _distorted(detect.nonlinearity(data, y))


def _periodic_floor_reached(result: Diagnosis, data, shared: dict, y=None) -> bool | None:
    """Whether a periodic time record's diagnosis ends within :data:`FLOOR_RATIO` of the
    noise floor its periods give (:func:`~workbench.diagnosis.detect.noise_floor`, white
    too): its final linear model's error or its last finding's (a nonlinear element's
    simulation model, which compare does not judge). The whole record's rerun
    (:func:`diagnose`) cannot go lower, nor the pairs' after an element (a casegen stage
    record with friction at 1.01x the floor: the pairs' rerun fitted the element again,
    22 -> 77 s, to the same finding); after linear findings compare's verdict calls the
    pairs (a casegen stage record, a delay at 1.01x: with the sensor lag beside it 1.00x).
    None where the record is not periodic, or not fitted on its lines. ``y``: the final
    linear model's prediction, where the caller has it."""
    problem = shared.get("problem")
    if not _periodic_record(data) or getattr(problem, "time", None) is None:
        return None
    linear = result.model
    y = problem.predict(linear) if y is None else y
    floor = detect.noise_floor(data, y, white=True)
    return floor is not None and (
        min(problem.error(linear), _final_error(result)) <= FLOOR_RATIO * floor
    )


def _first_round(memo: dict | None, key: tuple, compute, *args, **kwargs):
    """``compute(*args, **kwargs)``, or what another pass of the search computed for
    ``key`` in its first round (``memo``: :func:`_diagnose`'s ``shared``; None computes).

    The rerun on the pairs (:func:`diagnose`) starts from the same model on the same problem
    (the same objects): its first round's screens and fits are the greedy search's (an
    indep3 shaft time record fitted a coupled suspension twice, 9 s each: 52 -> 43 s CPU
    shared). Keys hold the structures (frozen dataclasses, equal by value) and the start
    points' bytes; a FitResult refitted on the record is keyed by its id, the value (it,
    the refit): the memo keeps it alive, so no other object takes its id.
    """
    if memo is None:
        return compute(*args, **kwargs)
    try:
        hit = memo.get(key)
    except TypeError:  # a structure that does not hash: computed afresh
        return compute(*args, **kwargs)
    if hit is None:
        hit = memo[key] = compute(*args, **kwargs)
    return hit


def _leaves_the_noise(memo, fr: FitResult, problem, base, data, verdict: bool) -> bool:
    """Whether the fit ``fr``, as the search takes it, leaves only the noise: on an FRF with
    G_var (``verdict``) by compare's criterion; on a periodic record refitted there where the
    lines cannot resolve what it adds (:func:`_kept_on_the_record`, memoized as the ranking
    asks for it), within FLOOR_RATIO of the floor the periods give (:func:`_at_time_floor`);
    on an FRF without G_var, at most FRF_QUIET of its residual's power beyond noise from line
    to line (:func:`detect.frf_structure_share`); on a record without periods, a white
    residual (:func:`detect.white_residual`).

    A refinement with tens of parameters then has nothing left to explain: an indep3
    planar record with a suspension, the rigid fit 1.00x the floor on the record, its
    coupling to the flexible modes fitted on the lines (37 parameters by differences) for
    13.7 of the diagnosis's 16.4 s, the same finding at the same error after.
    """
    if verdict:
        return bool(_verdict(fr.model, data).within_noise)
    if isinstance(data, TimeData) and data.period and getattr(problem, "line_hz", None) is not None:
        kept = _first_round(memo, ("record", id(fr)), _kept_on_the_record, fr, problem, base)[1]
        return _at_time_floor(data, problem, kept.model, kept.error)
    if problem.kind == "frf" and not problem.has_var:
        # no floor: what the search's rounds stop on, the residual's share beyond noise from
        # line to line (an indepgen beam FRF, a suspension at 1.00x the floor: its coupling
        # to the flexible modes, 38 parameters on 1707 lines, was most of its 25 s)
        residual = (data.G - problem.predict(fr.model)) * problem.w
        return detect.frf_structure_share(residual) < FRF_QUIET
    if isinstance(data, TimeData):
        # no periods, no floor: a white residual, the rounds' own stop
        return detect.white_residual(data.y - problem.predict(fr.model))
    return False


def _settled(best, memo, problem, base, data, verdict: bool, fr: FitResult) -> bool:
    """Whether ``fr`` needs no refinement that pays only where its structure falls short: it
    is not ``best`` (the round's first by BIC), or it leaves only the noise
    (:func:`_leaves_the_noise`). Asked of the best few, an indepgen stage record with a
    crosstalk had its upper residual (second by BIC) refined in both rounds: 2.4 -> 5.2 s,
    the same finding."""
    return fr is not best or _leaves_the_noise(memo, fr, problem, base, data, verdict)


def _fitted(memo, pairs, problem, base, bar=None) -> list:
    """The first round's memoized fits (:func:`_first_round`) of ``pairs`` (structure, its
    screened starts) on ``base``; ``bar``: :func:`fit`'s."""
    return [
        _first_round(
            memo,
            ("fit", s, _starts_key(starts), bar),
            fit,
            s,
            problem,
            base,
            starts=starts,
            bar=bar,
        )
        for s, starts in pairs
    ]


def _bar(memo, fr: FitResult, problem, base, data, verdict: bool) -> float | None:
    """``fr``'s cost where it leaves only the noise on a record (:func:`_leaves_the_noise`),
    the bar the round's later searches are given up against (:func:`fit`), else None.

    On a record only: there each evaluation of a search is a simulation or a whole record's
    lines, and a wrong structure's search grinds for seconds (FRF searches take a fraction
    of one). A fit above FLOOR_RATIO of a known floor is not tested."""
    if not isinstance(data, TimeData):
        return None
    floor = problem.noise_floor
    if floor is not None and fr.error > FLOOR_RATIO * floor:
        return None
    return fr.cost if _leaves_the_noise(memo, fr, problem, base, data, verdict) else None


def _record_decides(ranked: list, head: list, on_lines: list, data, problem, n: int) -> list:
    """``ranked`` with the record's choice first where the lines cannot make it.

    ``head``: the best few of ``on_lines`` as the search keeps them (refitted on the whole
    record where the lines cannot resolve what they add, :func:`_on_the_record`). A refitted
    one that leaves only the record's noise (:func:`_at_time_floor`) goes first, the lowest
    BIC among such, when the lines' best does not: its lines' cost is not what tells it
    apart (the lines leave its mode undetermined, and that cost is the lines' optimum's or
    near it). An indepgen beam record, two suspension modes at 3.0 and 4.2 Hz below the
    lowest excited line (4.9 Hz): the rigid suspension first by the lines' BIC (5
    parameters, 4.2x the floor on the record), the two modes refitted on the record 1.00x
    (6 parameters, the lines' cost 0.2 % above); the search went on to 2.8x the floor in 48 s,
    a rerun on the whole record found the two modes in 20 s more.
    """
    if not ranked or not (isinstance(data, TimeData) and data.period):
        return ranked
    refit = [k for k, r in zip(head, on_lines) if k is not r]
    if not refit or _at_time_floor(data, problem, ranked[0].model, ranked[0].error):
        return ranked
    at_floor = [
        k for k in refit if k is not ranked[0] and _at_time_floor(data, problem, k.model, k.error)
    ]
    if not at_floor:
        return ranked
    first = min(at_floor, key=lambda r: _bic(r.cost, n, r.n_params))
    return [first] + [r for r in ranked if r is not first]


def _kept_on_the_record(fr: FitResult, problem, base) -> tuple:
    """(``fr``, :func:`_on_the_record` of it): the memo's value keeps ``fr`` alive, so no
    other object takes the id it is keyed by (:func:`_first_round`)."""
    return fr, _on_the_record(fr, problem, base)


def _starts_key(starts) -> tuple:
    """A fit's start points as a memo key (:func:`_first_round`)."""
    return tuple(np.asarray(t, float).tobytes() for t in starts)


def _coloured_chain(result: Diagnosis, data) -> bool:
    """Whether a record without periods (no noise reference for compare) ends with two or
    more findings and a residual that is not white: a pair split by the greedy search leaves
    one of its effects half explained by others (an indepgen beam at 1024 Hz, a modal
    mismatch and a one-sample delay: an actuator lag at 109 Hz, the mismatch and an extra
    mode, 1.14x the floor). One finding with a coloured residual is not rerun (the residual's
    colour may be the sensor noise's)."""
    if not isinstance(data, TimeData) or data.period or len(result.findings) < 2:
        return False
    if any(f.effect == "nonlinearity" for f in result.findings):
        return False  # an element's simulation model is not the linear model's prediction
    model = result.findings[-1].model
    if model is None:
        return False
    problem = make_problem(data)
    return not detect.white_residual(data.y - problem.predict(model))


def _large_above_white(data: TimeData, problem, predicted, last: FitResult, err: float) -> bool:
    """Whether ``last`` removes COST_RATIO of the misfit above the noise of a record without
    periods, the noise's level read from the residuals' spectra
    (:func:`~workbench.diagnosis.detect.residual_floor`, the lower of the model's and the
    candidate's: each is the noise or more).

    The record's ``F = (err / floor)^2`` stands where a periodic record has its
    period-synchronous misfit (:func:`~workbench.diagnosis.detect.periodic_misfit`), and the
    same rule applies: ``F_last - 1 <= COST_RATIO (F - 1)``, with ``F`` at least PERIODIC_F
    (below, what is left is too close to the noise to share out). An indep3 planar record
    without periods, its modes above Nyquist truncated (the effect 0.63x the noise): the
    compliance lowered the error 7.97e-6 -> 6.92e-6 (0.87x, F 1.32 -> 0.99 over a floor of
    6.9e-6) and was not taken, the diagnosis 'none' at 1.16x the floor.
    """
    floors = [
        detect.residual_floor(data, data.y - y) for y in (predicted, problem.predict(last.model))
    ]
    if any(f is None for f in floors):
        return False
    floor = min(floors)
    F, F_last = (err / floor) ** 2, (last.error / floor) ** 2
    return F >= PERIODIC_F and F_last - 1 <= COST_RATIO * (F - 1)


def _judged_within_noise(model: ModalModel, problem) -> bool:
    """compare's verdict on ``model`` where it measures the noise (an FRF with G_var, a
    periodic record); False elsewhere (a record without periods: its verdict passed a model
    at 2.2x the noise floor, tests/test_sampled_image.py)."""
    data = problem.data
    judged = _periodic_record(data) or (problem.kind == "frf" and problem.has_var)
    return judged and _verdict(model, data).within_noise


def _periodic_record(data) -> bool:
    """A time record compare can judge against its noise (periods set)."""
    return isinstance(data, TimeData) and bool(data.period)


def _better(a: Diagnosis, b: Diagnosis) -> bool:
    """Whether diagnosis ``a`` leaves less unexplained than ``b``: within noise by compare's
    test where ``b`` is not, else the lower final error. (A greedy result the rerun replaces
    is above the noise by compare's test: incomplete, so a pair that explains more is the
    better account; a complete greedy result, compare's verdict taken per round, is not
    rerun.)"""
    wa, wb = (d.remaining is not None and d.remaining["within_noise"] for d in (a, b))
    if wa != wb:
        return wa
    return _final_error(a) < _final_error(b)


def base_model(model, data, delay_s: float = 0.0) -> ModalModel:
    """The model as diagnosis and augmentation start from it: its modal decomposition.

    ``model`` is the rational part (a ``StateSpace``), ``delay_s`` (s) its
    input delay, kept in the decomposition. A discrete model against a time
    record must have dt = 1/fs; a realization :func:`decompose` refuses is
    an :class:`InputError` naming the model.
    """
    _, _, _, _, dt = as_matrices(model)
    if isinstance(data, TimeData) and dt > 0 and abs(dt * data.fs - 1) > 1e-9:
        raise InputError(
            f"model: expected a discrete model with dt = 1/fs = {1 / data.fs:g} s, got dt = {dt:g} "
            "s"
        )
    try:
        base = decompose(model)
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(f"model: {exc}") from None
    return replace(base, delay_s=float(delay_s)) if delay_s else base


def model_notes(model) -> tuple[str, ...]:
    """What the diagnosis did to the model before starting (a discrete model made continuous)."""
    dt = as_matrices(model)[4]
    if dt > 0:
        return (
            f"discrete model (dt = {dt:g} s) converted to continuous time by the exact ZOH inverse",
        )
    return ()


def _diagnose(
    model,
    data,
    *,
    max_effects,
    n_full_fits,
    effects,
    delay_s,
    domain,
    pair_first=False,
    shared: dict | None = None,
) -> Diagnosis | None:
    """The diagnosis loop. ``pair_first``: the first round fits every structure and every
    pair of effects jointly (:func:`_pair_chain`) and takes the best pair when its BIC beats
    the best single effect's; None when there is no such pair. ``shared``: a dict the calls
    on one model and record share (:func:`_first_round`)."""
    check_model_matches(model, data)
    if shared is not None and "base" in shared:
        # the same objects: the modes' identity marks what a fit added (_on_the_record)
        base, problem = shared["base"], shared["problem"]
    else:
        base = base_model(model, data, delay_s)
        problem = make_problem(data, domain=domain)
        if shared is not None:
            shared.update(base=base, problem=problem)
    error_before = _spec_error(model, data, delay_s)
    notes = list(model_notes(model))
    if getattr(problem, "transient", False):
        from_rest = error_before
        error_before = problem.error(base)
        notes.append(
            f"the record does not start at rest: errors are from the estimated start (the "
            f"model's free response fitted per output), {error_before:.4g} for the model as "
            f"given; from rest {from_rest:.4g}"
        )
    floor = problem.noise_floor
    n = problem.n_obs
    current = base
    cur_cost = problem.cost(base)
    cur_err = problem.error(base)
    found: list[Finding] = []
    alternatives: list[dict] = []
    exclude: set[str] = set()
    accepted: list[FitResult] = []
    accepted_bases: list[ModalModel] = []
    runners: list = []
    hold: set[int] = set()  # the findings that hold the previous one's error (_falls)
    cur_err0 = cur_err
    # Closed-loop periodic record: the loop settles within a period, so distortion on the
    # unexcited lines of r is tested on the raw output, before any linear model is fitted (a
    # nonlinearity such as friction makes a linear model's simulation drift, and the linear
    # search would otherwise name whatever absorbs the drift, e.g. suspension_stiffness).
    # FRF with G_var: compare's noise test (cheap on an FRF) decides every round whether
    # something is still missing; elsewhere the floor / periodic tests below, and compare's
    # verdict on the final model
    per_round_verdict = problem.kind == "frf" and problem.has_var
    nl_first = None
    if isinstance(data, TimeData) and data.loop == "closed" and data.r is not None:
        nl0 = detect.nonlinearity(data, None)
        if (
            nl0 is not None
            and nl0.f_stat > NL_F_RAW
            and nl0.level > 1e-4
            and NL_STATIONARY[0] < nl0.stationarity < NL_STATIONARY[1]
        ):
            nl_first = nl0
            max_effects = min(max_effects, 1)
            n_full_fits = 2 if n_full_fits is None else n_full_fits
    F_given, nl_early, early_tried = None, None, False
    for round_ in range(max_effects):
        if per_round_verdict:
            # the loop ends where compare says the model is right within noise
            if _verdict(current, data).within_noise:
                break
        elif floor is not None and cur_err <= FLOOR_RATIO * floor:
            break
        F = None
        if isinstance(data, TimeData):
            predicted = problem.predict(current)
            F = detect.periodic_misfit(data, predicted)
            if round_ == 0:
                F_given = F
            if (
                F is not None
                and F < PERIODIC_F
                and not (round_ == 0 and _misfit_off_the_lines(data, predicted, cur_err))
            ):
                # (before the first round a record whose periods do not repeat, or whose
                # from-rest error the steady state does not show, is searched all the same;
                # after it, what the findings leave there is the nonlinearity test's, not more
                # linear terms')
                break
            if not data.period and detect.white_residual(data.y - predicted):
                # no periods, no floor: a residual left white by the findings so far is the
                # sensor noise of an output-error fit, nothing a further effect would explain
                # through the plant's dynamics (coloured). The next round's joint refits cost
                # most of the diagnosis (an indep3 shaft suspension, 35 of 47 s, the error
                # already 1.0001x the noise floor); coloured noise keeps the search going.
                # So does the model as given, before the first round: the FRF's verdict and
                # the periods' floor stop there too (an indep3 planar record, nothing
                # missing: every structure screened and the best few fitted, 5.9 s)
                break
        if round_ > 0 and problem.kind == "frf" and not problem.has_var:
            # an FRF without G_var: no floor. A further finding must remove a large share of
            # the misfit (ERROR_RATIO, COST_RATIO: about 0.3), and all the findings so far
            # leave beyond noise from line to line is at most ``share``
            # (detect.frf_structure_share). The next rounds refitted every candidate with the
            # findings (an indepgen beam FRF, a sensor lag found at 1.00x the floor in the
            # first round: 10 of the diagnosis's 14 s, none taken)
            share = detect.frf_structure_share((data.G - problem.predict(current)) * problem.w)
            if share < FRF_QUIET:
                notes.append(
                    f"round {round_ + 1} not searched: at most {100 * share:.2g} % of the "
                    "residual's power is more than noise from line to line, where a further "
                    f"finding must remove {100 * (1 - COST_RATIO):.0f} %"
                )
                break
        structures = candidate_structures(current, problem, exclude=exclude)
        if effects is not None:
            structures = [s for s in structures if s.effect in effects]
        if not structures:
            break
        memo = shared if round_ == 0 else None  # the first round starts from base alone
        screened = []
        for s in structures:
            sc = _first_round(memo, ("screen", s), screen, s, problem, current)
            screened.append((sc.cost, s, sc.starts))
            if sc.n_failed:
                notes.append(
                    f"round {round_ + 1}: {sc.n_failed} grid point(s) of {s.effect} failed "
                    "numerically and were scored as infinite cost"
                )
        screened.sort(key=lambda t: t[0])
        n_fits = (
            n_full_fits
            if n_full_fits is not None
            else (len(screened) if problem.kind == "frf" or pair_first else 5)
        )
        results: list[FitResult] = []
        deferred: list = []
        bar = None  # the cost of a fit that leaves only the noise, once there is one (_bar)
        for i, (_, s, starts) in enumerate(screened):
            # one-parameter structures are cheap and a coarse grid understates them: refine.
            # So does it a lag's, on each channel apart: every lag is fitted (an indepgen stage
            # record, output lags at 8-13x Nyquist: the input lags fitted, the output lags
            # screened out, a plant near diagonal telling the sides apart only through its
            # couplings; another, three inputs lagged near the band's top: no lag fitted, a
            # missing mode and a compliance named at the floor)
            # ... unless the best fitted so far, not a lag, already leaves only the noise (an
            # indep3 beam record without periods, crosstalk at the floor: the lags' fits 5.8
            # of its 17 s)
            if i < n_fits or len(s.bounds(problem, current)[0]) <= 1:
                results += _fitted(memo, [(s, starts)], problem, current, bar)
                if bar is None and not results[-1].abandoned:
                    bar = _bar(memo, results[-1], problem, current, data, per_round_verdict)
            elif s.effect in LAG_EFFECTS:
                deferred.append((s, starts))
        lead = min(results, key=lambda r: _bic(r.cost, n, r.n_params)) if results else None
        if deferred and not (
            lead is not None
            and lead.effect not in LAG_EFFECTS  # a lag is told from the other side's by fit
            and _leaves_the_noise(memo, lead, problem, current, data, per_round_verdict)
        ):
            results += _fitted(memo, deferred, problem, current, bar)
        by_bic = sorted(results, key=lambda r: _bic(r.cost, n, r.n_params))
        # the best by BIC of those that lower the error: a candidate that raises it is no
        # finding, and no reason to leave the refinements of the best that is unmade (an
        # indep3 beam FRF on undamped springs: a lag whose weighted cost fell while the error
        # rose 0.24 -> 1.03 came first, the rigid suspension at 0.088 was not refined with
        # its coupling, which reaches the floor; a modal mismatch stood in at 17x it)
        best_first = next((r for r in by_bic if r.error < cur_err), by_bic[0] if by_bic else None)
        # a refinement that only pays where its structure falls short (a second pseudo-mode
        # of an upper residual) is asked of the search's noise test, for the best candidate
        # (an indepgen stage FRF, modes at 4.9 and 6.4 kHz over a 4 kHz grid: one pseudo-mode
        # 2.87x the floor, two 1.00x)
        settled = partial(_settled, best_first, memo, problem, current, data, per_round_verdict)
        for r in list(results):
            if r.abandoned:
                continue  # far above a rival that leaves only the noise: nothing to refine
            for s, start in refinements(r, current, problem, settled=settled):
                if isinstance(s, UpperResidual) and _rings_in_band(start, problem):
                    continue  # its fit would be dropped (_pole_rings_in_band): not fitted
                if fit_budget(s) > MAX_NFEV and (
                    r is not best_first
                    or any(
                        _leaves_the_noise(memo, b, problem, current, data, per_round_verdict)
                        for b in by_bic[:JOINT_CANDIDATES]
                    )
                ):
                    # a costly refinement (a coupled suspension: tens of parameters, hundreds
                    # of evaluations) only where its structure already explains the data
                    # best, and neither it nor the next best leaves only the noise (an
                    # indepgen beam record, the rigid suspension first by the lines' BIC at
                    # 4.2x the floor, two suspension modes next at 1.00x on the record: its
                    # coupling's fit was 20 of the diagnosis's 27 s)
                    continue
                results.append(
                    _first_round(
                        memo,
                        ("refine", s, _starts_key([start]), bar),
                        fit,
                        s,
                        problem,
                        current,
                        starts=[start],
                        n_starts=1,
                        max_nfev=fit_budget(s),
                        bar=bar,
                    )
                )
        results = [
            r
            for r in results
            if not _on_frequency_bound(r, problem, current)
            and not _pole_rings_in_band(r, problem, current)
            and not (
                _two_poles(r)
                and not _leaves_the_noise(memo, r, problem, current, data, per_round_verdict)
            )
        ]
        bic0 = _bic(cur_cost, n, sum(a.n_params for a in accepted))
        ranked = sorted(results, key=lambda r: _bic(r.cost, n, r.n_params))
        # the best few refitted on the record where the lines cannot resolve what they add,
        # then ranked again: a lightly damped low mode between the lines, left off on them,
        # loses to a structure the lines fit better (an indepgen beam, a missing mode at
        # 35.1 Hz, zeta 0.016: 1.05x the floor on the lines against residual compliance's
        # 1.00x; refitted on the record 1.0006x at the true mode, and the fewer parameters)
        on_lines = ranked[:JOINT_CANDIDATES]
        head = [
            _first_round(memo, ("record", id(r)), _kept_on_the_record, r, problem, current)[1]
            for r in on_lines
        ]
        ranked = sorted(head + ranked[JOINT_CANDIDATES:], key=lambda r: _bic(r.cost, n, r.n_params))
        ranked = _record_decides(ranked, head, on_lines, data, problem, n)
        best = ranked[0]
        pair, alone = None, None
        # FRF with G_var: the floor is known in the first round, and a best single effect
        # far above it that explains little (the greedy's first step weakly determined)
        # calls for the pairs there; a pair that reaches the floor is taken
        # before the greedy rounds build on a wrong first step (their joint refits of every
        # candidate cost more than the pairs: an indepgen beam FRF, delay + mode, 24 s
        # greedy and 3.6 s in the rerun before). One that does not is left to the greedy
        # search and, where that ends above the noise, to the rerun
        # ... or where the BIC's best is not the error's best: the first step is ambiguous
        # (an indepgen stage FRF, delay + missing mode: residual compliance 0.406 first by
        # BIC, the delay 0.371 by error; the greedy search built on the compliance, 59 s,
        # before the rerun's pairs found delay + mode at the floor)
        by_error = min(ranked, key=lambda r: r.error)
        early_pair = (
            not pair_first
            and round_ == 0
            and per_round_verdict
            and floor is not None
            and best.error > PAIR_RATIO * floor
            and (
                best.error > PAIR_WEAK * cur_err
                or (by_error.effect != best.effect and by_error.error < best.error)
            )
        )
        if (pair_first and round_ == 0) or early_pair:
            if floor is None or best.error > PAIR_RATIO * floor:
                pair = _pair_chain(ranked, problem, base, n, cur_err)
            if pair is not None and not _bic(pair[0][-1].cost, n, pair[0][-1].n_params) < _bic(
                best.cost, n, best.n_params
            ):
                pair = None
            if pair is not None and not pair[0][-1].error < best.error:
                # the lines' cost may favour a pair whose record error is above the best
                # single effect's: it adds an effect and explains less (an indep3 beam record,
                # a coupled suspension alone 1.01x the floor; with crosstalk 1.14x, and a zero
                # delay and a null mismatch after it)
                pair = None
            if pair is not None:
                pair, alone = pair[:2], pair[2]
            if early_pair and pair is not None and pair[0][-1].error > PAIR_RATIO * floor:
                pair = None
            if pair is None and pair_first:
                return None
        if pair is not None:
            # taken even where the best single effect is one of the pair: the greedy search
            # may not have taken it (an input crosstalk's drift hides a delay's gain on the
            # record: the delay alone is no large finding, the pair reaches the floor)
            notes.append(
                f"round 1: {best.effect} alone is best (error {best.error:.4g}); "
                f"{pair[0][0].effect} and {pair[0][1].effect} fitted jointly reach "
                f"{pair[0][1].error:.4g}: both taken"
                + (
                    ""
                    if alone is None
                    else f"; neither lowers the error alone ({alone[0]} {alone[1]:.4g}, "
                    f"{alone[2]} {alone[3]:.4g}, from {cur_err:.4g}): one step, both "
                    "findings at the pair's error"
                )
            )
        if round_ == 0:
            alternatives = [
                {
                    "effect": r.effect,
                    "error_after": r.error,
                    "delta_bic": bic0 - _bic(r.cost, n, r.n_params),
                    "parameters": jsonable(
                        {
                            k: v
                            for k, v in r.structure.report(r, problem, current)[0].items()
                            if k != "residue_matrix"
                        }
                    ),
                }
                for r in ranked
            ]
        if pair is not None:
            best_chain, best_bases = pair
        elif accepted:
            # refit the earlier findings jointly with each of the best few new candidates:
            # an effect fitted alone is biased by the one not yet found
            n_joint = len(ranked) if problem.kind == "frf" else JOINT_CANDIDATES
            chosen = [r for i, r in enumerate(ranked) if i < n_joint or r.theta.size <= 1]
            # where only a large drop makes a finding, the held comparison may show none near
            reach = None if per_round_verdict or _periodic_record(data) else (current, cur_err)
            fits, bases = _joint_candidates(accepted, chosen, problem, base, n, reach=reach)
            fits = _backfitted(fits, problem, base)
            cand = fits[-1]
            k_best = sum(a.n_params for a in accepted) + best.n_params
            if not _on_frequency_bound(cand, problem, bases[-1]) and _chain_better(
                cand, cand.n_params, best, k_best, problem, base
            ):
                best_chain, best_bases = fits, bases
            else:
                best_chain, best_bases = accepted + [best], accepted_bases + [current]
        else:
            best_chain, best_bases = [best], [current]
        last = best_chain[-1]
        k_total = (
            last.n_params
            if (accepted and last is not best) or pair is not None  # a joint fit's own count
            else sum(a.n_params for a in best_chain)
        )
        d_bic = bic0 - _bic(last.cost, n, k_total)
        if d_bic <= 0 and getattr(problem, "time", None) is not None:
            rec = _record_best(ranked, problem, current, accepted)
            if rec is not None:
                d_bic, best = rec
                best_chain, best_bases = accepted + [best], accepted_bases + [current]
                last, k_total = best, sum(a.n_params for a in accepted) + best.n_params
        # significant (BIC), and large: the spec error falls by 15 %, or the noise-weighted
        # misfit by 30 % (with two effects present the first may move the spec error little)
        large = last.error <= ERROR_RATIO * cur_err or problem.record_cost(
            last.model
        ) <= COST_RATIO * problem.record_cost(current)
        if (
            not large
            and d_bic > 0
            and F is not None
            and not _distorted(detect.nonlinearity(data, predicted))
        ):
            # a periodic record measures the misfit above its noise: the period-synchronous
            # residual's power over the noise's, F - 1. A finding that removes as large a share
            # of that is large, however little it moves the error, which the noise holds up
            # near the floor (an indep3 beam record, six truncated modes above Nyquist ringing
            # at their images: the third image lowered the error 7.72e-6 -> 6.61e-6, 0.86x,
            # with F 11.8 -> 7.1 over a floor of 4.84e-6, and the search stopped at 1.6x it).
            # Not where the residual shows distortion on the unexcited lines: a linear effect
            # then takes part of a nonlinearity's periodic residual (a cubic output on a
            # closed-loop stage record: crosstalk, in place of the nonlinearity)
            F_last = detect.periodic_misfit(data, problem.predict(last.model))
            large = F_last is not None and F_last - 1 <= COST_RATIO * (F - 1)
        elif not large and d_bic > 0 and isinstance(data, TimeData) and not data.period:
            # a record without periods: the same rule, the noise read from the residuals'
            # spectra. No distortion test is possible there (no unexcited lines): a linear
            # effect on a nonlinear record must still remove 30 % of the misfit above the
            # noise (an indepgen beam record with a clear nonlinearity: F 8.3, a missing
            # mode took it to 7.3, not large)
            large = _large_above_white(data, problem, predicted, last, cur_err)
        if not large and d_bic > 0 and (per_round_verdict or _periodic_record(data)):
            # a small but significant effect that brings the model within noise by compare's
            # criterion (a subtle low suspension: few lines, the rest already right; a weak
            # missing mode beside a delay on a periodic record, compare's z 10.5 without it)
            large = _verdict(last.model, data).within_noise
        if d_bic <= 0 or not large:
            break
        chain_errs = [cur_err0] + [a.error for a in best_chain]
        if not last.error < cur_err:
            chain_errs.append(np.inf)  # not below the (refined) current model's error
        if pair is not None and alone is not None:
            hold = {1}  # the pair's second finding holds the first's error: one step
        if not _falls(chain_errs, hold) and accepted:
            # the joint refit moved an earlier finding so that its step no longer lowers the
            # error: keep the earlier findings as they were and add the new one on top
            seq = accepted + [best]
            seq_errs = [cur_err0] + [a.error for a in seq]
            if _falls(seq_errs, hold):
                best_chain, best_bases, last = seq, accepted_bases + [current], best
                chain_errs = seq_errs
        if not _falls(chain_errs, hold):
            # a finding never makes the error worse: the candidate is only an alternative
            alternatives.append(_rejected(last, cur_err, problem, best_bases[-1]))
            break
        new = best_chain[len(accepted) :] if len(best_chain) > len(accepted) else [last]
        for a in new:
            runners.append(next((r for r in ranked if r.effect != a.effect), None))
        accepted, accepted_bases = list(best_chain), list(best_bases)
        found = _findings(accepted, runners, accepted_bases, problem, data, cur_err0, floor)
        current = last.model
        cur_cost, cur_err = last.cost, last.error
        if any(m.effect in ("missing_mode", "upper_residual") for m in current.modes):
            polished = backfit(current, problem, d0=base.D)
            if per_round_verdict and not _verdict(polished, data).within_noise:
                polished = polish(polished, problem, d0=base.D)
            if polished is not current:
                current = polished
                cur_cost, cur_err = problem.cost(current), problem.error(current)
                found = _refresh_added(found, current, base)
                found[-1] = replace(found[-1], model=current, error_after=cur_err)
        exclude.update(a.effect for a in new if a.effect != "missing_mode")
        if (
            isinstance(data, TimeData)
            and nl_first is None
            and not early_tried
            and last.effect in LINEARIZED_ELEMENT
            and not _at_time_floor(data, problem, current, cur_err)
        ):
            # a modal mismatch or a suspension may be only a port element's linearization:
            # the element on the model as given is the other explanation of the same misfit,
            # judged as a finding is (it must lower the error below the linear finding's by
            # ERROR_RATIO, and the linear finding must not lower the element's by as much).
            # Tested here, not after the search: its period-synchronous test may pass (a
            # lightly damped mode's transient misfit counts as noise there), and further
            # rounds would only fit what the linear finding left of the element's signature
            early_tried = True
            ev = _misfit_evidence(cur_err, F_given, problem.band_hz)
            finding, _ = _nonlinearity_finding(
                ev, data, error_before, [current, base], cur_err, direct=False, only_given=True
            )
            if finding is not None and finding.model is base:
                notes.append(
                    f"round {round_ + 1}: {last.effect} (error {cur_err:.4g}) is what the "
                    f"nonlinear element linearizes to: {finding.parameters['element']} on the "
                    f"model as given reaches {finding.error_after:.4g}; the linear search stops"
                )
                nl_early = finding
                break
        moved = found[-1].parameters if found else {}
        if (
            isinstance(data, TimeData)
            and nl_first is None
            and not early_tried
            and last.effect == "modal_mismatch"
            and data.n_y != data.n_u
            and moved.get("model_freq_hz", np.inf) <= problem.band_hz[1] < moved["freq_hz"]
        ):
            # the mismatch moved a mode of the band out of it: the record shows only that the
            # mode does not resonate where the model has it, which is also what a hardening
            # spring on the mode's coordinate does when it holds the mode's motion (a modal
            # Duffing). At the noise floor (estimated from the periods) the record cannot
            # choose between them: the spring on the model as given, one level on the mode the
            # mismatch moved, is taken when it reaches the floor as well (the mismatch moved
            # the mode by more than the record resolves: no resonance of it is left to place)
            early_tried = True
            time_floor = detect.noise_floor(data, problem.predict(current))
            if time_floor is not None and cur_err <= FLOOR_RATIO * time_floor:
                ev = _misfit_evidence(cur_err, F_given, problem.band_hz)
                finding, _ = _nonlinearity_finding(
                    ev,
                    data,
                    error_before,
                    [base],
                    cur_err,
                    direct=False,
                    needed=FLOOR_RATIO * time_floor,
                    mode_hz=float(moved["model_freq_hz"]),
                )
                if finding is not None:
                    notes.append(
                        f"round {round_ + 1}: {last.effect} (error {cur_err:.4g}) moves the mode "
                        f"at {moved['model_freq_hz']:.4g} Hz out of the excited band; a cubic "
                        f"spring on that mode's coordinate, on the model as given, reaches "
                        f"{finding.error_after:.4g}, at the noise floor as well "
                        f"({time_floor:.4g}): the nonlinearity, with one parameter, is taken"
                    )
                    nl_early, ambiguous = _ambiguous_spring(
                        finding, found[-1], cur_err, error_before, time_floor
                    )
                    alternatives.append(ambiguous)
                    break
    if nl_early is None:
        chain = (accepted, accepted_bases, found, current, cur_cost, cur_err)
        chain = _simplified(chain, runners, problem, base, data, cur_err0, floor, notes)
        accepted, accepted_bases, found, current, cur_cost, cur_err = chain
    found = _merge_compliance(found)
    if nl_early is not None:
        found, current = [nl_early], base
        cur_err = problem.error(base)
    timed = isinstance(data, TimeData) and nl_early is None
    # the final linear model's prediction, once (a whole record's takes ~0.2 s)
    linear_end, y_end = current, (problem.predict(current) if timed else None)
    nl = detect.nonlinearity(data, y_end) if timed else None
    F_end = detect.periodic_misfit(data, y_end) if timed and nl_first is None else None
    # the error the record's noise leaves, from the spread of its periods (periodic records)
    time_floor = detect.noise_floor(data, y_end) if F_end is not None else None
    # whether the periods repeat, judged once on the final linear model (the evidence below
    # and the note at the end)
    unrepeated_note = (
        _unrepeated_periods(data, y_end, time_floor, cur_err) if time_floor is not None else None
    )
    # a nonlinearity is a finding only when a fitted port element (friction, cubic spring,
    # saturation) in the simulation model lowers the error: a linear misfit at low frequency
    # (a suspension, crosstalk) is not reduced by one, and is no false alarm
    nl_ev, nl_first_rank, unrepeated, nl_needed = None, False, False, None
    linear_left = None  # compare's verdict on the final linear model, when asked below
    given_only = False  # the element must explain the record on the model as given
    nl_why = None  # the evidence in words, when the detector's numbers do not say it
    # the from-rest error well above the noise the periods show (the rigid bodies' friction
    # is then fitted whatever its first-order signature, :func:`_fit_element`)
    drift = time_floor is not None and cur_err > DRIFT_RATIO * time_floor
    # distortion on the unexcited lines carrying a measurable share of the output; strong but
    # tiny distortion (a slight clipping: F 89, level 5e-5) leaves the residual test below
    distorted = _distorted(nl)
    if nl_first is not None:
        nl_ev, nl_first_rank = nl_first, True
    elif F_end is not None and F_end > PERIODIC_NL and not distorted:
        # a reproducible (period-synchronous) residual that no linear effect of the vocabulary
        # removes: the response is not linear in the recorded input (friction, saturation of
        # the applied force). It comes first when the only linear finding absorbs a drift (a
        # spring to the world on a rigid body, which is what a force error integrated twice
        # looks like to a linear model), after the linear findings otherwise.
        nl_ev = _misfit_evidence(cur_err, F_end, problem.band_hz)
        nl_first_rank = [f.effect for f in found] == ["suspension_stiffness"]
    elif distorted:
        # periodic power where a linear system has none: distortion. It ranks first when it
        # carries a share of the output power comparable with the linear misfit, or when the
        # periods do not repeat (the record's main feature, which no linear finding explains)
        unrepeated = unrepeated_note is not None
        nl_ev, nl_first_rank = nl, unrepeated or nl.level >= 0.5 * error_before**2
    elif F_end is not None and cur_err > DRIFT_RATIO * (time_floor or np.inf):
        # the steady state is right (its period-synchronous residual within noise, no
        # distortion), the from-rest simulation is not: a drift no linear effect removed. On
        # a rigid body in a closed loop that is the twice-integrated mean of a force the
        # linear model does not apply (a slightly clipped command: the loop holds the stage,
        # the recorded command's mean is not the applied force's), which only the element's
        # simulation model can show
        nl_ev = _misfit_evidence(cur_err, F_end, problem.band_hz)
        nl_first_rank = [f.effect for f in found] == ["suspension_stiffness"]
    elif (
        F_end is not None
        and any(f.effect == "suspension_stiffness" for f in found)
        and cur_err > FLOOR_RATIO * time_floor
    ):
        # a spring to the world found, and the error left above the floor: what stiction
        # linearizes to (a body held near its position looks sprung), the rest of its
        # misfit too small for the drift test above (an indepgen closed-loop stage record,
        # friction subtle: a 0.85 Hz suspension and a lag at 1.13x the floor). The element
        # must reach the floor, not a large share below the linear findings
        nl_ev = _misfit_evidence(cur_err, F_end, problem.band_hz)
        nl_first_rank = [f.effect for f in found] == ["suspension_stiffness"]
        nl_needed = FLOOR_RATIO * time_floor
    elif unrepeated_note is not None and nl is not None:
        # the periods do not repeat, and the final linear model's residual does not either:
        # the response to a periodic input is not periodic, which no linear time-invariant
        # plant gives once its transient has settled (and the model's own transient cancels
        # in the residual). What does not repeat is spread over the periods, not on the
        # unexcited lines' mean, so no distortion shows there (an indepgen beam record with
        # a cubic spring on its 34 Hz mode: F 0.82, the spread 11x its white estimate; the
        # linear search named a modal mismatch to 88 Hz that lowered the error by 7 %)
        nl_ev = _unrepeated_evidence(data, y_end, time_floor, nl)
        unrepeated, nl_first_rank = True, True
    elif (
        F_end is not None
        and (linear_left := _remaining(current, data)) is not None
        and not linear_left["within_noise"]
    ):
        # compare still fails where the linear findings are near the floor: what a weak
        # spring on a mode leaves (its describing function is a shifted mode whose shift
        # follows the amplitude, which no linear mode reproduces on every excited line; an
        # indepgen beam record, a cubic spring on its 54 Hz mode: a modal mismatch and a
        # missing mode beside it at 1.045x the floor, compare failing 52-58 Hz at median
        # z 42, the spring on the given model at 1.00x). The element must reach the floor,
        # and do better than the linear findings on the model as given, alone: on top of
        # them it would only trim what they left at the noise
        nl_ev = _misfit_evidence(cur_err, F_end, problem.band_hz)
        nl_needed, given_only = min(cur_err, FLOOR_RATIO * time_floor), True
        nl_why = _compare_left_words(found, cur_err, linear_left, data)
    elif (
        timed and nl_first is None and not data.period and not detect.white_residual(data.y - y_end)
    ):
        # no periods: the residual's colour is the only sign left that the linear search
        # stopped above the noise (an indepgen stage record with subtle friction ended
        # 'none' at 4.2x the floor); the element is tried, and must lower the error by
        # ERROR_RATIO to be a finding (coloured sensor noise it cannot explain)
        nl_ev = _misfit_evidence(cur_err, 0.0, problem.band_hz)
        nl_first_rank = not found or [f.effect for f in found] == ["suspension_stiffness"]
    if nl_ev is not None:
        # the element is fitted on the final linear model and on the model as given: what
        # the linear search found may be only what the element linearizes to (a port
        # element's describing function is linear: friction adds damping to the modes its
        # port moves, stiction or a hardening spring adds stiffness - a modal mismatch, a
        # suspension - and both leave a drift), and then the element on the model as
        # given explains the record as well with fewer parameters
        linear = [current] + ([base] if current is not base else [])
        finding, alt = _nonlinearity_finding(
            nl_ev,
            data,
            error_before,
            linear,
            cur_err,
            direct=nl_ev.n_lines > 0,
            unrepeated=unrepeated,
            drift=drift,
            needed=nl_needed,
            only_given=given_only,
            why=nl_why,
        )
        if finding is None:
            alternatives.append(alt)
        elif finding.model is base:
            # the nonlinear element on the given model explains the record better than the
            # linear findings: they absorbed its drift or its linearized stiffness
            found, current = [finding], base
            cur_err = problem.error(base)
        elif nl_first_rank:
            found.insert(0, finding)
        else:
            found.append(finding)
    if isinstance(data, TimeData):
        found = [_with_image(f, current, base, problem) for f in found]
        found = _merge_compliance(_truncated_images(found, current, base, problem))
        if not any(f.effect == "nonlinearity" for f in found):
            weak = _weak_distortion(nl)
            if weak is not None:
                notes.append(weak)
    found = _coupling_read_back(found, current, base)
    if linear_left is not None and current is linear_end:
        remaining = linear_left  # compare's verdict on this model, asked above
    else:
        remaining = _remaining(current, data)
    note = None
    if time_floor is not None and nl_early is None:
        note = unrepeated_note
        if current is not linear_end:  # the element on the model as given took its place
            note = _unrepeated_periods(data, problem.predict(current), time_floor, cur_err)
    elif nl_early is not None and isinstance(data, TimeData) and data.period:
        # the early element took the linear search's place: whether the periods repeat is
        # judged on the model as given all the same (an indepgen beam record whose spring
        # near its jumps the measured-coordinate fit reaches early: the note was lost with
        # the later path it came from)
        y_given = problem.predict(current)
        spread = detect.noise_floor(data, y_given)
        note = _unrepeated_periods(data, y_given, spread, cur_err) if spread else None
    if note is not None:
        notes.append(note)
        if remaining is not None:
            remaining["explanation"] += "; " + note
    element = next((f for f in found if f.effect == "nonlinearity" and f.model is not None), None)
    if remaining is not None and not remaining["within_noise"] and element is not None:
        # compare simulates a linear model: the element's simulation model is what explains
        remaining["explanation"] += (
            f"; compare judges the linear model only, the nonlinearity finding's simulation "
            f"model (its fitted element) reaches the error {element.error_after:.4g}"
        )
    if not any(f.effect != "nonlinearity" for f in found):
        if remaining is None or remaining["within_noise"]:
            drift = None
            if time_floor is not None and cur_err > DRIFT_RATIO * time_floor:
                drift = time_floor
            found.append(
                _none_finding(
                    problem, current, data, cur_err, error_before, floor, alternatives, drift
                )
            )
            found = [f for f in found if f.effect != "none"] or found
    return Diagnosis(
        error_before=error_before,
        findings=tuple(found),
        alternatives=tuple(alternatives),
        noise_floor=floor,
        data_kind=problem.kind,
        notes=tuple(notes),
        model=current,
        remaining=remaining,
    )


def _weak_distortion(nl) -> str | None:
    """A note when the unexcited lines carry distortion beyond the noise (F above NL_F) at
    a share of the output power too small to fit an element to (at most 1e-4), else None.

    The linear findings may then hold the nonlinearity's linearization (a held-out
    indepgen beam record, a hardening spring on a 47.8 Hz mode at 4e-5 of the output:
    a modal mismatch of +1 % at 1.09x the floor, the distortion at F 7.2, level 2e-6).
    """
    if nl is None or not (nl.f_stat > NL_F and nl.level <= 1e-4):
        return None
    return (
        f"the unexcited lines carry periodic power beyond the noise (F {nl.f_stat:.3g} > "
        f"{NL_F:g}) at {nl.level:.2g} of the output power: a weak nonlinearity, too small to "
        "fit an element to; a linear finding may be its linearization (a hardening spring "
        "shifts its mode up, friction adds damping)"
    )


def _misfit_off_the_lines(data, y_model, err: float) -> bool:
    """Whether a periodic record shows a misfit of ``y_model`` (error ``err``) that its
    period-synchronous residual (:func:`detect.periodic_misfit`) cannot, so that a low F
    there says nothing about it: the first round is searched all the same.

    - **The periods do not settle.** They spread about their mean (the residual's against
      ``y_model``: :func:`detect.noise_floor`) more than :data:`UNREPEATED_RATIO` times the
      spread with the noise taken as white: what does not repeat is more than the noise, so
      the periodic misfit's noise reference is not the noise. An indepgen beam record from
      rest, input crosstalk 0.12: its suspension's transient rang through all five periods
      (the spread 5.6x the white estimate), F came out below PERIODIC_F, and the record was
      named a nonlinearity at 10.2x the floor; the crosstalk fits to 1.01x.
    - **The from-rest error is beyond DRIFT_RATIO times that spread.** The steady state is
      right and the transient is not: a slow effect below the excited lines, which only the
      record's start shows (the candidates are then chosen on the record,
      :func:`_record_best`). An indepgen closed-loop stage record, its lines from 30 Hz, a
      suspension at 0.73 Hz (subtle, 3.4x the floor as given, F 1.23): the search stopped
      before the first round and Coulomb friction on the rigid bodies took the drift, at
      2.02x the floor in 14 s; the suspension fits to 1.00x, 0.07 % off, in 0.8 s.
    """
    spread = detect.noise_floor(data, y_model)
    if spread is None:
        return False
    return err > DRIFT_RATIO * spread or _white_below(data, y_model, spread) is not None


def _white_below(data, y_model, spread: float) -> float | None:
    """The record's noise floor with the noise taken as white (:func:`detect.noise_floor`)
    where the periods' ``spread`` exceeds it :data:`UNREPEATED_RATIO` times, else None."""
    white = detect.noise_floor(data, y_model, white=True)
    return white if white is not None and spread > UNREPEATED_RATIO * white else None


def _unrepeated_periods(data, y_model, spread_floor: float, err: float) -> str | None:
    """A note when a periodic record's periods do not repeat, else None.

    The periods' spread about their mean (``spread_floor``, :func:`detect.noise_floor`,
    the lower of the record's and the final model's residual's) more than
    :data:`UNREPEATED_RATIO` times its estimate with the noise taken as white, and the final
    error beyond DRIFT_RATIO times that white floor: the response to a periodic input does
    not settle into a periodic one. compare judges the kept periods' excited lines (their
    mean) and may find the final model within noise while its error is far above it (an
    indepgen beam record with a strong cubic spring on a mode, held-out seed 7: spread 0.113
    of the output, white floor 0.012, its residual growing from 4 % to 29 % of the output
    over ten periods; no spring on a mode of the model reproduced it).
    """
    white = _white_below(data, y_model, spread_floor)
    if white is None or not err > DRIFT_RATIO * white:
        return None
    return (
        f"the record's periods do not repeat: their spread is {spread_floor:.3g} of the output, "
        f"{spread_floor / white:.1f}x its estimate as white noise ({white:.3g}), and the final "
        f"error {err:.4g} is {err / white:.1f}x that: the response to the periodic input has "
        "not settled into a periodic one (a nonlinearity such as a strong spring, a drift, a "
        "time-varying plant, or a transient slower than the record), which no finding here "
        "explains; compare judges the kept periods' mean on the excited lines only"
    )


def _ambiguous_spring(spring: Finding, mismatch: Finding, err, err_before, floor):
    """(finding, alternative): a cubic spring on a mode's coordinate taken over a modal
    mismatch that moved the same mode out of the excited band, both at the noise floor
    ``floor``: the record cannot choose, so the spring's explanation says so and the
    mismatch (error ``err``) is listed beside it with its numbers. The spring is ranked
    first on its one parameter, a prior, not evidence; a record at another excitation
    amplitude tells them apart (the spring's stiffening grows with the motion, a wrong
    frequency does not)."""
    p = mismatch.parameters
    why = (
        f" The record cannot choose between this and a modal mismatch moving the mode from "
        f"{p['model_freq_hz']:.4g} to {p['freq_hz']:.4g} Hz (error {err:.4g}): both reach the "
        f"noise floor ({floor:.4g}), and the spring is preferred for its single parameter, "
        "not by the data. Repeat the experiment at another excitation amplitude: a spring's "
        "stiffening changes with the motion, a wrong frequency does not."
    )
    alt = {
        "effect": mismatch.effect,
        "error_before": float(err_before),
        "error_after": float(err),
        "parameters": jsonable(
            {k: v for k, v in p.items() if k not in ("residue_matrix", "modes")}
        ),
        "ambiguous": (
            f"at the noise floor as the {spring.parameters.get('element', 'element')} "
            "finding is: the record cannot choose between them"
        ),
    }
    return replace(spring, explanation=spring.explanation + why), alt


def _joint_candidates(accepted, chosen, problem, base: ModalModel, n: int, *, reach=None):
    """(fits, bases) of the earlier findings refitted jointly with the best of ``chosen``.

    Each candidate is refitted with the earlier findings, and the best (BIC) is taken. A
    coupled suspension among the findings keeps its coupling to the flexible modes (2 R
    n_f + n_f^2 parameters, :class:`~workbench.diagnosis.effects.CoupledSuspension`) while
    the candidates are compared (:class:`~workbench.diagnosis.fit.Held`), and all its
    parameters are refitted with the candidate taken:
    - on an FRF, where every candidate is refitted jointly: each joint refit differenced
      all 34 parameters of a beam's coupling (indep3 seed 5, 20 joint refits, 44 of the
      diagnosis's 64 s; held 15 s in all, the same findings; over the 36 suspension FRFs of
      seeds 0-5 the same findings, the slowest 42 / 21 / 18 s -> 15 / 6 / 5 s);
    - where an evaluation costs a simulation's worth (``problem.domain == "time"``: a
      record without periods, fitted as a whole): there each joint refit differenced all
      17-19 parameters (an indep3 shaft record: 7 joint refits, 44 of the diagnosis's 54 s,
      none taken; 22 s held).
    Not on a periodic record's lines, where an indep3 beam record took longer held (70 s
    against 37 s, the same findings; session 33), its later rounds going elsewhere.

    ``reach``: (the current model, its error), where a finding must lower its record cost
    or its error by a large factor (:data:`COST_RATIO`, :data:`ERROR_RATIO`; no within-noise
    verdict for small ones). A held best whose record cost stays above
    :data:`HELD_NEAR` of the current one and whose error above :data:`HELD_NEAR_ERROR`
    of it is returned as it is (its structures unheld at the held coupling): freeing the
    coupling re-optimizes what was already optimal without the candidate, and the
    refit of every parameter cost most of the round (an indep3 planar record from rest,
    seed 5, 28 parameters: 15.6 of the diagnosis's 59 s, then not taken).
    """
    held = []
    for a in accepted:
        h = None
        if isinstance(a.structure, CoupledSuspension) and (
            problem.kind == "frf" or problem.domain == "time"
        ):
            h = a.structure.held(a.theta, problem, base)
        held.append(h)
    parts = [h or a.structure for h, a in zip(held, accepted)]
    thetas = [a.theta if h is None else a.theta[list(h.free)] for h, a in zip(held, accepted)]
    fits, bases = _best_joint(parts, thetas, chosen, problem, base, n)
    if not any(held):
        return _joint_on_the_record(fits, bases, problem, base)
    if reach is not None:
        cand = fits[-1]
        # (the current model's record cost only here: a simulation on a record from rest)
        if cand.error > HELD_NEAR_ERROR * reach[1] and problem.record_cost(
            cand.model
        ) > HELD_NEAR * problem.record_cost(reach[0]):
            return _unheld(fits, held, accepted), bases
    # the one taken, with every parameter free, from where the held fit ended
    full = [a.structure for a in accepted] + [fits[-1].structure]
    start = [f.theta if h is None else h.full(f.theta) for h, f in zip(held, fits[:-1])]
    return _fit_joint(full, start + [fits[-1].theta], problem, base)


def _best_joint(parts, thetas, chosen, problem, base: ModalModel, n: int):
    """(fits, bases): the earlier findings ``parts`` (at ``thetas``) refitted jointly with
    the candidate of ``chosen`` that does best by BIC.

    Several candidates: each joint fit runs :data:`PAIR_NFEV` evaluations (as the pairs'
    search does), and the best is refined to convergence from where it stopped. Run to
    convergence, a candidate the data do not hold took most of a diagnosis: the public FE
    example's missing mode beside the modulus pattern, 22 parameters differenced 41 times
    and stopped by the budget, 1.1 of 2.9 s, its cost 2.5x the springs' taken after.
    """

    def joint(r, max_nfev=MAX_NFEV):
        return _fit_joint(
            parts + [r.structure], thetas + [r.theta], problem, base, max_nfev=max_nfev
        )

    def bic(t):
        return _bic(t[0][-1].cost, n, t[0][-1].n_params)

    if len(chosen) == 1:
        return joint(chosen[0])
    short = min((joint(r, PAIR_NFEV) for r in chosen), key=bic)
    fits = short[0]
    return _fit_joint([f.structure for f in fits], [f.theta for f in fits], problem, base)


def _backfitted(fits, problem, base: ModalModel) -> list:
    """A joint fit's results with the last model's added terms backfitted (:func:`backfit`)
    where it holds two or more (missing modes, upper residuals).

    The joint fit solves their linear parts one after another in its stacking order, each
    on what the others before it leave; the current model it is compared with was
    backfitted after its round. Unpolished, a candidate's error is biased up against it (an
    indep3 beam record: compliance and two modes refitted from the chain's own values at
    8.38e-6, backfitted 7.30e-6; a beam record without periods stopped at 3.1x the floor,
    its next folded mode at 0.869x the error, unpolished)."""
    last = fits[-1]
    model = last.model
    if sum(m.effect in ("missing_mode", "upper_residual") for m in model.modes) < 2:
        return fits
    polished = backfit(model, problem, d0=base.D)
    if polished is model:
        return fits
    done = replace(
        last,
        realized=replace(last.realized, model=polished),
        cost=problem.cost(polished),
        error=problem.error(polished),
    )
    return list(fits[:-1]) + [done]


def _unhold(fr: FitResult, h, whole: FitResult) -> FitResult:
    """A fit of a held structure ``h`` back as the whole structure of ``whole`` (the fit it
    was held from): theta full, the held entries' std ``whole``'s, its parameter count."""
    free = list(h.free)
    std = np.array(whole.theta_std, float)
    std[free] = fr.theta_std
    return replace(
        fr,
        structure=whole.structure,
        theta=h.full(fr.theta),
        theta_std=std,
        n_params=whole.n_params,
    )


def _unheld(fits, held, accepted) -> list:
    """A joint fit's results with each held part (:class:`~workbench.diagnosis.fit.Held`)
    back as its structure at the held values: theta full, the held entries' std NaN (not
    fitted), every result's n_params counting the held parameters."""
    extra = sum(len(a.theta) - len(h.free) for h, a in zip(held, accepted) if h is not None)
    out = []
    for k, f in enumerate(fits):
        h = held[k] if k < len(held) else None
        if h is not None:
            std = np.full(len(accepted[k].theta), np.nan)
            std[list(h.free)] = f.theta_std
            f = replace(f, structure=accepted[k].structure, theta=h.full(f.theta), theta_std=std)
        out.append(replace(f, n_params=f.n_params + extra))
    return out


def _simplified(chain, runners, problem, base: ModalModel, data, err0: float, floor, notes):
    """The search's chain (accepted fits, their bases, findings, model, cost, error) with
    what the other findings explain dropped (:func:`_pruned`: backward elimination, an
    early finding absorbed part of an effect found later: an indepgen stage record, a
    749 Hz mode the truth lacks taken before the modal mismatch and the delay that explain
    it) and a residual compliance that is the image of a resonance in the band named there
    (:func:`_in_band_image`). ``runners`` (one per finding) is edited in place; a note per
    change."""
    accepted, bases, found, _, cost, err = chain
    n = problem.n_obs
    while len(accepted) >= 2:
        pruned = _pruned(accepted, bases, problem, base, n, cost, err, err0, model=chain[3])
        if pruned is None:
            break
        i, fits, fb = pruned
        notes.append(
            f"{found[i].effect} (found in round {i + 1}) is dropped: the other findings, "
            f"refitted without it, reach the error {fits[-1].error:.4g} (was {err:.4g})"
        )
        del runners[i]
        chain = _rebuilt(fits, fb, runners, problem, base, data, err0, floor)
        accepted, bases, found, _, cost, err = chain
    swapped = _in_band_image(accepted, problem, base, err, err0)
    if swapped is not None:
        i, fits, fb, folded = swapped
        f_up = float(np.exp(accepted[i].theta[0]))
        extra = len(fits) > len(accepted)
        what = (
            "above Nyquist: the image of a resonance in the band, named as the missing mode there"
            if folded
            else "above the band, whose resonance the data resolve: named as a missing mode"
        )
        notes.append(
            f"the residual compliance of round {i + 1} is a pseudo-mode at {f_up:.5g} Hz, "
            + what
            + (", and a compliance of its own is added" if extra else "")
            + f" (error {fits[-1].error:.4g}, was {err:.4g})"
        )
        if extra:
            runners.append(None)
        chain = _rebuilt(fits, fb, runners, problem, base, data, err0, floor)
    return chain


def _rebuilt(fits, bases, runners, problem, base: ModalModel, data, err0: float, floor):
    """A chain of findings from a joint fit's ``fits`` (one per finding) and ``bases``:
    (accepted, bases, findings, model, cost, error), the added modes backfitted as the
    search's rounds do."""
    found = _findings(fits, runners, bases, problem, data, err0, floor)
    current = fits[-1].model
    if any(m.effect in ("missing_mode", "upper_residual") for m in current.modes):
        polished = backfit(current, problem, d0=base.D)
        if polished is not current:
            current = polished
            found = _refresh_added(found, current, base)
    cost, err = problem.cost(current), problem.error(current)
    found[-1] = replace(found[-1], model=current, error_after=err)
    return list(fits), list(bases), found, current, cost, err


def _findings(fits, runners, bases, problem, data, err0: float, floor) -> list[Finding]:
    """One finding per fit of a chain, each with its runner-up, its base and the error it
    starts from (``err0``, then the previous fit's)."""
    errs = [err0] + [a.error for a in fits[:-1]]
    return [
        _finding(a, rn, problem, b, data, e, floor)
        for a, rn, b, e in zip(fits, runners, bases, errs)
    ]


def _in_band_image(accepted, problem, base: ModalModel, err: float, err0: float):
    """(i, fits, bases, folded): the chain with its residual compliance ``i`` (an upper
    residual) replaced by a missing mode, refitted jointly, where that reaches the chain's
    error ``err`` (within :data:`IMAGE_TIE`); else None. ``folded`` says which of two
    places the mode is named at:

    - the pseudo-mode lies above Nyquist (``folded`` True): at its image in the excited
      band (its frequency folded by a multiple of ``fs``). Sampled, a mode at ``f`` and one
      at ``|f - k fs|`` (damping scaled by the frequency ratio: the same decay rate) have
      the same discrete poles (:class:`~workbench.diagnosis.effects.AliasedMode`): the
      record shows a resonance in the band, and the finding names it there;
      :func:`_with_image` then reports the image above Nyquist beside it;
    - the pseudo-mode lies above the band but below Nyquist and the data resolve it
      (:func:`_resolved`, ``folded`` False): where it is. The record shows that mode's
      resonance, as :func:`_finding` names a missing mode fitted there (an indepgen stage
      record at 5 kHz, a mode at 1785 Hz above its band beside a delay: a compliance
      whose pseudo-mode was the mode, 1784.9 Hz damped 0.0167 for 0.0164).
    """
    fs = getattr(problem.data, "fs", None)
    for i, a in enumerate(accepted):
        if not isinstance(a.structure, UpperResidual) or a.structure.n_poles != 1:
            continue
        f, z = (float(x) for x in np.exp(a.theta))
        folded = fs is not None and f > 0.5 * fs
        if folded:
            # every mode at k fs +- f_img has the same sampled poles: a pseudo-mode folds
            # into the band from any multiple of fs (an indepgen stage record at 8 kHz, a
            # mode at 2043 Hz beside an actuator lag named as a compliance with its
            # pseudo-mode at 18 043 Hz, zeta 0.003: the same decay rate, at the floor
            # either way)
            f_img = abs(f - fs * np.round(f / fs))
            z_img = min(z * f / f_img, 0.5) if f_img > 0 else 0.5
            # a resonance the band shows: its half-power band within the excited band (an
            # indep3 planar record at 5400 Hz: modes at 8133 and 10 256 Hz left out; the
            # compliance's image at 2667 Hz, zeta 0.06, reaches past Nyquist, and the mode
            # fitted there went to 2706 Hz, above it: a flat rise at the band's top, not a
            # resonance in it)
            top = min(problem.band_hz[1], 0.5 * fs)
            if not (problem.band_hz[0] < f_img and f_img * (1 + z_img) < top):
                continue
        else:
            _, std = a.structure.report(a, problem, base)
            sf, sz = std["upper_freq_hz"], std["upper_damping"]
            if not _resolved({"freq_hz": f, "damping": z}, {"freq_hz": sf, "damping": sz}):
                continue
            f_img, z_img, top = f, z, (0.5 * fs if fs is not None else np.inf)
        parts = [MissingMode() if k == i else b.structure for k, b in enumerate(accepted)]
        thetas = [np.log([f_img, z_img]) if k == i else b.theta for k, b in enumerate(accepted)]
        chain = _image_chain(
            parts,
            thetas,
            i,
            (z_img, bool(getattr(a.structure, "late", False))),
            problem,
            base,
            (err, err0, top),
        )
        if chain is not None:
            return i, *chain, folded
    return None


def _image_chain(parts, thetas, i: int, image, problem, base: ModalModel, errs):
    """(fits, bases) of :func:`_in_band_image`'s chain ``parts`` (the mode at the image
    ``i``, ``image`` = (its damping, whether the compliance was late)), or None where it
    does not hold (:func:`_image_holds`, ``errs`` = (err, err0, top))."""
    (z_img, late), (err, err0, top) = image, errs
    try:
        fits, fb, near = _refined_if_near(parts, thetas, problem, base, err, from_start=True)
    except NUMERICAL_FAILURES:
        return None
    variants = [(fits, fb)] if near and _image_holds(fits, i, err, err0, top) else []
    if z_img <= IMAGE_DAMPING_RATIO * _structural_damping(base) and not (
        variants and _judged_within_noise(fits[-1].model, problem)
    ):
        # a structural resonance (not damped in the band as a truncated mode is,
        # :func:`_truncated_images`): the pseudo-mode's static part may hold a compliance
        # of its own, modes far above the band beside the resonance whose image it took
        # (an oracle record at 2000 Hz, a mode at 250 Hz fitted as a pseudo-mode at 1750
        # Hz, damped 0.0014: 2.7x the floor; the mode in its place without a compliance
        # 2.2x with a second folded mode): the mode and a compliance added on top, the
        # better of the two by BIC. Not where the mode alone is within noise by compare's
        # criterion, where the search would stop (the 814 Hz mode of :func:`_joint_refined`
        # beside crosstalk, 1.02x the floor: a compliance of 74 parameters took it to 0.999x)
        try:
            upper = fit(UpperResidual(late=late), problem, fits[-1].model)
            *more, near = _refined_if_near(
                parts + [upper.structure],
                [x.theta for x in fits] + [upper.theta],
                problem,
                base,
                err,
            )
        except NUMERICAL_FAILURES:
            more = None
        if (
            more is not None
            and near
            and _image_holds(more[0], i, err, err0, top, tie=1.0)
            and more[0][-1].error < err
        ):
            variants.append(more)
    if not variants:
        return None
    n = problem.n_obs
    return min(variants, key=lambda t: _bic(t[0][-1].cost, n, t[0][-1].n_params))


def _refined_if_near(parts, thetas, problem, base: ModalModel, err: float, **kw):
    """(fits, bases, near): an image chain refined to convergence (:func:`_joint_refined`,
    ``kw`` its options) where a short joint fit (:data:`PAIR_NFEV` evaluations) comes within
    :data:`IMAGE_SCREEN` of the chain's error ``err``; else the short fit's, ``near`` False.

    An image that holds is near the chain's error within those few steps (indep3 seeds 9,
    11 and 13: 1.0064x-1.0083x after 8, then held); one that does not stays far (1.30x-4.8x),
    where the refit cost seconds to no end: a casegen beam FRF, the compliance's pseudo-mode
    folded into the band beside a searched crosstalk matrix, 4 of its 7.5 s.
    """
    short, sb = _fit_joint(parts, thetas, problem, base, max_nfev=PAIR_NFEV)
    if not short[-1].error <= IMAGE_SCREEN * err:
        # a periodic record's lines may not determine the mode's residue where the inputs
        # share them (an indepgen stage record, six inputs on every line of one period, a
        # mode at 621 Hz as a compliance's image above Nyquist: from the image the lines'
        # short fit went to 666 Hz, damping 7e-6, 13x the chain's error; on the record,
        # whose transient tells the inputs apart, 621.8 Hz damped 0.0234 at 1.008x it): the
        # short fit on the whole record decides, and the chain is refined from the start
        record = getattr(problem, "time", None)
        if getattr(problem, "line_hz", None) is None or record is None:
            return short, sb, False
        try:
            on_record, _ = _fit_joint(parts, thetas, record, base, max_nfev=PAIR_NFEV)
        except NUMERICAL_FAILURES:
            return short, sb, False
        if not on_record[-1].error <= IMAGE_SCREEN * err:
            return short, sb, False
        kw = {**kw, "from_start": True}
    fits, fb = _joint_refined(parts, thetas, problem, base, **kw)
    return fits, fb, True


def _image_holds(fits, i: int, err: float, err0: float, top: float, tie=IMAGE_TIE) -> bool:
    """Whether a chain refitted with a missing mode ``i`` at a pseudo-mode's image in the
    band (:func:`_in_band_image`) reaches the chain's error ``err`` (within ``tie``), its
    errors falling at each finding (from ``err0``), with the mode below ``top`` (Hz)."""
    errs = [err0] + [x.error for x in fits]
    return (
        fits[-1].error <= tie * err
        and all(b < a for a, b in zip(errs, errs[1:]))
        and float(np.exp(fits[i].theta[0])) < top
    )


def _pruned(
    accepted, bases, problem, base: ModalModel, n: int, cost: float, err: float, err0, model=None
):
    """(i, fits, bases): the chain without its finding i, refitted jointly, where that
    earns it: the lower BIC than the whole chain (``cost``, each finding's own parameters),
    or an error (the spec's measure) no higher than the chain's ``err``; the lowest BIC of
    such. None when every finding earns its parameters. A chain whose error does not fall
    at each step (from ``err0``) is not a candidate. ``model``: the chain's final model.

    The error test stands beside BIC for closed-loop records: fitting the measured input's
    response (output error) there, a flexible term can lower the cost below the true
    model's by following the noise the controller feeds into the input (an indepgen stage
    record: a 749 Hz mode the truth lacks halves the lines' cost of the true model, and
    raises the record's error from 1.0007x to 1.027x the noise floor).
    """
    k = sum(a.theta.size + a.structure.n_linear(b) for a, b in zip(accepted, bases))
    # on a periodic record whose chain holds a mode between the lines, refitted and judged
    # on the whole record (:func:`_joint_refined`, :func:`_chain_better`): on the lines a
    # chain refitted there costs more than its lines' optimum (an indep3 beam record, a
    # suspension and a crosstalk: the suspension alone, refitted on the lines, 1.09x the
    # floor against its own 1.007x on the record)
    on_record = model is not None and _between_lines(model, problem, base)
    bic_all = _bic_on(on_record, model, cost, k, problem)
    out, out_bic = None, np.inf
    for i in range(len(accepted)):
        rest = accepted[:i] + accepted[i + 1 :]
        starts = [[a.theta for a in rest]]
        back = _mismatch_restarts(rest, bases[:i] + bases[i + 1 :], problem)
        if back is not None:
            starts.append(back)
        for thetas in starts:
            try:
                fits, fb = (_joint_refined if on_record else _fit_joint)(
                    [a.structure for a in rest], thetas, problem, base
                )
            except NUMERICAL_FAILURES:
                continue
            errs = [err0] + [f.error for f in fits]
            if not all(b < a for a, b in zip(errs, errs[1:])):
                continue
            bic = _bic_on(on_record, fits[-1].model, fits[-1].cost, fits[-1].n_params, problem)
            if (bic < bic_all or fits[-1].error <= err) and bic < out_bic:
                out, out_bic = (i, fits, fb), bic
    return out


def _mismatch_restarts(rest, bases, problem) -> list | None:
    """The thetas of ``rest`` with each modal mismatch whose mode left the band restarted at
    the model's own frequency and damping, or None (no such finding).

    A mismatch moved out of the band beside other findings may stand for what one of them
    explains (a compliance: a heavily damped mode above the band); without that finding its
    own valley, where the data show the mode, is the one to refit from (an oracle dual-stage
    record, a lag and a 226 -> 248 Hz mismatch: refitted with a compliance the mode went
    to 1005 Hz, damped 0.36, and the compliance could not be dropped from there)."""
    f_lo, f_hi = problem.band_hz
    out, moved = [], False
    for a, b in zip(rest, bases):
        theta = a.theta
        if isinstance(a.structure, ModalMismatch) and theta.size == 2:
            f = float(np.exp(theta[0]))
            if not f_lo <= f <= f_hi:
                m = b.modes[a.structure.index]
                theta = np.log([m.freq_hz, max(m.damping, 1e-3)])
                moved = True
        out.append(theta)
    return out if moved else None


def _chain_better(a: FitResult, k_a: int, b: FitResult, k_b: int, problem, base) -> bool:
    """Whether the chain ending in ``a`` (``k_a`` parameters in all) has the lower BIC than
    the one ending in ``b``: on the lines, or on the whole record where a mode either adds
    falls between a periodic record's lines (:func:`_between_lines`; its joint refit took
    it there, :func:`_joint_on_the_record`).

    An oracle record (tests/test_crosstalk_stack.py), input crosstalk taken first and a
    mode at 414 Hz damped 0.003 between lines 16 Hz apart: the two refitted jointly on the
    record reach 1.00x the noise floor, their lines' cost 1 % above the mode's added alone
    (2.98x): on the lines the joint chain lost.
    """
    on_record = _between_lines(a.model, problem, base) or _between_lines(b.model, problem, base)
    return _bic_on(on_record, a.model, a.cost, k_a, problem) < _bic_on(
        on_record, b.model, b.cost, k_b, problem
    )


def _bic_on(on_record: bool, model: ModalModel, cost: float, k: int, problem) -> float:
    """BIC of ``model`` (``k`` parameters) on a periodic record's whole record, or on the
    problem's own observations from its ``cost`` (:func:`_chain_better`, :func:`_pruned`)."""
    if on_record:
        return _bic(problem.record_cost(model), problem.time.n_obs, k)
    return _bic(cost, problem.n_obs, k)


def _falls(errs, hold=frozenset()) -> bool:
    """Whether a chain's errors (the model's, then after each finding) fall at each finding:
    a finding never raises the error, nor leaves it as it was (a delay fitted at zero on a
    joint refit, the same error to the last bit: no finding). ``hold``: the findings (1 the
    first) that repeat the previous one's error exactly, the second of a pair fitted as one
    step (:func:`_pair_chain`)."""
    return all(b < a or (k in hold and b == a) for k, (a, b) in enumerate(zip(errs, errs[1:])))


def _pair_chain(ranked, problem, base: ModalModel, n: int, err0: float):
    """The best pair of distinct effects fitted jointly, as a chain (fits, bases, alone), or
    None.

    Each effect's best single fit of ``ranked`` starts the joint fit
    (:func:`~workbench.diagnosis.fit.fit_joint`, :data:`PAIR_NFEV` evaluations); the member
    that explained more alone comes first. A crosstalk's two sides are tried apart: the side
    that explains more alone may not be the one beside the other effect (an input delay
    commutes with crosstalk on the inputs, not on the outputs); a lag's per-channel and
    common forms too. The best pair by BIC is
    refined, in the order whose first member lowers the error alone (``err0`` the model's)
    and then ``alone`` is None. Where neither member does but the pair does, the pair is one
    step: the first fit reports the pair's error, and ``alone`` = (effect, its error alone,
    the other effect, its error alone) says why. None when the pair does not lower the
    error.
    """
    singles: dict[tuple, FitResult] = {}
    for r in ranked:  # best first: each effect's best fit, a crosstalk's per side, a lag's
        # per channel and common apart (an indepgen beam record, one input lagged beside a
        # missing mode: the common lag ranked first alone, and its pair missed the floor)
        s = r.structure
        singles.setdefault((r.effect, getattr(s, "side", None), getattr(s, "common", False)), r)
    out, out_bic = None, np.inf
    effects = list(singles)
    for i, e1 in enumerate(effects):
        for e2 in effects[i + 1 :]:
            if e1[0] == e2[0]:
                continue  # a pair of distinct effects
            first, second = sorted((singles[e1], singles[e2]), key=lambda r: r.error)
            parts = [first.structure, second.structure]
            held = [_pair_held(r, problem, base) for r in (first, second)]
            searched = [
                (r.structure, r.theta) if h is None else (h, r.theta[list(h.free)])
                for h, r in zip(held, (first, second))
            ]
            try:
                fits, _ = _fit_joint(
                    [p for p, _ in searched],
                    [t for _, t in searched],
                    problem,
                    base,
                    max_nfev=PAIR_NFEV,
                )
            except NUMERICAL_FAILURES:
                continue
            # the held entries count, as they do once the pair is refined in full
            extra = first.theta.size + second.theta.size - sum(t.size for _, t in searched)
            bic = _bic(fits[-1].cost, n, fits[-1].n_params + extra)
            if bic < out_bic:
                thetas = [f.theta if h is None else h.full(f.theta) for h, f in zip(held, fits)]
                out, out_bic = (parts, thetas), bic
    if out is None:
        return None
    # the best pair refined to convergence, from where the short search left it
    fits, bases = _joint_refined(out[0], out[1], problem, base)
    if err0 > fits[0].error > fits[1].error:
        return fits, bases, None
    if not fits[1].error < err0:
        return None
    # the other order: its first member alone may lower the error
    rfits, rbases = _joint_refined(out[0][::-1], [f.theta for f in fits][::-1], problem, base)
    if err0 > rfits[0].error > rfits[1].error:
        return rfits, rbases, None
    # neither member lowers the error alone, together they do (an indepgen beam record,
    # input crosstalk 0.24 on one entry and an 8-sample delay: alone 0.132 and 0.391, from
    # 0.128; together 0.0119, the floor): one step, both findings at the pair's error (a
    # finding never raises the error; here neither can be reported before the other)
    alone = (fits[0].effect, fits[0].error, rfits[0].effect, rfits[0].error)
    return [replace(fits[0], error=fits[1].error), fits[1]], bases, alone


#: the joint fits of one :func:`diagnose` call (:func:`_fit_joint`), None outside one
_JOINT_FITS: ContextVar[dict | None] = ContextVar("_JOINT_FITS", default=None)


def _fit_joint(parts, thetas, problem, base: ModalModel, **kw):
    """:func:`~workbench.diagnosis.fit.fit_joint`, or what the same call of this
    :func:`diagnose` returned (the same parts, start values, problem and base objects).

    A rerun (:func:`_searched`) that reaches the greedy search's chain refits it as the
    greedy search did, and so do the chain's simplification and the pairs' refinement (an
    indep3 beam record without periods, a coupled suspension and a crosstalk refined to
    convergence three times, 10 s each). The memo holds the problem and base, so no other
    object takes their ids."""
    memo = _JOINT_FITS.get()
    if memo is None:
        return fit_joint(parts, thetas, problem, base, **kw)
    try:
        key = (
            tuple(parts),
            tuple(np.asarray(t, float).tobytes() for t in thetas),
            id(problem),
            id(base),
            tuple(sorted(kw.items())),
        )
        hit = memo.get(key)
    except TypeError:  # a part that does not hash: fitted afresh
        return fit_joint(parts, thetas, problem, base, **kw)
    if hit is None:
        hit = memo[key] = (problem, base, fit_joint(parts, thetas, problem, base, **kw))
    fits, bases = hit[2]
    return list(fits), list(bases)


def _pair_held(fr: FitResult, problem, base: ModalModel):
    """A pair's member ``fr`` as :func:`_pair_chain`'s short search fits it: a coupled
    suspension with its coupling held (:class:`~workbench.diagnosis.fit.Held`), else None
    (the structure itself). The coupling is what the flexible modes' lines showed its
    single fit; each pair's search by differences paid for it again (an indep3 beam record
    without periods, a coupled suspension of 27 parameters in eight pairs: 36 s of the
    rerun's pairs). The best pair is refined with it free (:func:`_joint_refined`)."""
    s = fr.structure
    return s.held(fr.theta, problem, base) if isinstance(s, CoupledSuspension) else None


def _joint_refined(parts, thetas, problem, base: ModalModel, *, from_start: bool = False):
    """``parts`` fitted jointly to convergence (:func:`~workbench.diagnosis.fit.fit_joint`),
    then on a periodic record's whole record (:func:`_joint_on_the_record`). ``from_start``:
    the record's fit starts from ``thetas`` (a start the record gave), not from the lines'
    optimum."""
    fits, bases = _fit_joint(parts, thetas, problem, base)
    return _joint_on_the_record(fits, bases, problem, base, start=thetas if from_start else None)


def _joint_on_the_record(fits, bases, problem, base: ModalModel, *, start=None):
    """A joint fit on a periodic record's lines (``fits``, ``bases``: one per part) refitted
    on the whole record where the lines cannot resolve a mode it added (as
    :func:`_on_the_record` for one effect), from its optimum or from ``start`` where given;
    the record's fit kept when its error is lower, each part's cost the lines' (the search
    compares those).

    An indepgen stage record, input crosstalk and a mode at 814 Hz damped 0.0054 between
    the lines: the pair the lines chose (the crosstalk and an upper residual whose
    pseudo-mode's image falls near the mode) ended at 4.0x the noise floor on the record;
    refitted there, 1.00x. The mode named at that image (:func:`_in_band_image`) went to
    832 Hz damped 0.083 on the lines (4.9x), no longer between them; on the record from
    the image itself, 1.02x.
    """
    if getattr(problem, "line_hz", None) is None:
        return fits, bases
    if _at_time_floor(problem.data, problem, fits[-1].model, fits[-1].error):
        # nothing for the record to resolve (an indep3 beam record, a compliance at 1.05x
        # the floor: 14 record refits, 37 of the diagnosis's 81 s, none lower)
        return fits, bases
    if start is None:
        if not _between_lines(fits[-1].model, problem, base):
            return fits, bases
        start = [f.theta for f in fits]
    # (a start the record gave: the lines may move its mode where they do not hold it
    # between them, and from the lines' optimum the record gained nothing)
    # a coupled suspension with its coupling held, as :func:`_refit_on_record` holds it
    held = [
        f.structure.held(f.theta, problem, base)
        if isinstance(f.structure, CoupledSuspension)
        else None
        for f in fits
    ]
    parts = [h or f.structure for h, f in zip(held, fits)]
    theta = [t if h is None else np.asarray(t)[list(h.free)] for h, t in zip(held, start)]
    try:
        on_record, record_bases = _fit_joint(parts, theta, problem.time, base)
    except NUMERICAL_FAILURES:
        return fits, bases
    if not on_record[-1].error < fits[-1].error:
        return fits, bases
    if any(held):  # back to the whole structures, the held entries' std the lines'
        on_record = [
            _unhold(r, h, f) if h is not None else replace(r, n_params=f.n_params)
            for r, h, f in zip(on_record, held, fits)
        ]
    costs = [problem.cost(f.model) for f in on_record]
    return [
        replace(
            f,
            cost=c,
            sigma2=c / max(problem.n_obs - f.n_params, 1),
            error=problem.error(f.model),
        )
        for f, c in zip(on_record, costs)
    ], record_bases


def _record_best(ranked, problem, model: ModalModel, accepted) -> tuple[float, FitResult] | None:
    """(BIC gain on the record, candidate): the ranked candidate that the whole record finds
    significant when the excited lines find none, or None.

    A periodic record's lines judge the steady state with the transient fitted freely; what
    only the from-rest response shows (a coupling of a slow mode's unsettled transient into
    the other outputs: an indepgen beam's subtle crosstalk, 3.1x the noise floor as given,
    1.12x with it, BIC -21 on the lines) is judged on the record (``problem.record_cost``,
    its samples the observations), each candidate's parameters as the lines fitted them;
    the one chosen is refitted on the record.
    """
    n_rec = problem.time.n_obs
    k0 = sum(a.n_params for a in accepted)
    bic0 = _bic(problem.record_cost(model), n_rec, k0)
    gains = [(bic0 - _bic(problem.record_cost(r.model), n_rec, k0 + r.n_params), r) for r in ranked]
    gain, best = max(gains, key=lambda t: t[0], default=(0.0, None))
    if not gain > 0:
        return None
    # chosen on the record, fitted there: the lines leave what only the record shows poorly
    # determined (the crosstalk above: 0.20 on the lines, at the wrong entry)
    best = _refit_on_record(best, problem, model)
    return bic0 - _bic(problem.record_cost(best.model), n_rec, k0 + best.n_params), best


def _at_time_floor(data, problem, model: ModalModel, err: float) -> bool:
    """Whether ``model`` already leaves only the record's noise (periodic time records).

    The early element test asks a port element on the model as given to lower the error
    below the linear finding's by ERROR_RATIO. When the linear finding is within
    FLOOR_RATIO of the noise floor estimated from the periods
    (:func:`~workbench.diagnosis.detect.noise_floor`, the lower of the spread and its white
    estimate), that would take an error
    ERROR_RATIO * FLOOR_RATIO = 0.94x the noise itself, which a few element parameters on
    thousands of samples cannot reach: the test (hundreds of nonlinear simulations, most of
    a stage record's diagnosis) is skipped. A record without periods has no such floor:
    there the residual must be white (:func:`~workbench.diagnosis.detect.white_residual`).
    """
    # the floor taken as white noise too: a non-periodic part of the record (friction's
    # stick-slip) inflates the periods' spread (a casegen beam with slight friction: 0.071
    # for a noise floor 8.2e-5, and a modal mismatch at 0.066 skipped the element that
    # explains the record at 1.5x the floor); white, the estimate is 0.0035
    y_model = problem.predict(model)
    if not data.period:
        # no periods, no floor: a residual that is white output noise leaves nothing for an
        # element to explain (its distortion reaches the outputs through the plant's
        # dynamics: coloured). An indep3 shaft record with a suspension spent 115 of its 163
        # s in that test; coloured sensor noise keeps the test (white fails, as it should)
        return detect.white_residual(data.y - y_model)
    floor = detect.noise_floor(data, y_model, white=True)
    return floor is not None and err <= FLOOR_RATIO * floor


def _on_the_record(fr: FitResult, problem, base) -> FitResult:
    """``fr`` refitted on the whole record when the excited lines cannot resolve what it added.

    A periodic record is fitted on its steady-state excited lines
    (:class:`PeriodicProblem`). A mode whose half-power band ``2 zeta f`` is narrower
    than the gap between the excited lines around it (or that lies below the lowest)
    falls between them: its leak into them is what the transient term absorbs, and the
    lines leave it poorly determined; the record, which also holds the start and the
    first period, does not (an indepgen beam, two suspension modes at 2.54 / 2.66 Hz,
    zeta 0.1, one excited line at 2.46 Hz and the next at 4.1 Hz: the lines' optimum
    7.2x the noise floor on the record, refitted on the record from it 1.00x). The
    refit's model replaces ``fr``'s when its record error is lower; its cost stays the
    lines' (the search compares costs on the lines).
    """
    if fr.abandoned or not _between_lines(fr.model, problem, base):
        return fr  # (a search given up far above a rival's cost: nothing to settle)
    return _refit_on_record(fr, problem, base)


def _between_lines(model: ModalModel, problem, base: ModalModel) -> bool:
    """Whether a mode ``model`` adds to ``base`` falls between a periodic record's excited
    lines (:func:`_on_the_record`): its half-power band narrower than the gap between the
    lines around it, or outside them."""
    line_hz = getattr(problem, "line_hz", None)
    if line_hz is None or line_hz.size < 2:
        return False
    added = [m for m in model.modes if not any(m is b for b in base.modes) and m.freq_hz > 0]

    def gap(f):
        i = np.searchsorted(line_hz, f)
        return np.inf if i == 0 or i == line_hz.size else line_hz[i] - line_hz[i - 1]

    return any(2 * m.damping * m.freq_hz < gap(m.freq_hz) for m in added)


def _refit_on_record(fr: FitResult, problem, base) -> FitResult:
    """``fr`` refitted on a periodic record's whole record from its lines' optimum; kept
    when its record error is lower, its cost the lines' (the search compares those).

    A coupled suspension is refitted there with its coupling to the flexible modes held
    (:class:`~workbench.diagnosis.fit.Held`): what the lines leave undetermined is the
    suspended modes between them, not the coupling the flexible modes' lines show, and
    each evaluation is a simulation (an indep3 planar record, 37 parameters by finite
    differences: 51 of the diagnosis's 56 s, to no lower error).
    """
    structure, start = fr.structure, fr.theta
    if isinstance(structure, CoupledSuspension):
        structure = structure.held(fr.theta, problem, base)
        start = fr.theta[list(structure.free)]
    on_record = fit(
        structure,
        problem.time,
        base,
        starts=[start],
        n_starts=1,
        max_nfev=fit_budget(fr.structure),
    )
    if not on_record.error < fr.error:
        return fr
    if structure is not fr.structure:  # back to the whole structure's theta
        on_record = _unhold(on_record, structure, fr)
    cost = problem.cost(on_record.model)
    return replace(
        on_record,
        cost=cost,
        sigma2=cost / max(problem.n_obs - on_record.n_params, 1),
        error=problem.error(on_record.model),
    )


def _rejected(fr: FitResult, err_before: float, problem, base) -> dict:
    """A candidate that lowers the weighted misfit but not the spec error: not a finding."""
    params = {
        k: v
        for k, v in fr.structure.report(fr, problem, base)[0].items()
        if k not in ("residue_matrix", "modes")
    }
    return {
        "effect": fr.effect,
        "error_before": float(err_before),
        "error_after": float(fr.error),
        "parameters": jsonable(params),
        "rejected": "error_after >= error_before: adding it does not lower the error",
    }


def _verdict(model: ModalModel, data):
    """compare's judgement of ``model`` (its own criterion, :mod:`workbench.validate.compare`)."""
    from workbench.validate.compare import compare

    return compare(model.to_lti(), data)


#: failing bands listed in ``Diagnosis.remaining``
N_REMAINING_BANDS = 6


def _remaining(model: ModalModel, data) -> dict | None:
    """What compare says is left: within noise, or the worst failing bands named.

    None when compare has no noise reference (FRF without G_var, non-periodic time
    record): it then declares no band failing, so its silence proves nothing.
    """
    if isinstance(data, FrfData) and (data.G_var is None or not np.any(data.G_var > 0)):
        return None
    if isinstance(data, TimeData) and not data.period:
        return None
    cmp = _verdict(model, data)
    if cmp.z_mean is None:
        return None
    bands = sorted(cmp.failing_bands, key=lambda b: -b.median * b.n_lines)
    out: dict[str, Any] = {
        "within_noise": bool(cmp.within_noise),
        "z_mean": float(cmp.z_mean),
        "z_expected": cmp.z_expected,
        "n_failing_bands": len(bands),
        "failing_bands": [b.as_dict() for b in bands[:N_REMAINING_BANDS]],
        "criterion": cmp.criterion,
    }
    if cmp.within_noise:
        out["explanation"] = (
            f"compare finds the final model within noise (z_mean {cmp.z_mean:.3g}, no failing band)"
        )
    else:
        where = []
        for b in bands[:3]:
            ch = _channel_words(data, b.output, b.input)
            where.append(f"{ch} {b.f_lo_hz:.4g}-{b.f_hi_hz:.4g} Hz (median z {b.median:.3g})")
        out["explanation"] = (
            f"not explained by any effect found: compare still fails in {len(bands)} band(s) "
            f"(z_mean {cmp.z_mean:.3g}, {_z_right(cmp)} when the model is right), worst "
            + "; ".join(where)
        )
    return out


def _z_right(cmp) -> str:
    """What z_mean is for a right model, in words (F(2, d) has mean d / (d - 2), not 1)."""
    return "about 1" if cmp.z_expected is None else f"about {cmp.z_expected:.3g}"


def _sigma(problem, model_after, fr: FitResult | None, freq, G_after) -> np.ndarray:
    if problem.kind == "frf":
        if problem.has_var:
            return np.sqrt(np.maximum(problem.data.G_var, 1e-300))
        s2 = fr.sigma2 if fr is not None else 1.0
        return np.sqrt(2 * s2) / problem.w
    # time data: a relative noise level per line from the residual error
    err = problem.error(model_after)
    norm = np.linalg.norm(G_after, axis=(1, 2))[:, None, None]
    return np.maximum(0.3 * err * norm / math.sqrt(G_after.shape[1] * G_after.shape[2]), 1e-300)


def _finding(fr: FitResult, runner, problem, base, data, err_before, floor) -> Finding:
    params, params_std = fr.structure.report(fr, problem, base)
    effect = fr.effect
    above = effect == "missing_mode" and _above_band(params, problem)
    resolved = above and _resolved(params, params_std)
    if above and not resolved:
        # a "mode" whose resonance lies above the measured band shows only its static part:
        # physically that is the residual compliance of truncated high-frequency modes
        effect = "residual_compliance"
        f0 = np.array([1e-3 * problem.band_hz[0]])
        static = (fr.model.core_frf(f0) - base.core_frf(f0))[0].real
        params = {
            "matrix": static.tolist(),
            "freq_hz_fitted": params["freq_hz"],
            "damping_fitted": params["damping"],
        }
        params_std = {}
    if problem.kind == "frf":
        freq = problem.freq
    else:
        freq = np.geomspace(*problem.band_hz, 400)
    G_before = base.frf(freq)
    G_after = fr.model.frf(freq)
    where = detect.where_it_shows(
        freq, G_after - G_before, _sigma(problem, fr.model, fr, freq, G_after)
    )
    ins, outs = where.inputs, where.outputs
    if getattr(fr.structure, "common", False):  # one lag on every channel, however fast
        ins = tuple(range(base.n_u))
    elif fr.effect == "actuator_dynamics":
        ins = tuple(
            j
            for j, c in enumerate(params["cutoff_hz"])
            if c is not None and c < 10 * problem.band_hz[1]
        )
    if fr.effect == "sensor_dynamics":
        outs = tuple(
            i
            for i, c in enumerate(params["cutoff_hz"])
            if c is not None and c < 10 * problem.band_hz[1]
        )
    ev: dict[str, Any] = dict(
        parameters=params,
        band_hz=where.band_hz,
        inputs=ins,
        outputs=outs,
        n_u=base.n_u,
        n_y=base.n_y,
        error_before=err_before,
        error_after=fr.error,
        noise_floor=floor,
        kind=problem.kind,
        alternative=(runner.effect, runner.error) if runner is not None else None,
        fs=getattr(data, "fs", None),
        late=bool(getattr(fr.structure, "late", False)),
    )
    if fr.effect == "time_delay" and problem.kind == "frf":
        lo, hi = where.band_hz
        sel = (freq >= lo) & (freq <= hi)
        w = np.abs(G_before) / _sigma(problem, fr.model, fr, freq, G_after)
        slope, mag_db, n_ch = detect.phase_slope(
            freq[sel], problem.data.G[sel], G_before[sel], weight=w[sel]
        )
        ev.update(phase_slope_deg_per_hz=slope, magnitude_db=mag_db, n_channels_used=n_ch)
    if effect == "missing_mode":
        S = np.linalg.svd(np.asarray(params["residue_matrix"]), compute_uv=False)
        ev["rank_one_ratio"] = float(S[1] / S[0]) if S.size > 1 and S[0] > 0 else 0.0
    if effect != fr.effect:
        ev["alternative"] = ("missing_mode", fr.error)
    explanation = explain(effect, ev)
    if resolved:
        explanation += (
            f" It lies above the excited band (top {problem.band_hz[1]:.4g} Hz), yet the data "
            f"resolve its resonance (frequency +- {params_std['freq_hz']:.3g} Hz, damping +- "
            f"{params_std['damping']:.2g}): a mode, not residual compliance."
        )
    explanation += damping_floor_note(params, params_std)
    undetermined = [k for k, v in params_std.items() if _has_nan(v)]
    if undetermined:
        explanation += (
            f" The data do not determine {', '.join(undetermined)}: no standard deviation is "
            "given for them."
        )
    if fr.status != "ok":
        explanation += f" The fit did not converge ({fr.status}): the parameters are approximate."
    return Finding(
        effect=effect,
        inputs=tuple(ins),
        outputs=tuple(outs),
        band_hz=where.band_hz,
        parameters=params,
        parameters_std=params_std,
        error_after=fr.error,
        explanation=explanation,
        model=fr.model,
        fit_status=fr.status,
    )


def _refresh_added(found: list[Finding], model: ModalModel, base: ModalModel) -> list[Finding]:
    """Parameters of the added modes and the residual read back from the refined ``model``.

    After :func:`~workbench.diagnosis.effects.backfit` / ``polish`` the poles and
    residues of the added modes moved a little: the findings report what the final model
    holds (their standard deviations stay those of the joint fit).
    """
    added = [m for m in model.modes if m.effect == "missing_mode"]
    upper = [m for m in model.modes if m.effect == "upper_residual"]
    out = []
    for f in found:
        p = dict(f.parameters)
        if f.effect == "missing_mode" and added and "freq_hz" in p:
            m = _nearest(added, p["freq_hz"])
            N0 = m.numerator()[0]
            b, c = _rank_one(N0)
            p.update(freq_hz=m.freq_hz, damping=m.damping, b=b, c=c, residue_matrix=N0.tolist())
        elif f.effect == "residual_compliance" and added and "freq_hz_fitted" in p:
            # a mode above the band named by its static part (:func:`_finding`)
            m = _nearest(added, p["freq_hz_fitted"])
            p.update(matrix=_static_part(m).tolist(), freq_hz_fitted=m.freq_hz)
            p.update(damping_fitted=m.damping)
        elif f.effect == "residual_compliance" and upper and "upper_freq_hz" in p:
            # one pseudo-mode, or (a list) the two of a two-pole upper residual
            ms = upper if isinstance(p["upper_freq_hz"], list) else upper[:1]
            late = [x for x in model.modes if x.effect == "late_compliance"]
            static = model.D - base.D + sum(_static_part(x) for x in ms + late)
            fq, zq = [m.freq_hz for m in ms], [m.damping for m in ms]
            one = not isinstance(p["upper_freq_hz"], list)
            p.update(
                matrix=static.tolist(),
                upper_freq_hz=fq[0] if one else fq,
                upper_damping=zq[0] if one else zq,
            )
        out.append(replace(f, parameters=p))
    return out


def _coupling_read_back(found: list[Finding], model: ModalModel, base: ModalModel) -> list:
    """A crosstalk finding's matrix read back from the final ``model``: the coupling it adds
    to ``base`` on its side (where one crosstalk finding holds that side).

    A crosstalk found first is refitted with what the later rounds add (their terms solved
    seeing it: :func:`~workbench.diagnosis.fit._recoupled`); its own round's matrix was
    solved on a model that lacked them (a scipy-ZOH oracle, output crosstalk 8 % / -5 %
    beside a compliance: 7.90 % / -5.09 % in its round, 7.999 % / -5.010 % in the final
    model). Its standard deviations stay its fit's.
    """
    out = []
    for f in found:
        side = f.parameters.get("side") if f.effect == "crosstalk" else None
        alone = (
            side is not None
            and [g.parameters.get("side") for g in found if g.effect == "crosstalk"].count(side)
            == 1
        )
        T = coupling_added(model, base, "out" if side == "outputs" else "in") if alone else None
        if T is not None:
            f = replace(f, parameters={**f.parameters, "matrix": T.tolist()})
        out.append(f)
    return out


def _merge_compliance(found: list[Finding]) -> list[Finding]:
    """One residual_compliance finding: the static parts of modes above the band add up (and
    the truncated modes the record shows above Nyquist, :func:`_truncated_images`, list)."""
    rc = [f for f in found if f.effect == "residual_compliance"]
    if len(rc) < 2:
        return found
    M = sum(np.asarray(f.parameters["matrix"], float) for f in rc)
    params: dict[str, Any] = {"matrix": M.tolist()}
    # the pseudo-mode of the first compliance that has one (the others are static parts)
    upper = next((f.parameters for f in rc if "upper_freq_hz" in f.parameters), {})
    params.update({k: upper[k] for k in ("upper_freq_hz", "upper_damping") if k in upper})
    above = [m for f in rc for m in f.parameters.get("modes_above_nyquist", [])]
    if above:
        params["modes_above_nyquist"] = above
    last = rc[-1]
    explanation = (
        rc[0].explanation
        + "".join(f.explanation for f in rc[1:] if f.parameters.get("modes_above_nyquist"))
        + f" With its {len(rc) - 1} other part(s), the error falls to {last.error_after:.4g}."
    )
    merged = Finding(
        effect="residual_compliance",
        inputs=tuple(sorted(set().union(*(f.inputs for f in rc)))),
        outputs=tuple(sorted(set().union(*(f.outputs for f in rc)))),
        band_hz=(min(f.band_hz[0] for f in rc), max(f.band_hz[1] for f in rc)),
        parameters=params,
        parameters_std={},
        error_after=last.error_after,
        explanation=explanation,
        model=last.model,
    )
    out, done = [], False
    for f in found:
        if f.effect != "residual_compliance":
            out.append(f)
        elif not done:
            out.append(merged)
            done = True
    return out


def _nearest(modes, freq_hz: float):
    """The mode of ``modes`` nearest ``freq_hz`` on a log scale: an added mode a finding
    names, after later rounds moved it."""
    return min(modes, key=lambda m: abs(math.log(m.freq_hz / freq_hz)))


def _static_part(mode) -> np.ndarray:
    """A mode's static compliance ``N0 / w^2`` (n_y, n_u)."""
    return mode.numerator()[0] / mode.omega**2


def _truncated_images(
    found: list[Finding], model: ModalModel, base: ModalModel, problem
) -> list[Finding]:
    """The missing modes of a sampled record that are truncated modes above Nyquist, named
    residual compliance where the record shows that too.

    Sampled, a resonance in the band and its image above Nyquist fit alike
    (:func:`_with_image`); the damping tells them apart physically. A truncated mode at
    ``f_up`` folds to ``f = |f_up - k fs|`` with its damping scaled by ``f_up / f``: an
    indep3 beam record at 4800 Hz showed modes at 4307 and 5088 Hz (damping 0.017, 0.006)
    as resonances at 493 and 288 Hz damped 0.14 and 0.075, named missing modes beside the
    compliance, and the compliance's matrix lost their static parts (88 % off; 1.6 % with
    them). A missing mode is taken for a truncated one where its damping in the band
    exceeds :data:`IMAGE_DAMPING_RATIO` times the most damped flexible mode of ``base``
    (the model as given; :data:`Z_STRUCTURAL` without one) and its image's does not: damped
    like the structure's modes above Nyquist, unlike them in the band. Only the missing
    modes next to a residual compliance finding (no other effect between them: the merged
    finding has one error after it) are taken. Their static parts (the added mode's
    ``N0 / w^2``, what the sampled record shows at DC either way) join the compliance's
    matrix (:func:`_merge_compliance`); ``modes_above_nyquist`` lists them. Such modes found
    after other missing modes are first moved next to the compliance (:func:`_folded_first`,
    its errors from ``problem``).
    """
    z_ref = _structural_damping(base)
    added = [m for m in model.modes if m.effect == "missing_mode"]
    if not added:
        return found
    folded = [
        f.effect == "missing_mode"
        and "image_damping" in f.parameters
        and f.parameters["damping"] > IMAGE_DAMPING_RATIO * z_ref >= _image_damping(f.parameters)
        for f in found
    ]
    found, folded = _folded_first(found, folded, model, problem)
    # runs of findings next to each other that are compliance or such modes, with a compliance
    keep: list[bool] = []
    runs = itertools.groupby(
        zip(found, folded), key=lambda t: t[1] or t[0].effect == "residual_compliance"
    )
    for in_run, group in runs:
        group = list(group)
        with_rc = in_run and any(f.effect == "residual_compliance" for f, _ in group)
        keep += [with_rc and fold for _, fold in group]
    out = []
    for f, take in zip(found, keep):
        if take:
            p = f.parameters
            mode = _nearest(added, p["freq_hz"])
            static = _static_part(mode)
            image = {
                "freq_hz": p["image_freq_hz"],
                "damping": _image_damping(p),
                "band_freq_hz": p["freq_hz"],
                "band_damping": p["damping"],
            }
            why = (
                f" The resonance at {p['freq_hz']:.4g} Hz (damping {p['damping']:.3g}) is a "
                f"truncated mode above Nyquist: in the band it is damped more than "
                f"{IMAGE_DAMPING_RATIO:g}x the model's most damped mode ({z_ref:.3g}), its image "
                f"at {p['image_freq_hz']:.5g} Hz (damping {_image_damping(p):.3g}) is not; its "
                "static part is in the matrix."
            )
            f = replace(
                f,
                effect="residual_compliance",
                parameters={"matrix": static.tolist(), "modes_above_nyquist": [image]},
                parameters_std={},
                explanation=why,
            )
        out.append(f)
    return out


def _image_damping(p: dict) -> float:
    """The damping of a missing mode's image above Nyquist with the resonance's own decay
    rate (its sampled poles): ``z f / f_img``.

    Not the image's fitted damping (``image_damping``), which only has to tie the
    resonance's error: a broad resonance leaves it loose (an oracle record, a mode at 4300
    Hz damped 0.03 beside a compliance at 2000 Hz: found at 334.6 Hz damped 0.219, its image
    at 2335 Hz fitted with 0.042 where the resonance's poles give 0.031).
    """
    return p["damping"] * p["freq_hz"] / p["image_freq_hz"]


def _pole_rings_in_band(fr: FitResult, problem, base: ModalModel) -> bool:
    """Whether ``fr`` is a two-pole upper residual on a sampled record with a pole whose
    image (folded by a multiple of ``fs``) is a resonance in the excited band: a mode of the
    record, which the search names as one from a one-pole compliance
    (:func:`_in_band_image`, which does not split two poles). Modes at 1500 and 2600 Hz
    sampled at 2 kHz, ringing at 500 and 600 Hz: the two poles took both images as one
    compliance, where each is a missing mode."""
    s = fr.structure
    if not (isinstance(s, UpperResidual) and s.n_poles > 1):
        return False
    return _rings_in_band(fr.theta, problem)


def _two_poles(fr: FitResult) -> bool:
    """Whether ``fr`` is a two-pole upper residual: a refinement kept only where it leaves
    the noise (:func:`_leaves_the_noise`). Where it does not,
    its lower cost on the lines may hold a neighbouring mode's misfit: the walkthrough
    stage FRF, delay and a 1320 Hz mode found, the two poles (1608 and 2374 Hz, damped
    0.38 and 0.23) first by BIC in the third round, and compare failing at 1302-1350 Hz
    after them, where one pole ends within noise."""
    return isinstance(fr.structure, UpperResidual) and fr.structure.n_poles > 1


def _rings_in_band(theta: np.ndarray, problem) -> bool:
    """Whether a pole of ``theta`` ((ln f, ln z) per pole) folds into a sampled record's
    excited band as a resonance there (:func:`_pole_rings_in_band`)."""
    fs = getattr(problem.data, "fs", None)
    if not (problem.kind == "time" and fs):
        return False
    top = min(problem.band_hz[1], 0.5 * fs)
    for f, z in np.exp(theta).reshape(-1, 2):
        f_img = abs(f - fs * np.round(f / fs))
        z_img = min(z * f / f_img, 0.5) if f_img > 0 else 0.5
        if problem.band_hz[0] < f_img and f_img * (1 + z_img) < top:
            return True
    return False


def _structural_damping(base: ModalModel) -> float:
    """The damping ratio of the model's most damped flexible mode (:data:`Z_STRUCTURAL`
    where it has none): what a structural mode of it may have."""
    return max(
        (m.damping for m in base.modes if m.kind == "flexible" and m.freq_hz > 0),
        default=Z_STRUCTURAL,
    )


def _folded_first(found: list[Finding], folded: list[bool], model: ModalModel, problem):
    """(found, folded) with the folded modes after a residual compliance moved next to it,
    where only missing modes follow the compliance and the errors fall in the new order.

    The search adds modes in the order they lower the error: a resonance the record shows
    may come between the compliance and a truncated mode folded into the band (an indep3
    beam record at 6300 Hz: compliance, a mode at 2313 Hz, then a truncated mode folded to
    2545 Hz, damped 0.035 there; its static part left out, the matrix 29.9 % off, 22.4 %
    with it). The errors after each finding in the new order are
    those of the final ``model`` without the modes of the findings after it (no refit), and
    each finding's explanation states them.
    """
    rc = [k for k, f in enumerate(found) if f.effect == "residual_compliance"]
    if not rc:
        return found, folded
    i = rc[-1]
    tail = list(range(i + 1, len(found)))
    fold = [k for k in tail if folded[k]]
    kept = [k for k in tail if not folded[k]]
    if (
        not fold
        or not kept
        or max(fold) < min(kept)
        or not all(
            found[k].effect == "missing_mode" and "freq_hz" in found[k].parameters for k in tail
        )
    ):
        return found, folded
    added = [m for m in model.modes if m.effect == "missing_mode"]
    mode_of = {k: _nearest(added, found[k].parameters["freq_hz"]) for k in tail}
    if len({id(m) for m in mode_of.values()}) < len(tail):
        return found, folded
    order = fold + kept
    models, errs = [], []
    for j in range(len(order) + 1):
        drop = {id(mode_of[k]) for k in order[j:]}
        m = replace(model, modes=tuple(x for x in model.modes if id(x) not in drop))
        models.append(m)
        errs.append(problem.error(m))
    if not _falls(errs):
        return found, folded
    moved = [
        _restated(found[k], before, after, m)
        for k, before, after, m in zip(order, errs, errs[1:], models[1:])
    ]
    return found[: i + 1] + moved, folded[: i + 1] + [folded[k] for k in order]


def _restated(f: Finding, before: float, after: float, model: ModalModel) -> Finding:
    """``f`` with the errors before and after it (and the model after it) replaced, in its
    explanation too (:func:`~workbench.diagnosis.explain.explain` states them once)."""
    text = _FALLS.sub(f"the error falls from {before:.4g} to {after:.4g}", f.explanation, count=1)
    return replace(f, error_after=after, model=model, explanation=text)


#: the errors a finding's explanation states (:func:`~workbench.diagnosis.explain.explain`)
_NUMBER = r"(?:\d+(?:\.\d+)?(?:e[-+]\d+)?|inf|nan)"
_FALLS = re.compile(rf"the error falls from {_NUMBER} to {_NUMBER}")
#: the runner-up's error an explanation states (:func:`~workbench.diagnosis.explain.explain`)
_RUNNER_UP = re.compile(rf"(only reaches |fits as closely \()({_NUMBER})")
#: ... and the 'none' finding's best candidate (:func:`_none_finding`)
_RUNNER_UP_NONE = re.compile(rf"would only reach {_NUMBER}")


def _with_image(finding: Finding, model: ModalModel, base: ModalModel, problem) -> Finding:
    """A missing mode on a sampled record, with its image above Nyquist where that fits as well.

    The mode at ``f`` is taken out of ``model`` and an :class:`AliasedMode` fitted from
    one of its images (:func:`_image`). When that reaches the error of the mode in the band
    (within ``IMAGE_TIE``), the record cannot tell the two apart: the finding keeps its
    rank (the resonance the data show) and reports the image (``image_freq_hz``,
    ``image_damping``, ``image_error_after``) with a sentence saying so. Images lighter than
    ``IMAGE_MIN_DAMPING`` are not tried (no structure that light).
    """
    if finding.effect != "missing_mode":
        return finding
    f0 = finding.parameters["freq_hz"]
    added = [m for m in model.modes if m.effect == "missing_mode"]
    if not added:
        return finding
    mode = _nearest(added, f0)
    fs = problem.data.fs
    if not 0.01 * fs < mode.freq_hz < 0.5 * fs:
        return finding  # above Nyquist it is itself an image; near 0 its image would be at fs
    fold, side, f_img, z_img = _image(mode, fs, IMAGE_REACH * problem.band_hz[1], base)
    if z_img < IMAGE_MIN_DAMPING:
        return finding
    rest = replace(model, modes=tuple(m for m in model.modes if m is not mode))
    fr = fit(
        AliasedMode(fold=fold, side=side),
        problem,
        rest,
        starts=[np.log([f_img, z_img])],
        n_starts=1,
    )
    if not fr.error <= IMAGE_TIE * problem.error(model):
        return finding
    f_fit, z_fit = (float(x) for x in np.exp(fr.theta))
    p = dict(finding.parameters)
    p.update(image_freq_hz=f_fit, image_damping=z_fit, image_error_after=float(fr.error))
    note = (
        f" Sampled at {fs:g} Hz, this resonance cannot be told from its image: a mode at "
        f"{f_fit:.5g} Hz above Nyquist (damping {z_fit:.3g}) fits the record as well (error "
        f"{fr.error:.4g}), as would one near any k fs +- {mode.freq_hz:.4g} Hz (the same "
        f"sampled poles). If the structure has no mode near {mode.freq_hz:.4g} Hz, it is a "
        "truncated mode above Nyquist (residual compliance with its dynamics); a record "
        "sampled faster tells them apart."
    )
    return replace(finding, parameters=p, explanation=finding.explanation + note)


def _image(mode, fs: float, f_max: float, base: ModalModel) -> tuple[int, int, float, float]:
    """(fold, side, f_img, z_img): the image ``fold fs + side f`` of a mode at ``f`` in the
    band, damped ``z f / f_img``, that a truncated mode of the structure would be.

    Every ``k fs -+ f`` has the mode's sampled poles. The lowest whose damping is a
    structural mode's (:data:`IMAGE_DAMPING_RATIO` times the model's most damped, as
    :func:`_truncated_images` asks) up to ``f_max``; ``fs - f`` where none is. A mode far
    above Nyquist folds from any multiple of ``fs`` (an indep3 planar record at 7700 Hz: a
    mode at 21 833 Hz, damping 0.02, rang at 1293 Hz damped 0.34; its image at ``fs - f``
    is damped 0.069, more than 2x the model's 0.023, and its static part, 80 % of the
    compliance's, was left out of it).
    """
    f, z = mode.freq_hz, mode.damping
    z_ref = IMAGE_DAMPING_RATIO * _structural_damping(base)
    images = [
        (k, side, k * fs + side * f)
        for k in range(1, int(f_max / fs) + 2)
        for side in (-1, 1)
        if k * fs + side * f <= f_max or (k, side) == (1, -1)
    ]
    for k, side, f_img in images:
        z_img = z * f / f_img
        if IMAGE_MIN_DAMPING <= z_img <= z_ref:
            return k, side, f_img, z_img
    return 1, -1, fs - f, z * f / (fs - f)


def _distorted(nl) -> bool:
    """Whether :func:`detect.nonlinearity`'s result ``nl`` (or None) shows distortion on
    the unexcited lines carrying a measurable share of the output (:data:`NL_F`; strong but
    tiny distortion, a slight clipping at F 89 and level 5e-5, is not)."""
    return nl is not None and nl.f_stat > NL_F and nl.level > 1e-4


#: a fitted log-frequency this close to an end of its range is on it
BOUND_TOL = 1e-4


def _on_frequency_bound(fr: FitResult, problem, base: ModalModel) -> bool:
    """Whether ``fr`` is a missing mode fitted on an end of the frequency range searched
    whose resonance reaches into the excited band.

    The data do not place such a resonance: the fit went as far as it was let, standing in
    for what lies beyond (an indep3 planar record at 7600 Hz, its compliance's second
    truncated mode: a "mode" at 1.3x the band's top, damped 0.5, was named before the
    image of the first, and the compliance's matrix came out 1.7x off). One whose half-power
    band lies above the excited band is a static part there (named residual compliance,
    :func:`_finding`; an indep3 beam record's truncated modes just above the band)."""
    if type(fr.structure) is not MissingMode:
        return False
    lo, hi = fr.structure.bounds(problem, base)
    f, z = np.exp(fr.theta[:2])
    return not lo[0] + BOUND_TOL < fr.theta[0] < hi[0] - BOUND_TOL and not _above_band(
        {"freq_hz": f, "damping": z}, problem
    )


def _above_band(params: dict, problem) -> bool:
    """The fitted resonance and its half-power band lie above the data's top frequency."""
    f, z = params.get("freq_hz"), params.get("damping")
    if f is None or z is None:
        return False
    return f * (1 - min(z, 0.5)) > problem.band_hz[1]


#: a mode fitted above the excited band stays a mode when the data resolve its resonance:
#: the standard deviation of its frequency under this fraction of its half-power half-width
#: (z f), that of its damping under this fraction of z
RESOLVED = 0.1


def _resolved(params: dict, params_std: dict) -> bool:
    """The fitted mode's resonance is resolved by the data (:data:`RESOLVED`).

    A mode above the band that the record shows as a static term only fits with its
    frequency and damping undetermined (truncated modes: held-out indep3 residual
    compliance records: frequency +- 0.7-3.8 %, or damping +- 37 % or undetermined); one whose
    transient rings in the record (a beam mode at 778 Hz above a band that ends at 612
    Hz, on a record started at rest) is pinned (+- 0.01 %, damping +- 1.2 %): named as
    residual compliance it lost its frequency and damping.
    """
    f, z = params.get("freq_hz"), params.get("damping")
    sf, sz = params_std.get("freq_hz"), params_std.get("damping")
    if any(v is None or not np.isfinite(v) for v in (f, z, sf, sz)) or z <= 0:
        return False
    return sf < RESOLVED * z * f and sz < RESOLVED * z


def _channel_words(data, output: int, input_: int | None) -> str:
    """A failing band's channel by the record's names ("y2", "y1/u0"; indices past them as
    numbers)."""
    names_out, names_in = data.output_names, data.input_names
    ch = names_out[output] if output < len(names_out) else str(output)
    if input_ is not None:
        ch += "/" + (names_in[input_] if input_ < len(names_in) else str(input_))
    return ch


def _compare_left_words(found: list, err: float, left: dict, data) -> str:
    """Why an element is tried where the linear findings ``found`` reach ``err`` and
    compare still fails on their model (``left``, :func:`_remaining`'s dict): its words."""
    band = left["failing_bands"][0]
    ch = _channel_words(data, band["output"], band.get("input"))
    lo, hi = band["band_hz"]
    effects = ", ".join(dict.fromkeys(f.effect for f in found)) or "no linear finding"
    return (
        f"the linear findings ({effects}) reach the error {err:.4g}, yet compare still fails "
        f"on their model in {left['n_failing_bands']} band(s), worst {ch} {lo:.4g}-{hi:.4g} Hz "
        f"(median z {band['median']:.3g})"
    )


def _misfit_evidence(err: float, f_stat: float | None, band_hz) -> detect.NonlinearityEvidence:
    """Evidence for an element from a misfit no linear effect removed (no distortion lines):
    its level the error squared (at most 1), ``f_stat`` the period-synchronous misfit (0
    when unknown)."""
    return detect.NonlinearityEvidence(
        level=float(min(err**2, 1.0)),
        f_stat=float(f_stat) if f_stat is not None else 0.0,
        n_lines=0,
        band_hz=band_hz,
    )


def _unrepeated_evidence(data, y_model, spread_floor: float, nl) -> detect.NonlinearityEvidence:
    """Evidence of a response that does not repeat (:func:`_unrepeated_periods`): its level
    the share of the output power that the periods' spread holds beyond the noise (the
    spread's power less its white estimate's; both relative to the output, squared), its
    ``f_stat`` the spread's power over the white estimate's; the unexcited lines, band and
    stationarity of the detector's ``nl`` (which tested them and found nothing periodic)."""
    white = detect.noise_floor(data, y_model, white=True)
    return replace(
        nl,
        level=float(min(max(spread_floor**2 - white**2, 0.0), 1.0)),
        f_stat=float(spread_floor**2 / max(white**2, 1e-300)),
        unrepeated=True,
    )


def _nonlinearity_finding(
    nl,
    data,
    err,
    linear: list,
    cur_err: float,
    *,
    direct: bool,
    only_given: bool = False,
    needed: float | None = None,
    mode_hz: float | None = None,
    unrepeated: bool = False,
    drift: bool = False,
    why: str | None = None,
):
    """The nonlinearity finding with its fitted port element, or (None, alternative).

    ``err`` is the error of the model as given, ``cur_err`` that of the final linear
    model ``linear[0]``. ``linear``: the linear models (ModalModel) the element may sit
    on (:func:`_fit_element` chooses). Without ports (a square model, whose outputs are
    collocated with the inputs, or a sensor collocated with an input) only a saturation of
    the inputs can be fitted; when it does not lower the error (or the data are an FRF),
    the finding carries the distortion level only and the error of the linear model,
    ``cur_err`` (it adds nothing to that model, so it cannot lower the error), and only
    ``direct`` evidence (distortion on unexcited lines) makes it a finding: a residual
    the linear search merely left is what any linear effect it missed leaves too.

    With an element, ``parameters["level"]`` is the share of the output power the element
    adds to the linear model's response (the spec's level, :attr:`ElementFit.level`) and
    ``parameters["evidence_level"]`` the detector's estimate (``nl.level``); without one,
    ``level`` is the detector's estimate.

    ``only_given``: only a finding on the model as given (``linear[-1]``) is wanted; the
    element is fitted on the other linear models only when it is one there (the same
    answer, one element fit instead of two when it is not).

    ``needed``: the error the element must go below (default: ``cur_err`` with ``direct``
    evidence of distortion, ``ERROR_RATIO * cur_err`` without, or with evidence that the
    periods do not repeat). ``mode_hz``: only a cubic spring on the
    mode of this frequency (Hz) is fitted (:func:`_fit_element`).

    ``unrepeated``: the record's periods do not repeat (:func:`_unrepeated_periods`). With
    ``direct`` evidence that is a finding even when no element lowers the error: a response
    sensitive to its own state (a Duffing oscillator driven into chaos: an indepgen beam
    record, a 1e-12 relative change of the input moved the truth's own output by 30 % after
    six periods) is followed sample by sample by no simulation model, the truth's included.

    ``drift``: the from-rest error is above DRIFT_RATIO times the noise floor the record's
    periods show (:func:`_fit_element`'s ``drift``).

    ``why``: the evidence in words, leading the explanation in place of the detector's
    numbers (:func:`_compare_left_words`).
    """
    params: dict[str, Any] = {"level": nl.level, "f_stat": nl.f_stat}
    if nl.unrepeated:
        params["periods_repeat"] = False
    ins, outs = tuple(range(data.n_u)), tuple(range(data.n_y))
    error_after, model, note = cur_err, None, ""
    # distortion on unexcited lines is direct evidence: the element must only lower the
    # error; a residual that is merely not explained needs the element to explain it
    if needed is None:
        # (a response that does not repeat is evidence on its own, but an element is attached
        # to it only where it explains the record as a finding must, not where it trims it)
        needed = cur_err if direct and not nl.unrepeated else ERROR_RATIO * cur_err
    fitted = (
        _fit_element(
            data,
            linear,
            stop_above=needed if only_given else None,
            band_hz=nl.band_hz,
            mode_hz=mode_hz,
            screen=needed,
            errors=[cur_err] + ([err] if len(linear) > 1 else []),
            drift=drift,
        )
        if isinstance(data, TimeData)
        else None
    )
    portless = False  # only an input saturation was tried (no port located)
    tried_element = None  # (element, error) fitted without lowering the error
    if fitted is not None:
        ef, _, pair = fitted
        on_mode = "mode" in ef.parameters  # a spring on a mode's coordinate needs no port
        screened = bool(ef.parameters.get("screened"))  # no hypothesis passed the screen
        portless = pair is None and data.n_y != data.n_u and not on_mode
        if screened:  # (its pair is None: none fitted)
            portless = bool(ef.parameters["portless"])
        if not ef.error_after < needed:
            tried = dict(params, element=ef.element, ports=list(ef.ports), **ef.parameters)
            tried["element_errors"] = ef.candidates
            if pair is not None:
                tried["collocated"] = list(pair)
            alt = {
                "effect": "nonlinearity",
                "error_before": float(cur_err),
                "error_after": float(ef.error_after),
                "parameters": jsonable(tried),
                "rejected": (
                    "no port nonlinearity (Coulomb friction, cubic spring, saturation) in the "
                    "simulation model lowers the error: the misfit is linear"
                ),
            }
            if portless:
                alt["rejected"] = (
                    "no port could be located for friction or a spring (no sensor collocated "
                    "with an input), and a saturation of the inputs, which needs none, does not "
                    "lower the error: not evidence of a nonlinearity"
                )
            if screened:
                why = (
                    f"to first order (its signature at level zero reaches "
                    f"{ef.parameters['first_order_error']:.4g} from {ef.error_before:.4g} "
                    "simulated from rest), or the record's start, which a simulation from "
                    "rest does not have, is most of that error"
                )
                alt["rejected"] = (
                    "no port nonlinearity (Coulomb friction, cubic spring, saturation) was "
                    f"fitted: none lowers the error towards {needed:.4g} {why}: the misfit "
                    "is linear"
                )
                if portless:
                    alt["rejected"] = (
                        "no port could be located for friction or a spring (no sensor "
                        "collocated with an input), and a saturation of the inputs, which "
                        f"needs none, does not lower the error towards {needed:.4g} {why}: "
                        "not evidence of a nonlinearity"
                    )
            if not ((portless or unrepeated) and direct):
                return None, alt
            # distortion on unexcited lines is evidence on its own: the finding without an
            # element, as when no element can be fitted at all, or when the response does not
            # repeat (no simulation from the recorded input follows it sample by sample)
            fitted = None
            tried_element = (ef.element, float(ef.error_after))
    if fitted is not None:
        ef, model, pair = fitted
        params.update(element=ef.element, ports=list(ef.ports), **ef.parameters)
        params["element_errors"] = ef.candidates
        if pair is not None:
            params["collocated"] = list(pair)
        # the spec's level, measured as a generator measures it with the truth: the share of
        # the output power the element adds to the linear model's response; the detector's
        # estimate (unexcited lines, or the linear residual's share) is kept beside it
        params["evidence_level"] = params["level"]
        params["level"] = ef.level
        error_after = ef.error_after
        ins = outs = tuple(ef.ports)
        if pair is not None or portless:
            outs = tuple(range(data.n_y))
        where = f"at port(s) {', '.join(str(j) for j in ef.ports)}"
        if ef.parameters.get("on") == "rigid_modes":
            where += (
                " on the rigid bodies' motion (at their bearings: the friction force enters "
                "the rigid-body modes only, not the flexible ones)"
            )
        if on_mode:
            # the mode's coordinate: every input drives it, every output sees it
            ins, outs = tuple(range(data.n_u)), tuple(range(data.n_y))
            where = (
                f"on the coordinate of mode {ef.parameters['mode']} "
                f"({ef.parameters['mode_freq_hz']:.4g} Hz; k3 "
                f"{ef.parameters['cubic_stiffness'][0]:.4g} in its modal units, a modal Duffing)"
            )
        note = (
            f" Fitted element: {ef.element.replace('_', ' ')} {where}; the nonlinear simulation "
            f"model (workbench.diagnosis.nonlinear) brings the error from {ef.error_before:.4g} "
            f"to {ef.error_after:.4g}."
        )
        if "port_gains" in ef.parameters:
            gains = ", ".join(
                f"{g:.3g} m/N at {f:.0f} Hz"
                for g, f in zip(ef.parameters["port_gains"], ef.parameters["port_gain_freq_hz"])
            )
            note += (
                " The outputs are the ports' motion for the modes they see as the inputs "
                "drive them; the modes they see with other shapes enter the ports with a "
                f"fitted gain |b_k|^2 each ({gains})."
            )
        if portless:
            note += (
                " No port could be located (no sensor collocated with an input), so friction "
                "and a spring, which act on the port motion, were not tried; a saturation of "
                "the inputs needs none."
            )
        if pair is not None:
            note += (
                f" The ports' motion comes from the model's mode shapes, mass-normalized at "
                f"output {pair[0]} taken as collocated with input {pair[1]} (every mode's "
                "driving-point residue is positive there)."
            )
    elif not direct:
        alt = {
            "effect": "nonlinearity",
            "error_before": float(cur_err),
            "error_after": float(cur_err),
            "parameters": jsonable(params),
            "rejected": (
                "a periodic residual that no linear effect removed, without distortion on the "
                "unexcited lines, and no port element to explain it (that needs a time record "
                "and a square model or a collocated sensor): not evidence of a nonlinearity"
            ),
        }
        return None, alt
    elif unrepeated and tried_element is not None:
        name, e_el = tried_element
        note = (
            " The record's periods do not repeat (their spread far beyond the noise): a "
            "response to a periodic input that is not periodic, which a linear time-invariant "
            "plant does not give (a time-varying plant does too), and which no model simulated "
            "from the recorded input follows sample by sample when it is sensitive to its own "
            "state (a strong spring driven into chaotic or quasi-periodic motion). The best "
            "element fitted, "
            f"{name.replace('_', ' ')}, reaches {e_el:.4g} where the linear model reaches "
            f"{cur_err:.4g}: the error cannot measure it, and the linear findings are only the "
            "best periodic approximation of the record."
        )
    else:
        note = (
            " No port element fitted: friction and a spring need a time record and a square "
            "model or a collocated sensor"
            + (", and a saturation of the inputs does not lower the error." if portless else ".")
        )
    ev = dict(
        parameters={"level": params["level"]},
        band_hz=nl.band_hz,
        n_lines=nl.n_lines,
        f_stat=nl.f_stat,
        unrepeated=nl.unrepeated,
        error_before=err,
        error_after=error_after,
        inputs=(),
        outputs=(),
        n_u=data.n_u,
        n_y=data.n_y,
        kind="time",
        why=why,
    )
    finding = Finding(
        effect="nonlinearity",
        inputs=ins,
        outputs=outs,
        band_hz=nl.band_hz,
        parameters=params,
        parameters_std={},
        error_after=float(error_after),
        explanation=explain("nonlinearity", ev) + note,
        model=model,
    )
    return finding, None


def _screen_passes(
    e_lin: float, e_first: float, needed: float, e_model: float, first_order: bool = True
) -> bool:
    """Whether an element hypothesis is worth its fit (the element must go below ``needed``).

    ``e_lin``: the linear model's error simulated from rest (as the element's simulation
    runs), ``e_model`` its error as the problem measures it (from the estimated start of a
    record that starts moving; the same on one at rest), ``e_first`` the error the
    element's first-order signature reaches (:func:`~workbench.diagnosis.nonlinear.
    first_order_errors`).

    - ``e_lin`` above SCREEN_START times ``e_model``: the record's start is most of the
      from-rest misfit, which an element simulated from rest does not have: no.
    - ``e_lin`` >= 1 (the from-rest simulation is off by more than the record: a drift):
      yes, whatever the first order says. Friction that holds a drifting rigid body is far
      from its first order (an indepgen stage record: the signature removes 17 % of the
      drift's power, the fit 100 %).
    - else: the signature must remove at least SCREEN_SHARE of the residual power the
      element must remove (a linear model already below ``needed`` passes). Not with
      ``first_order`` False (a spring on a lightly damped mode's coordinate: its response
      moves with the mode's frequency, far from linearly in k3 at the levels a record shows;
      on indepgen beam Duffing draws the signature removed almost none of what the fitted
      spring did).
    """
    if e_lin > SCREEN_START * e_model:
        return False
    if e_lin >= 1.0 or not first_order:
        return True
    return e_lin**2 - e_first**2 >= SCREEN_SHARE * (e_lin**2 - needed**2)


#: a spring on a mode's coordinate changes only that mode's output, from y_k to what the
#: spring makes of it, about as large (a hardening spring bends the resonance, its peak stays
#: near the linear one): it lowers the relative error by at most this many times the mode's
#: share ||y_k|| / ||y|| (y_k: the linear model's mode k alone driven by the record's input)
SPRING_REACH = 3.0


def _mode_share(port, data: TimeData) -> float:
    """||y_k|| / ||y||: the output of ``port``'s mode alone (ModalPort), driven by the record's
    input, against the record's output."""
    m = port.model
    alone = replace(m, modes=(m.modes[port.mode],), D=np.zeros_like(m.D))
    y_k = simulate_zoh(alone.to_lti(), data.u, data.fs)
    return float(np.linalg.norm(y_k) / max(np.linalg.norm(data.y), 1e-300))


def _fit_element(
    data: TimeData,
    linear: list,
    stop_above: float | None = None,
    band_hz: tuple[float, float] | None = None,
    mode_hz: float | None = None,
    screen: float | None = None,
    errors: list | None = None,
    drift: bool = False,
):
    """The port element that explains the record best: (ElementFit, linear model, pair) or None.

    ``linear``: the final linear model first, then the model as given. The ports are the
    outputs of a square model; on another, every pair (output, input) that may be collocated
    (:func:`~workbench.diagnosis.nonlinear.collocated_pairs`) is a hypothesis of where the
    ports are, and the record decides. Each element is fitted on each linear model; the
    element on the model as given wins unless the linear findings below it lower its error
    by the factor a finding must (``ERROR_RATIO``): they may be only the element's
    linearization. When no port can be located (no collocated pair), a saturation of the
    inputs, which needs no port, is the only element tried (pair None, as on a square model).

    ``stop_above``: when the element on the model as given (fitted first) leaves an error
    at or above it, that fit is returned and the other linear models are not tried (a
    caller that wants only a finding on the model as given, below this error). Each
    model's fit does not depend on the others', so what is returned otherwise is the same.

    On a model that is not square, a cubic spring on one mode's coordinate (a modal
    Duffing, :class:`~workbench.diagnosis.nonlinear.ModalPort`: no port needed) is a
    hypothesis beside the port elements, on each flexible mode within MODAL_BAND of the
    excited band ``band_hz`` (Hz): each mode's spring fitted cheaply (its level's scale
    scanned through the simulation), the best refined, and it is the element when it
    leaves the lower error (one level against the ports' several). Its pair is None. It is
    not tried when the port element already leaves only the record's noise. Square models
    (the ports are their outputs) are not given it: not validated there.

    On a square model with rigid modes, friction on the rigid bodies' motion
    (:class:`~workbench.diagnosis.nonlinear.RigidPorts`: at their bearings, driving no
    flexible mode) is a hypothesis beside the ports' elements (:data:`RIGID_FRICTION`),
    fitted first (on free rigid bodies its simulation is event-exact and takes milliseconds),
    and it is the element when it leaves the lower error. Its pair is None. When it leaves at
    most FLOOR_RATIO times the noise floor (a periodic record's, white:
    :func:`~workbench.diagnosis.detect.noise_floor`, the lower estimate), the ports' elements
    are not fitted: nothing is left for them to explain.

    ``mode_hz``: only the spring on the flexible mode of this frequency (Hz, within 1e-6
    relative) of each linear model, refined; None when no model has it.

    ``screen``: the error the element must go below; ``errors`` the linear models' errors
    as the problem measures them (aligned with ``linear``). A hypothesis (the port elements
    on one pair's ports, the rigid bodies' friction, a mode's spring) is then fitted only
    when :func:`_screen_passes` says so from its elements' first-order signature
    (:func:`~workbench.diagnosis.nonlinear.first_order_errors`: the error the linear model
    plus the element reaches near level zero, from a few linear simulations) and its linear
    model's from-rest error: the fit starts from that regression and moves the levels
    locally, hundreds of nonlinear simulations whose answer would be no (a linear misfit no
    element's signature spans; a record that starts moving, whose start the element's
    simulation from rest does not have). A linear model none of whose hypotheses passes
    gets an ElementFit with no element (``parameters["screened"]`` True, ``error_after``
    the linear model's own from-rest error; ``candidates`` the first-order errors). The
    port and rigid-body fits get it as ``give_up_above``: a fit far above it at its first
    substep count is not converged to finer ones.

    ``drift``: the from-rest error is above DRIFT_RATIO times the noise floor the record's
    periods show. The rigid bodies' friction is then fitted whatever its first-order
    signature says: a bearing's friction is integrated twice by a free body, far from its
    first order (its signature removed 0.5 % of the residual power on an indepgen
    closed-loop stage record with subtle friction on every body, 9.3x the floor, named
    'none'; the fit, 1.5 s, took it to 1.00x). The ports' elements stay screened (their
    fits take 10-30 s).
    """
    from workbench.diagnosis.nonlinear import (
        ElementFit,
        ModalPort,
        PortNonlinearity,
        RigidPorts,
        SquarePorts,
        collocated_pairs,
        first_order_errors,
        fit_port_element,
        fit_saturation,
        simulate_nonlinear,
        square_ports,
        with_ports,
    )

    n_y, n_u = data.n_y, data.n_u
    if mode_hz is not None:
        fits = []
        for i, m in enumerate(linear):
            for k, mode in enumerate(m.modes):
                if mode.kind == "flexible" and abs(mode.freq_hz - mode_hz) <= 1e-6 * mode_hz:
                    try:
                        mp = ModalPort(m, k)
                    except InputError:  # no single coordinate (a residue of rank > 1)
                        continue
                    fits.append((fit_port_element(mp, data.u, data.y, data.fs), i))
        if not fits:
            return None
        ef, i = min(fits, key=lambda t: t[0].error_after)
        return ef, linear[i], None
    if n_y == n_u:
        pairs: list = [None]
    else:
        pairs = collocated_pairs(linear[-1])
    ports = list(range(n_y, n_y + n_u))
    hyps = []  # (linear model index, sys, port outputs, pair, motion)
    for pair in pairs:
        motion = None
        if pair is not None:
            # the port motion of the model closest to the record (the final linear model)
            first = with_ports(linear[0], pair)
            if first is None:
                continue
            motion = simulate_zoh(first.to_lti(), data.u, data.fs)[:, ports]
        for i, m in enumerate(linear):
            if pair is None:
                # the outputs are the ports for the collocated modes; the others' port gains
                # are fitted with the element (SquarePorts), else Cp = C
                hyps.append((i, square_ports(m) or m.to_lti(), None, pair, None))
                continue
            aug = with_ports(m, pair)
            if aug is not None:
                hyps.append((i, aug.to_lti(), ports, pair, motion))
    # no port located: friction and a spring act on the port motion, which nothing fixes
    # then; a saturation of the inputs needs none (the linear model driven by the clipped
    # recorded input), so it is tried alone
    saturation_only = not hyps
    if saturation_only:
        hyps = [(i, m.to_lti(), None, None, None) for i, m in enumerate(linear)]

    def fit_one(h, refine, saturation=None):
        _, sys, port_outputs, _, motion = h
        if saturation_only:
            return fit_saturation(sys, data.u, data.y, data.fs, refine=refine)
        return fit_port_element(
            sys,
            data.u,
            data.y,
            data.fs,
            port_outputs=port_outputs,
            motion=motion,
            refine=refine,
            give_up_above=screen,
            saturation=saturation,
        )

    several = len(hyps) > 1
    given = len(linear) - 1
    # per linear model: (its from-rest error, the best first-order error per element) of the
    # hypotheses the screen left out
    screened: dict[int, tuple[float, dict[str, float]]] = {}
    # per linear model: the first-order error of a saturation of its inputs
    saturation_screened: dict[int, float] = {}

    def passes(h) -> bool:
        """Whether hypothesis ``h`` is fitted: no ``screen``, or :func:`_screen_passes` (the
        first-order errors of those it does not pass are kept for the report)."""
        if screen is None:
            return True
        i, sys, port_outputs, _, motion = h
        if drift and isinstance(sys, RigidPorts):
            return True
        e_m, fo = first_order_errors(
            sys,
            data.u,
            data.y,
            data.fs,
            port_outputs=port_outputs,
            motion=motion,
            ports=not saturation_only,
            saturation=saturation_screened.get(i),
            period=data.period,
        )
        if "saturation" in fo:  # the linear model's, whatever the ports (~0.1 s each)
            saturation_screened[i] = fo["saturation"]
        e_model = e_m if errors is None else errors[i]  # (None: at rest, as simulated)
        # a mode's spring is judged by the record's start only (not by its first order), and
        # on a drifting linear model by what it can move at all: its mode's own output
        modal = isinstance(sys, ModalPort)
        passed = _screen_passes(e_m, min(fo.values(), default=e_m), screen, e_model, not modal)
        if passed and modal and e_m >= 1.0:
            passed = e_m - SPRING_REACH * _mode_share(sys, data) <= screen
        if passed:
            return True
        e_prev, fo_prev = screened.get(i, (e_m, {}))
        for name, e in fo.items():
            fo_prev[name] = min(fo_prev.get(name, np.inf), e)
        screened[i] = (min(e_prev, e_m), fo_prev)
        return False

    def none_fitted(i):
        """The ElementFit of linear model ``i`` when the screen left no hypothesis on it."""
        e_m, fo = screened[i]
        best = min(fo, key=fo.get) if fo else "saturation"
        nl = PortNonlinearity(friction_force=np.zeros(n_u))
        ef = ElementFit(
            element=best,
            ports=(),
            parameters={
                "screened": True,
                "first_order_error": float(fo.get(best, e_m)),
                "portless": saturation_only,
            },
            nonlinearity=nl,
            error_before=float(e_m),
            error_after=float(e_m),
            candidates={k: float(v) for k, v in fo.items()},
            level=0.0,
        )
        return ef, (i, None, None, None, None)

    def modal_ports(m) -> list:
        """The ModalPorts of model ``m``'s flexible modes near the excited band (non-square)."""
        if n_y == n_u or band_hz is None:
            return []
        lo, hi = band_hz[0] / MODAL_BAND, band_hz[1] * MODAL_BAND
        out = []
        for k, mode in enumerate(m.modes):
            if mode.kind == "flexible" and lo <= mode.freq_hz <= hi:
                try:
                    out.append(ModalPort(m, k))
                except InputError:  # no single coordinate (a residue of rank > 1)
                    continue
        return out

    def at_floor(ef, h) -> bool:
        """Whether the port element ``ef`` leaves only the record's noise (periodic records:
        within FLOOR_RATIO of the floor from the periods, taken as white noise too; a record
        without periods: a residual that :func:`~workbench.diagnosis.detect.white_residual`
        finds white): a spring
        on a mode could then only fit the noise, and its scans (about 1 s a mode) are not
        run; nor, on the model as given, the element on the other linear models. The
        rigid-body friction's (:class:`RigidPorts`, fitted first) likewise: the ports'
        elements (10-30 s on a stage) are then not fitted.
        """
        if saturation_only:
            return False
        _, sys, port_outputs, _, _ = h
        if isinstance(sys, RigidPorts):  # its own ports (the element carries them)
            sys = sys.lti
        if isinstance(sys, SquarePorts):  # the model with the fitted port gains
            g = ef.parameters.get("port_gains")
            port_outputs = sys.port_outputs
            sys = sys.system(sys.unit if g is None else np.asarray(g, float))
        y_el = ef.output  # the fit's own run of the element (friction, a spring), else run it
        if y_el is None:
            y_el = simulate_nonlinear(
                sys, data.u, data.fs, ef.nonlinearity, port_outputs=port_outputs
            )
        if data.period is None:
            # no periods, no floor: a residual the element leaves white is the sensor noise
            # of an output-error fit (as the linear search's rounds judge such a record); the
            # test's False is "unknown" (coloured noise fails it too), and the rest is fitted
            # (an indepgen closed-loop stage record without periods, friction on its rigid
            # bodies at 1.00x the floor: the ports' fit after it took 43 of 49 s)
            return detect.white_residual(data.y - y_el)
        floor = detect.noise_floor(data, y_el, white=True)
        return floor is not None and ef.error_after <= FLOOR_RATIO * floor

    def fit_on(i):
        """The element's fit on linear model ``i``: (ElementFit, hypothesis); the port
        elements' best, or the modal spring's (the rigid-body friction's) when it leaves the
        lower error. Only the hypotheses the screen passes are fitted."""
        rigid = rigid_ports(linear[i]) if RIGID_FRICTION else None
        if rigid is not None and not passes((i, rigid, None, None, None)):
            rigid = None
        ef_r = None
        if rigid is not None:
            # friction on the rigid bodies' motion (at their bearings, driving no flexible
            # mode) beside the ports' (through the actuators); fitted first, whole: on free
            # rigid bodies its simulation is event-exact and cheap (a few seconds; the ports'
            # fit, through the flexible modes at up to MAX_SUBSTEPS, 10-30 s), and when it
            # leaves only the noise the ports' elements could only fit the noise
            h_r = (i, rigid, None, None, None)
            ef_r = _rigid_fit(rigid, data, screen)
            if at_floor(ef_r, h_r):
                floor_reached.add(i)
                return ef_r, h_r
        ef, h = fit_on_ports(i)
        if ef is None and ef_r is not None:
            ef, h = ef_r, h_r
        elif ef_r is not None and ef_r.error_after < ef.error_after:
            return ef_r, h_r
        if ef is not None and at_floor(ef, h):
            floor_reached.add(i)
            return ef, h
        modal = [mp for mp in modal_ports(linear[i]) if passes((i, mp, None, None, None))]
        if ef is not None:
            # a spring on a mode changes only that mode's output, so it lowers the linear
            # model's error by at most SPRING_REACH times the mode's share: a mode that
            # cannot reach the port element's error is not scanned (an indepgen beam record
            # whose saturation is at the floor, which the periods' estimate put lower: 5 of
            # its 8 modes in the band, each scan ~0.65 s)
            modal = [
                mp
                for mp in modal
                if ef.error_before - SPRING_REACH * _mode_share(mp, data) < ef.error_after
            ]
        if not modal:
            return (ef, h) if ef is not None else none_fitted(i)
        # the port elements' error, or (none passed the screen) the linear model's own
        err = ef.error_after if ef is not None else screened[i][0]
        kept = (ef, h) if ef is not None else none_fitted(i)
        cheap = [(fit_port_element(mp, data.u, data.y, data.fs, refine=False), mp) for mp in modal]
        ef_m, mp = min(cheap, key=lambda t: t[0].error_after)
        if not ef_m.error_after < err:
            return kept
        ef_m = fit_port_element(mp, data.u, data.y, data.fs)
        if not ef_m.error_after < err:
            return kept
        return ef_m, (i, mp, None, None, None)

    def rigid_ports(m):
        """The RigidPorts of a square model ``m`` with rigid modes (else None)."""
        if n_y != n_u or not any(mode.kind == "rigid" for mode in m.modes):
            return None
        try:
            return RigidPorts(m)
        except InputError:  # e.g. sensor lags: no rigid displacement output
            return None

    def fit_on_ports(i):
        """The port elements' fit on linear model ``i``: (ElementFit, hypothesis); (None,
        None) when the screen passes none of its hypotheses."""
        mine = [h for h in hyps if h[0] == i and passes(h)]
        if not mine:
            return None, None
        if saturation_only:
            (h,) = mine
            return fit_one(h, True), h
        # a saturation of the inputs needs no port: the same on every hypothesis of where
        # the ports are, fitted once and first. When it leaves only the noise, friction and
        # the spring (hundreds of nonlinear simulations: 7 of 10 s on an indepgen stage record
        # whose inputs saturate) could only fit the noise, and are not fitted
        ef_s = fit_saturation(linear[i].to_lti(), data.u, data.y, data.fs)
        if at_floor(ef_s, mine[0]):
            return ef_s, mine[0]
        if pairs == [None]:
            # a square model: one hypothesis per linear model, nothing to compare cheaply
            # first; the port gains (SquarePorts) are fitted refined, the outputs as ports not
            (h,) = mine
            return fit_one(h, not several or isinstance(h[1], SquarePorts), ef_s), h
        # the hypotheses compared cheaply, then the best refined (the refinement acts only
        # where the port motion is estimated, not measured)
        ef, h = min(
            ((fit_one(h, not several, ef_s), h) for h in mine), key=lambda t: t[0].error_after
        )
        return (fit_one(h, True, ef_s) if several else ef), h

    order = sorted({h[0] for h in hyps}, key=lambda i: i != given)  # the model as given first
    chosen: dict[int, tuple] = {}
    floor_reached: set[int] = set()
    for i in order:
        chosen[i] = fit_on(i)
        if i == given and stop_above is not None and chosen[i][0].error_after >= stop_above:
            ef, h = chosen[i]
            return ef, linear[h[0]], h[3]
        if i == given and i in floor_reached:
            # the element on the model as given leaves only the noise: on another linear
            # model it would have to go ERROR_RATIO below that, 0.94x the noise itself
            break
    i_pick = max(chosen)  # the model as given (last), unless the linear findings are needed
    if 0 in chosen and i_pick != 0:
        if chosen[0][0].error_after <= ERROR_RATIO * chosen[i_pick][0].error_after:
            i_pick = 0
    ef, h = chosen[i_pick]
    return ef, linear[h[0]], h[3]


#: the rigid-body friction fits of the records being diagnosed (:func:`_rigid_fit`)
_RIGID_FITS: dict = {}


def _rigid_fit(rigid, data: TimeData, give_up_above: float | None = None):
    """:func:`~workbench.diagnosis.nonlinear.fit_port_element` on ``rigid`` (RigidPorts),
    ``give_up_above`` passed on, kept per record and realization.

    A diagnosis fits friction on the model as given's rigid bodies in its early element test,
    again after the search, and again in a pair rerun: the same model and record, the same
    fit (on a smooth law at 256 substeps, 80 s each: an indep3 shaft record with a
    suspension). Keyed by the record's identity (kept alive in the entry) and the
    realization's matrices and delay; the few entries of the last records only. A fit that
    gave up (its coarse error more than COARSE_MARGIN times ``give_up_above``) serves a call
    that would give up as well (a bound as low or lower); a whole fit serves every call.
    """
    from workbench.diagnosis.nonlinear import COARSE_MARGIN, fit_port_element

    arrays = [np.ascontiguousarray(x, float) for x in (*as_matrices(rigid.lti)[:4], *rigid.maps)]
    key = (
        id(data),
        hashlib.sha1(b"".join(x.tobytes() for x in arrays)).hexdigest(),
        tuple(x.shape for x in arrays),
        float(rigid.lti.delay_s),
    )
    hit = _RIGID_FITS.get(key)
    if hit is not None and hit[0] is data:
        _, ef, gave_up_at = hit
        if gave_up_at is None or (give_up_above is not None and give_up_above <= gave_up_at):
            return ef
    ef = fit_port_element(rigid, data.u, data.y, data.fs, give_up_above=give_up_above)
    gave_up = give_up_above is not None and ef.error_after > COARSE_MARGIN * give_up_above
    if len(_RIGID_FITS) >= 8:
        _RIGID_FITS.clear()
    _RIGID_FITS[key] = (data, ef, give_up_above if gave_up else None)
    return ef


def _none_finding(
    problem, model, data, cur_err, error_before, floor, alternatives, drift=None
) -> Finding:
    """The 'none' finding: no effect of the vocabulary lowers the error significantly.

    ``drift``: the noise floor estimated from a periodic record's periods
    (:func:`workbench.diagnosis.detect.noise_floor`) when the error stays above
    DRIFT_RATIO times it: the steady state is right but not the from-rest simulation, and
    the explanation says so instead of "nothing is missing". On a record without periods
    it says "nothing is missing" only when the residual is white.
    """
    if problem.kind == "frf" and problem.has_var:
        chi = problem.cost(model) / problem.n_obs * 2
        # G_var estimated from few averages: z ~ F(2, d), mean d / (d - 2) (compare's law)
        mean = right_model_z_mean(variance_dof(problem.data.G_var))
        right = f"about {mean:.3g}" if mean is not None else "about 1"
        reason = (
            f"the error {cur_err:.4g} is at the noise floor {floor:.4g} computed from G_var; the "
            "noise-normalized "
            f"misfit is {chi:.3g} per element ({right} when the model is right)"
        )
    elif not alternatives and isinstance(data, TimeData) and not data.period:
        # the search stopped before its first round (_diagnose): nothing was fitted
        reason = (
            f"the error {cur_err:.4g} leaves a white residual (Ljung-Box, "
            "detect.white_residual): on a record without periods, the sensor noise an "
            "output-error fit leaves, nothing an effect would explain through the plant's "
            "dynamics; no effect was fitted"
        )
    else:
        reason = (
            f"the error {cur_err:.4g} is not lowered significantly by any effect of the vocabulary"
        )
    if alternatives:
        a = alternatives[0]
        reason += f"; the best candidate, {a['effect']}, would only reach {a['error_after']:.4g}"
    coloured = (
        isinstance(data, TimeData)
        and not data.period
        and not detect.white_residual(data.y - problem.predict(model))
    )
    if coloured:
        # no periods, no noise floor: the residual's whiteness is the only noise test left
        reason += (
            ". The record has no periods to tell noise from misfit, and the residual is not "
            "white (Ljung-Box, detect.white_residual): part of it may be a misfit no effect "
            "of the vocabulary explains, or coloured sensor noise; a periodic record tells."
        )
    elif drift is None:
        reason += ": nothing is missing."
    else:
        reason += (
            f". The steady state is within noise, but the error is {cur_err / drift:.3g} times "
            f"the noise floor estimated from the record's periods ({drift:.4g}): a drift of the "
            "from-rest simulation that no effect of the vocabulary (and no port element) explains."
        )
    band = problem.band_hz
    return Finding(
        effect="none",
        inputs=(),
        outputs=(),
        band_hz=band,
        parameters={},
        parameters_std={},
        error_after=cur_err,
        explanation=reason,
        model=model,
    )

"""Modal state feedback with an observer, designed on an (identified) modal model.

Data flow::

    ModalModel (continuous, ideal modal form) --restrict to inputs / outputs-->
        check_minimality: a mode failing Lemma 1/2 -> InputError, a weak one -> DataWarning
        --ZOH at fs, total delay (model delay_s + loop delay) as shift states
          (workbench.sim.c2d_zoh / delay_augmented), integrators on the rigid-body DOFs-->
    DesignModel  xi = [x_p (modal, scaled form); d_1 .. d_{m+1} (past u); x_i (integrators)]
        --> feedback K: control.dlqr (per-mode weights: modal_weights) or control.place
                        (per-mode targets: modal_poles)
        --> observer L on x_p only: control.dlqe (Kalman, DARE) or control.place (Luenberger)
        --> ModalSFDesign.controller: a StateSpaceController e = r - y -> u

    tune_modal_sf (what ``workbench design --method modal-sf`` and the scenarios call):
        bandwidth_lqg - LQR + Kalman weights set per mode from a rigid-body bandwidth,
        a rigid-body damping, an observer / integral ratio and an active-damping level,
        scale-free across DOFs (R = I, V = I; weights ~ w^4 / |b_k|^2, w^4 dt^2 / |c_k|^2)
        --> scanned and scored on the model with the loop delay
            (workbench.loop.screen_loops: stability, |S_ii|, crossover per loop)

The controller (predictor-form observer, strictly proper, ``D = 0``)::

    x_p^+ = Ad x_p + [plant rows of the delay model] + L (y_hat - C xi_p - D_p u),  y_hat = -e
    d^+   = shift(d, u)                   the delay line: past u, known exactly
    x_i^+ = x_i + dt P_r e                integral action on the rigid-body coordinates
    u     = -K [x_p; d; x_i]

How the loop delay enters (spec 5): the computation delay of the real-time
system belongs to the loop, not to the controller's matrices; the simulator
applies it (``workbench.sim.closed_loop(..., delay_samples=n)``). The design
model contains it (and the model's own ``delay_s``) as shift states, so the
controller carries a copy of the delay line fed with its own output: its
observer predicts the plant state ``m`` samples ahead and the feedback on the
delay states is the prediction (a Smith predictor in state-space form). The
delay line is known exactly, so the observer corrects the plant states only
and its error dynamics are ``eig(Ad - L C)`` (separation: the closed loop on
the design model has the poles ``eig(Phi - Gamma K)`` and ``eig(Ad - L C)``).
The controller's ``delay_samples`` records the loop delay the design assumed.

Units: inputs as the model (e.g. N), outputs as the model (e.g. m), fs in Hz.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Literal

import numpy as np

from controllers.protocol import StateSpaceController
from workbench.core.errors import DataWarning, InputError

__all__ = [
    "DesignModel",
    "ModalSFDesign",
    "design_model",
    "modal_weights",
    "mode_damping",
    "lqr_damping_weights",
    "modal_poles",
    "bandwidth_lqg",
    "lqr_gain",
    "place_gain",
    "kalman_gain",
    "luenberger_gain",
    "observer_controller",
    "design_modal_sf",
    "ModalSFTuneReport",
    "tune_modal_sf",
]

#: Riccati solver of every LQR / Kalman design here. python-control picks SLICOT
#: (slycot, installed for the H-inf synthesis) when it is present; its sb02md /
#: sg02ad refuse some of the stage's modal designs ("roundoff changed values of
#: some complex eigenvalues") that scipy's solver (the generalized Schur method
#: with balancing) solves, so the choice is explicit and the same on every machine.
ARE_METHOD = "scipy"


@dataclass(frozen=True)
class DesignModel:
    """The discrete design model ``xi^+ = Phi xi + Gamma u``, ``y = C xi + D u``.

    Attributes
    ----------
    Phi, Gamma, C, D : arrays (n, n), (n, n_u), (n_y, n), (n_y, n_u)
        States ``[x_p (n_p); delay line (n_d); integrators (n_i)]``; the
        integrator rows are ``x_i^+ = x_i - dt P_r y`` (``e = -y`` at r = 0).
    n_p, n_d, n_i : int
        Plant (modal), delay-line and integrator state counts.
    fs : float
        Sampling frequency, Hz.
    delay_samples : int
        Loop (computation) delay the design assumes, samples (the loop's, not the controller's).
    total_delay_s : float
        Model delay plus loop delay, s: what the shift states represent.
    P_r : (n_i, n_y) array
        Outputs -> rigid-body coordinates (pseudo-inverse of the rigid modes' c_k).
    modal : ModalModel
        The continuous modal model restricted to the chosen inputs and outputs.
    mode_states : tuple of slice
        The states of each mode (in ``modal.modes`` order) inside ``x_p``.
    """

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: np.ndarray
    n_p: int
    n_d: int
    n_i: int
    fs: float
    delay_samples: int
    total_delay_s: float
    P_r: np.ndarray
    modal: object
    mode_states: tuple

    @property
    def n(self) -> int:
        return self.Phi.shape[0]

    @property
    def dt(self) -> float:
        return 1.0 / self.fs

    @property
    def plant(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of plant + delay line (no integrators), input u[k]."""
        k = self.n_p + self.n_d
        return self.Phi[:k, :k], self.Gamma[:k], self.C[:, :k], self.D


def _restrict(model, inputs, outputs):
    """The ModalModel with only the chosen input columns / output rows (b_k, c_k, D)."""
    modes = tuple(dataclasses.replace(m, b=m.b[inputs], c=m.c[outputs]) for m in model.modes)
    return dataclasses.replace(
        model,
        modes=modes,
        D=model.D[np.ix_(outputs, inputs)],
        transform=None,
        input_names=tuple(model.input_names[i] for i in inputs),
        output_names=tuple(model.output_names[i] for i in outputs),
    )


def _as_modal(model):
    from workbench.modal.model import ModalModel

    if isinstance(model, ModalModel):
        return model
    try:
        return ModalModel.from_statespace(model)
    except AttributeError as exc:
        raise InputError(
            f"model: expected a ModalModel, control.StateSpace or LTIModel, got "
            f"{type(model).__name__}"
        ) from exc


def _channels(sel, names, what):
    n = len(names)
    if sel is None:
        return list(range(n))
    out = []
    for s in sel:
        if isinstance(s, str):
            if s not in names:
                raise InputError(f"{what}: expected one of {list(names)}, got {s!r}")
            out.append(names.index(s))
        elif isinstance(s, (int, np.integer)) and 0 <= s < n:
            out.append(int(s))
        else:
            raise InputError(f"{what}: expected a name or an index in [0, {n}), got {s!r}")
    if not out or len(set(out)) != len(out):
        raise InputError(f"{what}: expected distinct channels, got {list(sel)}")
    return out


def check_modes(modal, *, tol: float = 1e-8, weak: float = 1e-3) -> None:
    """Refuse a mode failing Lemma 1/2 (InputError, one line); warn on a weak margin.

    The relative margin ``m`` of Lemma 1 is ``|b_k| / max_j |b_j|`` (Lemma 2:
    ``c_k``); moving the mode's pole as far as the best-controlled mode's takes
    a feedback (observer) gain about ``1 / m`` times larger, which the warning states.
    """
    from workbench.modal.minimality import check_minimality

    report = check_minimality(modal, tol=tol, weak=weak)
    fails = [f for f in report.failures if f.severity == "fails"]
    if fails:
        f = fails[0]
        raise InputError(
            f"mode {f.mode} ({f.kind}, {f.freq_hz:.2f} Hz): {f.criterion} fails "
            f"({f.property} margin {f.margin:.2e} < {tol:g}): {f.meaning}; drop the mode "
            "(skip_modes) or choose other actuators / sensors"
        )
    for f in report.failures:
        gain = 1.0 / max(f.margin, 1e-300)
        what = "feedback" if f.property == "controllability" else "observer"
        best = "controlled" if f.property == "controllability" else "observed"
        warnings.warn(
            f"mode {f.mode} ({f.kind}, {f.freq_hz:.2f} Hz): weak {f.property}, {f.criterion}, "
            f"margin {f.margin:.2e}: placing its poles takes a {what} gain ~1/margin = "
            f"{gain:.2e} times that of the best-{best} mode",
            DataWarning,
            stacklevel=3,
        )


def design_model(
    model,
    fs: float,
    *,
    loop_delay_samples: int = 0,
    inputs=None,
    outputs=None,
    skip_modes=(),
    integral: bool = True,
    tol: float = 1e-8,
    weak: float = 1e-3,
) -> DesignModel:
    """Discretize the modal model with the delay and integral action (see the module notes).

    Parameters
    ----------
    model : ModalModel or control.StateSpace or LTIModel
        Continuous (or discrete) plant model; converted with
        ``ModalModel.from_statespace`` unless already modal. Its ``delay_s``
        (the delay inside the model, s) is kept.
    fs : float
        Controller sampling frequency, Hz.
    loop_delay_samples : int
        Computation delay of the real-time loop, samples (applied by the simulator).
    inputs, outputs : sequence of int or str, optional
        Actuators / sensors the controller uses (default all).
    skip_modes : sequence of int
        1-based modes left out of the design model (e.g. ones failing Lemma 1/2).
    integral : bool
        Integrators on the rigid-body coordinates ``P_r y`` (none without rigid modes).
    tol, weak : float
        Minimality thresholds (:func:`workbench.modal.minimality.check_minimality`).
    """
    from workbench.sim import c2d_zoh, delay_augmented

    fs = float(fs)
    if not np.isfinite(fs) or fs <= 0:
        raise InputError(f"fs: expected a sampling frequency > 0 Hz, got {fs}")
    if int(loop_delay_samples) != loop_delay_samples or loop_delay_samples < 0:
        raise InputError(f"loop_delay_samples: expected an integer >= 0, got {loop_delay_samples}")
    modal = _as_modal(model)
    n_modes = len(modal.modes)
    skip = set()
    for k in skip_modes:
        if not (isinstance(k, (int, np.integer)) and 1 <= k <= n_modes):
            raise InputError(f"skip_modes: expected 1-based modes in [1, {n_modes}], got {k!r}")
        skip.add(int(k))
    if skip:
        keep = tuple(m for j, m in enumerate(modal.modes) if j + 1 not in skip)
        modal = dataclasses.replace(modal, modes=keep, transform=None)
    modal = _restrict(
        modal,
        _channels(inputs, modal.input_names, "inputs"),
        _channels(outputs, modal.output_names, "outputs"),
    )
    if not modal.modes:
        raise InputError("model: expected at least one mode to control, got none")
    check_modes(modal, tol=tol, weak=weak)
    # "scaled" form: states (w q, dq/dt) per flexible mode, energy-like, better balanced
    sys = modal.to_statespace(form="scaled")
    A, B, C, D = (np.asarray(x, float) for x in (sys.A, sys.B, sys.C, sys.D))
    n_p, n_y = A.shape[0], C.shape[0]
    dt = 1.0 / fs
    total = modal.delay_s + int(loop_delay_samples) * dt
    Ad, B0, B1, m = c2d_zoh(A, B, dt, delay_s=total)
    Pa, Ga, Ca, Da = delay_augmented(Ad, B0, B1, m, C, D)
    n_d = Pa.shape[0] - n_p
    rigid = [k for k, md in enumerate(modal.modes) if md.kind == "rigid"]
    if integral and rigid:
        Cr = np.array([modal.modes[k].c for k in rigid]).T  # (n_y, n_r)
        P_r = np.linalg.pinv(Cr)
    else:
        P_r = np.zeros((0, n_y))
    n_i = P_r.shape[0]
    n1 = Pa.shape[0]
    Phi = np.zeros((n1 + n_i, n1 + n_i))
    Phi[:n1, :n1] = Pa
    Phi[n1:, :n1] = -dt * P_r @ Ca
    Phi[n1:, n1:] = np.eye(n_i)
    Gamma = np.vstack([Ga, -dt * P_r @ Da])
    Cf = np.hstack([Ca, np.zeros((n_y, n_i))])
    starts = np.cumsum([0] + [md.n_states for md in modal.modes])
    return DesignModel(
        Phi=Phi,
        Gamma=Gamma,
        C=Cf,
        D=Da,
        n_p=n_p,
        n_d=n_d,
        n_i=n_i,
        fs=fs,
        delay_samples=int(loop_delay_samples),
        total_delay_s=total,
        P_r=P_r,
        modal=modal,
        mode_states=tuple(slice(a, b) for a, b in zip(starts[:-1], starts[1:])),
    )


# ------------------------------------------------------------------ feedback
def _per_mode(value, n_modes: int, name: str) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, float), (n_modes,)) if np.ndim(value) == 0 else value
    v = np.asarray(v, float)
    if v.shape != (n_modes,) or not np.all(np.isfinite(v)):
        raise InputError(f"{name}: expected a scalar or {n_modes} values (one per mode), got {v}")
    return v


def modal_weights(
    dm: DesignModel,
    *,
    rigid_position: float = 1.0,
    rigid_velocity: float = 0.0,
    flexible=1.0,
    integral: float = 1.0,
) -> np.ndarray:
    """LQR state weight Q (n, n), set mode by mode.

    Rigid mode k: ``rigid_position q_k^2 + rigid_velocity (dq_k/dt)^2``.
    Flexible mode k (scaled states ``(w q, dq/dt)``): ``flexible[k] (w^2 q^2 +
    qdot^2)``, twice the mode's energy per unit modal mass, so a larger weight
    asks for more added damping of that mode. Integrators: ``integral``. The
    delay line is not weighted (it is a consequence of u).
    """
    modes = dm.modal.modes
    wf = _per_mode(flexible, len(modes), "flexible")
    Q = np.zeros((dm.n, dm.n))
    for k, (md, sl) in enumerate(zip(modes, dm.mode_states)):
        if md.kind == "rigid":
            Q[sl, sl] = np.diag([rigid_position, rigid_velocity])
        else:
            Q[sl, sl] = wf[k] * np.eye(sl.stop - sl.start)
    i0 = dm.n_p + dm.n_d
    Q[i0:, i0:] = integral * np.eye(dm.n_i)
    if np.any(np.linalg.eigvalsh(Q) < -1e-12 * max(1.0, np.abs(Q).max())):
        raise InputError("modal_weights: expected weights >= 0")
    return Q


def lqr_gain(dm: DesignModel, Q, R=None) -> np.ndarray:
    """K (n_u, n) from ``control.dlqr(Phi, Gamma, Q, R)``; R default identity."""
    import control

    R = np.eye(dm.Gamma.shape[1]) if R is None else np.atleast_2d(np.asarray(R, float))
    try:
        K, _, _ = control.dlqr(dm.Phi, dm.Gamma, Q, R, method=ARE_METHOD)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"lqr: the Riccati equation has no usable solution ({exc})") from exc
    return np.asarray(K, float)


def mode_damping(dm: DesignModel, K) -> np.ndarray:
    """Closed-loop damping of each flexible mode under ``u = -K xi`` (rigid / real: nan).

    The mode's pole pair is the eigenvalue of ``Phi - Gamma K`` (as ``s =
    fs log z``, upper half plane) nearest the mode's natural frequency.
    """
    z = np.linalg.eigvals(dm.Phi - dm.Gamma @ np.asarray(K, float))
    z = z[(np.abs(z) > 1e-12) & (z.imag > 0)]
    s = np.log(z.astype(complex)) * dm.fs
    out = np.full(len(dm.modal.modes), np.nan)
    flex = [k for k, md in enumerate(dm.modal.modes) if md.kind == "flexible"]
    if flex and s.size:
        from scipy.optimize import linear_sum_assignment

        # one pole pair per mode: modes of nearby frequency must not share one
        w = np.array([dm.modal.modes[k].omega for k in flex])
        rows, cols = linear_sum_assignment(np.abs(np.abs(s)[None, :] - w[:, None]))
        for i, j in zip(rows, cols):
            out[flex[i]] = -s[j].real / abs(s[j])
    return out


def lqr_damping_weights(dm: DesignModel, damping, *, R=None, max_weight: float = 1e30, **weights):
    """Q from :func:`modal_weights` with each flexible mode's weight raised to reach ``damping``.

    Mode by mode (the others held), the smallest weight (log bisection to 1 %)
    whose LQR closed loop gives the mode a damping >= ``damping[k]``
    (:func:`mode_damping`); two passes, as the modes couple through K. A target
    the mode already has keeps the weight given. Refused (InputError) when
    ``max_weight`` does not reach it.
    """
    modes = dm.modal.modes
    zt = _per_mode(damping, len(modes), "damping")
    w = _per_mode(weights.pop("flexible", 0.0), len(modes), "flexible").copy()

    def damp(wv):
        return mode_damping(dm, lqr_gain(dm, modal_weights(dm, flexible=wv, **weights), R))

    for _ in range(2):
        for k, md in enumerate(modes):
            if md.kind != "flexible" or damp(w)[k] >= zt[k]:
                continue
            lo, hi = max(w[k], 1e-30), max(w[k], 1.0)
            while True:
                trial = w.copy()
                trial[k] = hi
                try:
                    if damp(trial)[k] >= zt[k]:
                        break
                except InputError:
                    hi = np.inf  # the DARE breaks down before the target is reached
                lo, hi = hi, hi * 10
                if hi > max_weight:
                    raise InputError(
                        f"mode {k + 1} ({md.kind}, {md.freq_hz:.2f} Hz): LQR does not reach "
                        f"damping {zt[k]:g} with weights up to {max_weight:g}; lower the target "
                        "or use pole placement"
                    )
            while hi / lo > 1.01:
                mid = np.sqrt(lo * hi)
                trial = w.copy()
                trial[k] = mid
                if damp(trial)[k] >= zt[k]:
                    hi = mid
                else:
                    lo = mid
            w[k] = hi
    return modal_weights(dm, flexible=w, **weights)


def _rigid_bandwidths(dm: DesignModel, bandwidth_hz) -> np.ndarray:
    """Per-mode bandwidth (Hz) from a scalar or one value per mode; rigid entries checked."""
    modes = dm.modal.modes
    bw = _per_mode(bandwidth_hz, len(modes), "bandwidth_hz")
    for k, md in enumerate(modes):
        if md.kind == "rigid" and not (0 < bw[k] < dm.fs / 2):
            raise InputError(
                f"bandwidth_hz: expected 0 < f < fs/2 = {dm.fs / 2:g} Hz, "
                f"got {bw[k]} (mode {k + 1})"
            )
    return bw


def modal_poles(
    dm: DesignModel,
    *,
    damping=0.3,
    bandwidth_hz=10.0,
    delay_pole: float = 0.0,
) -> np.ndarray:
    """Target discrete poles, mode by mode.

    Flexible mode k keeps its natural frequency and gets ``max(damping[k],
    its own)``; real poles stay; each rigid DOF with its integrator gets the
    third-order Butterworth pattern at ``bandwidth_hz`` (scalar, or one value
    per mode: each rigid mode its own; without integrator, the second-order
    pattern); the delay line goes to ``delay_pole`` (spread by 0.02 so that
    ``control.place`` sees distinct poles). Continuous targets are mapped
    with ``z = exp(s / fs)``.
    """
    modes = dm.modal.modes
    zt = _per_mode(damping, len(modes), "damping")
    if np.any((zt < 0) | (zt >= 1)):
        raise InputError(f"damping: expected targets in [0, 1), got {zt}")
    bw = _rigid_bandwidths(dm, bandwidth_hz)
    s, w_int = [], []
    n_rigid = 0
    for k, md in enumerate(modes):
        if md.kind == "rigid":
            n_rigid += 1
            # spread the DOFs a little: place needs multiplicity <= rank(Gamma)
            w = 2 * np.pi * bw[k] * (1 + 1e-3 * (n_rigid - 1))
            w_int.append(w)
            if dm.n_i:  # 3rd-order Butterworth with the integrator pole
                s += [w * np.exp(1j * np.pi * 2 / 3), w * np.exp(-1j * np.pi * 2 / 3)]
            else:
                s += [w * np.exp(1j * np.pi * 3 / 4), w * np.exp(-1j * np.pi * 3 / 4)]
        elif md.kind == "real":
            s.append(md.pole)
        else:
            z = max(zt[k], md.damping)
            w = md.omega
            wd = w * np.sqrt(1 - z * z)
            s += [complex(-z * w, wd), complex(-z * w, -wd)]
    for j in range(dm.n_i):
        s.append(-w_int[j] * (1 + 1e-3 * j))
    z = list(np.exp(np.array(s, complex) / dm.fs))
    z += [delay_pole + 0.02 * j for j in range(dm.n_d)]
    return np.array(z, complex)


def _place(A, B, poles, maxiter):
    """``control.place`` (scipy YT, maxiter 30), or scipy's YT with fewer robustness sweeps.

    The poles are placed exactly either way; ``maxiter`` only bounds the
    conditioning sweeps (a 34-state MIMO placement takes seconds at 30).
    """
    if maxiter is None:
        import control

        return np.asarray(control.place(A, B, poles), float)
    from scipy.signal import place_poles

    return np.asarray(place_poles(A, B, poles, method="YT", maxiter=maxiter).gain_matrix, float)


def place_gain(dm: DesignModel, poles, *, maxiter: int | None = None) -> np.ndarray:
    """K (n_u, n) with ``eig(Phi - Gamma K) = poles`` (``control.place``; see :func:`_place`)."""
    poles = np.asarray(poles, complex)
    if poles.shape != (dm.n,):
        raise InputError(f"poles: expected {dm.n} poles, got {poles.shape}")
    return _place(dm.Phi, dm.Gamma, poles, maxiter)


def bandwidth_lqg(
    dm: DesignModel,
    *,
    bandwidth_hz=10.0,
    observer_ratio=2.0,
    integral_ratio: float = 0.3,
    flexible: float = 0.0,
    rigid_damping=0.7071067811865476,  # 1/sqrt 2: the plain LQR (Butterworth) pair
) -> tuple[np.ndarray, np.ndarray]:
    """(K, L): LQR + Kalman predictor whose weights follow from per-mode bandwidths.

    Scale-free in the units of each DOF (m vs rad, N vs N m): with ``R = I``
    on the inputs and ``V = I`` on the outputs, rigid mode k (``q'' = b_k u``,
    ``y = c_k q``) gets the position weight ``w_k^4 / |b_k|^2`` (alone, the
    LQR double-integrator loop: Butterworth poles at ``w_k = 2 pi
    bandwidth_hz[k]``), its integrator ``w_k^4 / |b_k|^2 (integral_ratio
    w_k)^2`` (integral action corner ~ ``integral_ratio`` below it), and the
    observer a white modal acceleration of per-sample variance ``w_o^4 dt^2 /
    |c_k|^2`` (the Kalman double-integrator filter at ``w_o = observer_ratio
    w_k``, loop-transfer-recovery-like as the ratio grows). Flexible and real
    modes carry no weight and no process noise: their poles stay where they
    are in both (the model-based "notch"); the delay line is known. LQR by
    ``control.dlqr``, Kalman by ``control.dlqe``. ``rigid_damping`` (scalar or per
    mode, >= 1/sqrt 2) adds the velocity weight ``(4 zeta^2 - 2) w_k^2 / |b_k|^2``: the
    LQR pair becomes ``s^2 + 2 zeta w_k s + w_k^2`` (more phase lead at crossover).
    """
    import control

    modes = dm.modal.modes
    bw = _rigid_bandwidths(dm, bandwidth_hz)
    ro = _per_mode(observer_ratio, len(modes), "observer_ratio")
    zr = _per_mode(rigid_damping, len(modes), "rigid_damping")
    Q = np.zeros((dm.n, dm.n))
    W = np.zeros((dm.n_p, dm.n_p))
    rigid = [k for k, md in enumerate(modes) if md.kind == "rigid"]
    w_r = 2 * np.pi * float(np.min(bw[rigid])) if rigid else 0.0
    for md, sl in zip(modes, dm.mode_states):
        if md.kind == "flexible" and flexible > 0 and rigid:
            # active damping: the mode's scaled states (w q, dq/dt) weighted like a rigid
            # position at the (lowest) rigid bandwidth, times `flexible`; its observer gets the
            # process noise of a rigid DOF observed at that bandwidth, times `flexible`
            nb = float(np.sum(np.square(md.b))) or 1e-300
            nc = float(np.sum(np.square(md.c))) or 1e-300
            Q[sl, sl] = flexible * w_r**4 / nb / md.omega**2 * np.eye(2)
            wo = min(float(np.min(ro[rigid])) * w_r, 2 * np.pi * 0.45 * dm.fs)
            W[sl.stop - 1, sl.stop - 1] = flexible * wo**4 * dm.dt**2 / nc
    add_rigid_weights(dm, Q, W, bw=bw, zr=zr, ro=ro, integral_ratio=integral_ratio)
    K = lqr_gain(dm, Q, np.eye(dm.Gamma.shape[1]))
    Ad, C = _obs_matrices(dm)
    try:
        L, _, _ = control.dlqe(Ad, np.eye(dm.n_p), C, W, np.eye(C.shape[0]), method=ARE_METHOD)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"kalman: the Riccati equation has no usable solution ({exc})") from exc
    return K, np.asarray(L, float)


def add_rigid_weights(dm, Q, W, *, bw, zr, ro, integral_ratio: float) -> None:
    """Fill the LQR weights ``Q`` and Kalman process noise ``W`` of every rigid mode (in place).

    Rigid mode k at bandwidth ``w_k = 2 pi bw[k]``: position ``w_k^4 / |b_k|^2``,
    velocity ``(4 zeta_k^2 - 2) w_k^2 / |b_k|^2`` (the LQR pair ``s^2 + 2 zeta w s +
    w^2``, zeta >= 1/sqrt 2), its integral state ``w_k^4 / |b_k|^2 (integral_ratio
    w_k)^2``; process noise ``w_o^4 dt^2 / |c_k|^2`` on its velocity state, ``w_o =
    ro[k] w_k`` (at most 0.45 fs). ``bw``, ``zr``, ``ro``: per mode of ``dm.modal``.
    """
    i0 = dm.n_p + dm.n_d
    j = 0
    for k, (md, sl) in enumerate(zip(dm.modal.modes, dm.mode_states)):
        if md.kind != "rigid":
            continue
        w = 2 * np.pi * bw[k]
        nb = float(np.sum(np.square(md.b))) or 1e-300
        nc = float(np.sum(np.square(md.c))) or 1e-300
        Q[sl.start, sl.start] = w**4 / nb
        Q[sl.start + 1, sl.start + 1] = max(4 * zr[k] ** 2 - 2, 0.0) * w**2 / nb
        if j < dm.n_i:
            Q[i0 + j, i0 + j] = w**4 / nb * (integral_ratio * w) ** 2
        j += 1
        wo = min(ro[k] * w, 2 * np.pi * 0.45 * dm.fs)
        W[sl.start + 1, sl.start + 1] = wo**4 * dm.dt**2 / nc


# ------------------------------------------------------------------ observers
def _obs_matrices(dm: DesignModel):
    n = dm.n_p
    return dm.Phi[:n, :n], dm.C[:, :n]


def kalman_gain(dm: DesignModel, *, process=1.0, sensor=1.0) -> np.ndarray:
    """Predictor Kalman gain L (n_p, n_y) on the plant states, ``control.dlqe``.

    Process noise: a force at every input with standard deviation ``process``
    (scalar or (n_u,), input units), through the one-sample ZOH input matrix
    of the plant; sensor noise ``sensor`` (scalar or (n_y,), output units).
    The delay line is known exactly (no noise, no gain rows).
    """
    import control

    from workbench.sim import phi_gamma

    Ad, C = _obs_matrices(dm)
    sys = dm.modal.to_statespace(form="scaled")
    _, G = phi_gamma(np.asarray(sys.A, float), np.asarray(sys.B, float), dm.dt)
    n_u, n_y = G.shape[1], C.shape[0]
    qn = np.broadcast_to(np.asarray(process, float), (n_u,)) ** 2
    rn = np.broadcast_to(np.asarray(sensor, float), (n_y,)) ** 2
    if np.any(rn <= 0) or np.any(qn < 0):
        raise InputError("kalman_gain: expected process >= 0 and sensor > 0 noise levels")
    L, _, _ = control.dlqe(Ad, G, C, np.diag(qn), np.diag(rn), method=ARE_METHOD)
    return np.asarray(L, float)


def luenberger_gain(dm: DesignModel, poles, *, maxiter: int | None = None) -> np.ndarray:
    """L (n_p, n_y) with ``eig(Ad - L C) = poles`` by ``control.place`` on the dual."""
    Ad, C = _obs_matrices(dm)
    poles = np.asarray(poles, complex)
    if poles.shape != (dm.n_p,):
        raise InputError(f"poles: expected {dm.n_p} observer poles, got {poles.shape}")
    return _place(Ad.T, C.T, poles, maxiter).T


# ------------------------------------------------------------------ controller
def observer_controller(dm: DesignModel, K, L) -> StateSpaceController:
    """Observer + feedback as one discrete controller e -> u (module notes), D = 0."""
    K = np.asarray(K, float)
    L = np.asarray(L, float)
    n, n_p, n_i = dm.n, dm.n_p, dm.n_i
    n_y = dm.C.shape[0]
    if K.shape != (dm.Gamma.shape[1], n) or L.shape != (n_p, n_y):
        raise InputError(
            f"K, L: expected shapes {(dm.Gamma.shape[1], n)} and {(n_p, n_y)}, "
            f"got {K.shape} and {L.shape}"
        )
    k1 = n - n_i
    Lf = np.zeros((k1, n_y))
    Lf[:n_p] = L  # the delay line gets no correction: it is known exactly
    Pp, Gp, Cp, Dp = dm.plant
    Ac = np.zeros((n, n))
    Ac[:k1, :k1] = Pp - Lf @ Cp
    Ac[k1:, k1:] = np.eye(n_i)
    Ac[:k1] -= (Gp - Lf @ Dp) @ K
    Bc = np.vstack([-Lf, dm.dt * dm.P_r])
    return StateSpaceController(
        Ac,
        Bc,
        -K,
        np.zeros((K.shape[0], n_y)),
        fs=dm.fs,
        input_names=dm.modal.output_names,
        output_names=dm.modal.input_names,
        delay_samples=dm.delay_samples,
    )


@dataclass(frozen=True)
class ModalSFTuneReport:
    """What :func:`tune_modal_sf` scanned and kept.

    ``settings`` the kept design settings (JSON-ready), ``crossover_hz`` the
    lowest per-loop crossover on the model (Hz), ``ms_max`` the |S| bound,
    ``scanned`` the grid (name -> values), ``tried`` / ``feasible`` the
    candidate counts.
    """

    settings: dict
    crossover_hz: float
    ms_max: float
    scanned: dict
    tried: int
    feasible: int


@dataclass(frozen=True)
class ModalSFDesign:
    """A finished design: the model, the gains and the controller.

    ``K`` (n_u, n) state feedback, ``L`` (n_p, n_y) observer gain, ``controller``
    the :class:`StateSpaceController` e -> u (loop delay ``dm.delay_samples``
    applied by the loop, not inside it).
    """

    dm: DesignModel
    K: np.ndarray
    L: np.ndarray
    controller: StateSpaceController
    report: ModalSFTuneReport | None = None  # set by tune_modal_sf

    def design_poles(self) -> tuple[np.ndarray, np.ndarray]:
        """(feedback poles eig(Phi - Gamma K), observer poles eig(Ad - L C)), discrete."""
        Ad, C = _obs_matrices(self.dm)
        return (
            np.linalg.eigvals(self.dm.Phi - self.dm.Gamma @ self.K),
            np.linalg.eigvals(Ad - self.L @ C),
        )


def design_modal_sf(
    model,
    fs: float,
    *,
    loop_delay_samples: int = 0,
    inputs=None,
    outputs=None,
    skip_modes=(),
    feedback: Literal["lqr", "place"] = "lqr",
    observer: Literal["kalman", "luenberger"] = "kalman",
    weights: dict | None = None,
    R=None,
    damping=0.3,
    bandwidth_hz: float = 10.0,
    observer_poles=None,
    observer_speed: float = 3.0,
    process=1.0,
    sensor=1.0,
    integral: bool = True,
    lqr_damping=None,
) -> ModalSFDesign:
    """Modal state feedback + observer in one call (see the module notes).

    Parameters (beyond :func:`design_model`)
    ----------------------------------------
    feedback : {"lqr", "place"}
        LQR with ``modal_weights(**weights)`` and input weight ``R``, or pole
        placement at ``modal_poles(damping=, bandwidth_hz=)``. With
        ``lqr_damping`` (scalar or per mode), the flexible weights are raised
        to reach that damping (:func:`lqr_damping_weights`).
    observer : {"kalman", "luenberger"}
        ``kalman_gain(process=, sensor=)``, or placement at ``observer_poles``
        (default: the feedback targets of the plant states with their
        continuous poles decaying ``observer_speed`` times faster, same frequencies).
    """
    dm = design_model(
        model,
        fs,
        loop_delay_samples=loop_delay_samples,
        inputs=inputs,
        outputs=outputs,
        skip_modes=skip_modes,
        integral=integral,
    )
    if feedback == "lqr" and lqr_damping is not None:
        K = lqr_gain(dm, lqr_damping_weights(dm, lqr_damping, R=R, **(weights or {})), R)
    elif feedback == "lqr":
        K = lqr_gain(dm, modal_weights(dm, **(weights or {})), R)
    elif feedback == "place":
        K = place_gain(dm, modal_poles(dm, damping=damping, bandwidth_hz=bandwidth_hz))
    else:
        raise InputError(f"feedback: expected 'lqr' or 'place', got {feedback!r}")
    if observer == "kalman":
        L = kalman_gain(dm, process=process, sensor=sensor)
    elif observer == "luenberger":
        if observer_poles is None:
            z = modal_poles(dm, damping=damping, bandwidth_hz=bandwidth_hz)[: dm.n_p]
            s = np.log(z.astype(complex)) * dm.fs
            # same frequencies, observer_speed times faster decay
            observer_poles = np.exp((observer_speed * s.real + 1j * s.imag) / dm.fs)
        L = luenberger_gain(dm, observer_poles)
    else:
        raise InputError(f"observer: expected 'kalman' or 'luenberger', got {observer!r}")
    ctrl = observer_controller(dm, K, L)
    rho = float(np.max(np.abs(np.linalg.eigvals(dm.Phi - dm.Gamma @ K))))
    if rho >= 1:
        raise InputError(f"design: the state feedback is unstable (spectral radius {rho:.4f})")
    return ModalSFDesign(dm=dm, K=K, L=L, controller=ctrl)


# ------------------------------------------------------------------ tuning
# Scan grid of tune_modal_sf. Rigid-body LQR bandwidths as fractions of fs: a one-sample delay
# limits a double integrator's crossover near fs/25 at |S| <= 2, so 0.2 %..10 % of fs spans
# delays from a fraction of a sample to several; observer speed as a ratio to it (a fast
# Kalman filter recovers the LQR loop, loop-transfer-recovery-like; a slower one rolls the
# controller off sooner; 10 and 30 gave the same crossovers within 1 %); integral action
# corner as a ratio to it (0.05..0.5 tried on delayed double integrators: 0.05-0.1 best)
_TUNE_BW_FRACTIONS = tuple(np.logspace(np.log10(2e-3), np.log10(0.1), 14))
_TUNE_OBS_RATIO = 30.0
_TUNE_INTEGRAL_RATIO = 0.1
# damping of the rigid-body LQR pair (velocity weight): more damping, more phase lead at
# crossover; on a delayed double integrator the crossover at |S| <= 2 rises with it
# (1 sample, fs 5 kHz, best over bandwidth: 0.71 -> 190 Hz, 1.3 -> 222 Hz, 2.5 -> 235 Hz)
_TUNE_RIGID_DAMPING = (1.0, 2.0, 3.0)
# active damping of the flexible modes (bandwidth_lqg's `flexible`): none, light, strong
_TUNE_FLEXIBLE = (0.0, 1e-3, 0.1)
_TUNE_REFINE = 5  # bisection steps on the kept bandwidth (grid step 1.35x -> ~1 %)


def _tune_fs(model, fs) -> float:
    dt = getattr(model, "dt", None)
    if dt:  # discrete model: its own rate
        own = 1.0 / float(dt)
        if fs is not None and abs(float(fs) - own) > 1e-9 * own:
            raise InputError(f"fs: expected the discrete model's rate {own:g} Hz, got {fs:g}")
        return own
    if fs is None:
        raise InputError("fs: expected the controller sampling frequency for a continuous model")
    return float(fs)


def _rigid_loops(dm: DesignModel) -> dict[int, int]:
    """Rigid mode index -> the loop (output) it dominates, one loop per mode.

    Assignment on ``|P_r|`` scaled per output (units differ: m, rad): the
    output through which the integrator of each rigid coordinate mainly acts.
    Empty when the rigid modes cannot be assigned one loop each.
    """
    from scipy.optimize import linear_sum_assignment

    rigid = [k for k, md in enumerate(dm.modal.modes) if md.kind == "rigid"]
    if not rigid or len(rigid) > dm.C.shape[0]:
        return {}
    Cr = np.abs(np.array([dm.modal.modes[k].c for k in rigid]))  # (n_r, n_y)
    W = Cr / np.maximum(Cr.max(axis=0, keepdims=True), 1e-300)
    rows, cols = linear_sum_assignment(-W)
    return {rigid[r]: int(c) for r, c in zip(rows, cols)}


def _candidate(dm, bw, zeta, flexible, screen_model, m, f):
    """(controller, K, L, stable, peak, fc) of one setting; None if a Riccati equation fails."""
    from workbench import loop

    try:
        K, L = bandwidth_lqg(
            dm,
            bandwidth_hz=bw,
            observer_ratio=_TUNE_OBS_RATIO,
            integral_ratio=_TUNE_INTEGRAL_RATIO,
            rigid_damping=zeta,
            flexible=flexible,
        )
    except (InputError, ValueError, np.linalg.LinAlgError):
        return None
    ctrl = observer_controller(dm, K, L)
    stable, peak, fc = loop.screen_loops(screen_model, ctrl, loop_delay_samples=m, freq_hz=f)
    return ctrl, K, L, stable, peak, fc


def tune_modal_sf(
    model, *, ms_max: float = 2.0, loop_delay_samples: int = 0, fs=None, progress=None
) -> ModalSFDesign:
    """Modal LQG (:func:`bandwidth_lqg`) tuned per rigid mode for the highest crossover.

    Derived from the model, the loop delay and ``ms_max`` only:

    1. scan common settings (every rigid mode the same): LQR bandwidth x
       rigid-body damping x active damping of the flexible modes; each candidate scored on the model
       with the loop delay by :func:`workbench.loop.screen_loops` (per loop:
       |S_ii| peak, crossover);
    2. per active damping level, give each rigid mode the setting with the highest
       crossover of its own loop (:func:`_rigid_loops`) among the stable ones
       meeting ``|S_ii| <= ms_max`` there (DOFs of different mass / inertia
       and mode coupling may want different settings);
    3. check that combination on the model; a loop over the bound moves its
       rigid mode to its next setting until all loops meet it. The highest
       lowest-crossover design is kept (the common settings of step 1 compete).

    The design model (and its minimality check: a mode failing Lemma 1/2 is
    an InputError, a weak one warns once) is built once. ``progress(i, n)``
    is called after each scanned candidate. Refused (InputError) when no
    stable setting meets the bound.
    """
    from workbench import loop

    fs = _tune_fs(model, fs)
    ms_max = float(ms_max)
    if not np.isfinite(ms_max) or ms_max <= 1.0:
        raise InputError(f"ms_max: expected a bound > 1 on |S|, got {ms_max}")
    m = loop._delay_check(loop_delay_samples)
    dm = design_model(model, fs, loop_delay_samples=m)
    screen_model = model.to_lti() if hasattr(model, "to_lti") else model
    f = loop._default_grid(fs)
    modes = dm.modal.modes
    n_modes = len(modes)
    grid = [
        (fr * fs, r, g)
        for g in _TUNE_FLEXIBLE
        for fr in _TUNE_BW_FRACTIONS
        for r in _TUNE_RIGID_DAMPING
    ]
    results = {}
    for i, key in enumerate(grid):
        results[key] = _candidate(dm, *key, screen_model, m, f)
        if progress is not None:
            progress(i + 1, len(grid))

    def score(res):
        if res is None or not res[3] or np.max(res[4]) > ms_max or not np.all(np.isfinite(res[5])):
            return 0.0
        return float(np.min(res[5]))

    key = max(grid, key=lambda k: score(results[k]))
    best = (score(results[key]), results[key], np.full(n_modes, key[0]), np.full(n_modes, key[1]))
    best_g = key[2]
    tried = len(grid)
    if best[0] > 0:
        # refine the common bandwidth between the kept grid point and the next one up: the
        # crossover grows with it until the |S| bound breaks (bisection on that boundary)
        step = _TUNE_BW_FRACTIONS[1] / _TUNE_BW_FRACTIONS[0]
        lo, hi = key[0], key[0] * step
        for _ in range(_TUNE_REFINE):
            mid = np.sqrt(lo * hi)
            res = _candidate(dm, mid, key[1], key[2], screen_model, m, f)
            tried += 1
            sc = score(res)
            if sc > 0:
                lo = mid
                if sc > best[0]:
                    best = (sc, res, np.full(n_modes, mid), np.full(n_modes, key[1]))
            else:
                hi = mid
    owners = _rigid_loops(dm)
    for g in _TUNE_FLEXIBLE if owners else ():
        keys = [k for k in grid if k[2] == g and results[k] is not None and results[k][3]]
        # per rigid mode: its settings ranked by its own loop's crossover, bound met there
        ranked = {}
        for k, i in owners.items():
            ok = [c for c in keys if results[c][4][i] <= ms_max and np.isfinite(results[c][5][i])]
            ranked[k] = sorted(ok, key=lambda c: -results[c][5][i])
        if not all(ranked.values()):
            continue
        pick = dict.fromkeys(owners, 0)
        for _ in range(4 * len(owners)):
            bw = np.full(n_modes, best[2][0] if best[0] > 0 else grid[0][0])
            ratio = np.full(n_modes, _TUNE_RIGID_DAMPING[0])
            for k in owners:
                bw[k], ratio[k] = ranked[k][pick[k]][:2]
            res = _candidate(dm, bw, ratio, g, screen_model, m, f)
            tried += 1
            sc = score(res)
            if sc > 0:
                if sc > best[0]:
                    best, best_g = (sc, res, bw, ratio), g
                break
            if res is None or not res[3]:
                worst = list(owners)  # unstable: step every mode down
            else:
                worst = [k for k, i in owners.items() if res[4][i] > ms_max]
                if not worst:  # a loop without crossover: not a usable design
                    break
            moved = False
            for k in worst:
                if pick[k] + 1 < len(ranked[k]):
                    pick[k] += 1
                    moved = True
            if not moved:
                break
    if best[0] <= 0:
        raise InputError(
            f"modal-sf: no stable design meets |S| <= {ms_max:g} on the model (rigid-body "
            f"bandwidths {_TUNE_BW_FRACTIONS[0] * fs:.3g}..{_TUNE_BW_FRACTIONS[-1] * fs:.3g} Hz, "
            f"rigid damping {_TUNE_RIGID_DAMPING}, active damping {_TUNE_FLEXIBLE})"
        )
    fc, res, bw, ratio = best
    ctrl, K, L = res[:3]
    rigid = [k for k, md in enumerate(modes) if md.kind == "rigid"]
    settings = {
        "rigid_bandwidth_hz": [float(bw[k]) for k in rigid],
        "rigid_damping": [float(ratio[k]) for k in rigid],
        "observer_ratio": _TUNE_OBS_RATIO,
        "integral_ratio": _TUNE_INTEGRAL_RATIO,
        "flexible": float(best_g),
    }
    report = ModalSFTuneReport(
        settings=settings,
        crossover_hz=float(fc),
        ms_max=ms_max,
        scanned={
            "bandwidth_hz": [float(x * fs) for x in _TUNE_BW_FRACTIONS],
            "rigid_damping": list(_TUNE_RIGID_DAMPING),
            "flexible": list(_TUNE_FLEXIBLE),
        },
        tried=tried,
        feasible=int(sum(score(r) > 0 for r in results.values())),
    )
    return ModalSFDesign(dm=dm, K=K, L=L, controller=ctrl, report=report)

"""Baseline design: decentralized PID / lead-lag + low-pass + notches, highest crossover.

Per DOF i (loop u_i -> y_i of a square plant) the continuous shape is

    K_i(s) = k (1 + w_i / s) (1 + s / w_z) / (1 + s / w_p) w_lp^2 / (s^2 + 2 z_lp w_lp s + w_lp^2)
             prod_n (s^2 + 2 z_nz w_n s + w_n^2) / (s^2 + 2 z_np w_n s + w_n^2)

with, for a crossover fc: integrator at fc / integrator_ratio, lead zero at
fc / lead_ratio and pole at fc * lead_ratio, low-pass at fc * lowpass_ratio
(capped at 0.45 fs) and one notch per flexible mode (given, or detected as the
peaks of |G_ii| f^2 above the rigid-body line). Every corner is pre-warped and
the shape mapped with Tustin at fs (as :mod:`controllers.pid`). The gain k sets
|L_i(j 2 pi fc)| = 1 on the sampled loop (ZOH, plant delay, loop delay).

The tuner searches fc per DOF and per shape: a log scan of candidates, then
bisection between the highest candidate meeting the constraint and the next
one, for the largest fc with the diagonal loop stable (Nyquist count) and
max |S_i| <= ms_max on the analysis lines. The shapes tried are every
(lead_ratio, lowpass_ratio) pair given, with the notches and (for detected
modes) without them; the shape reaching the highest fc is kept (a notch costs
phase at crossover, so it only pays where the mode limits the loop). Each DOF
is tuned on its diagonal element G_ii; the report analyses the full MIMO
loop (:func:`workbench.loop.analyze_loop`), so the coupling shows there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from controllers.pid import PidChannel
from controllers.protocol import StateSpaceController
from workbench.core.errors import InputError

__all__ = ["PidNotchChannel", "DecentralizedPidNotch", "PidNotchReport", "tune_pid_notch"]


@dataclass(frozen=True)
class PidNotchChannel:
    """One DOF: the PID/lead-lag/low-pass of :class:`PidChannel` and notches (Hz).

    ``notch_hz`` centres, Hz; zeros damped ``notch_depth_damping``, poles
    ``notch_width_damping`` (depth = their ratio).
    """

    pid: PidChannel
    notch_hz: tuple[float, ...] = ()
    notch_depth_damping: float = 0.02
    notch_width_damping: float = 0.3

    def sections(self, fs: float | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """First/second-order sections (num, den) in s whose product is K_i(s).

        With ``fs`` the corners are pre-warped for Tustin at fs (they land where
        asked in the discrete controller); notches at or above fs/2 are dropped
        (the sampled loop cannot notch them).
        """
        p = self.pid

        def w(f_hz):
            if fs is None:
                return 2 * np.pi * f_hz
            if f_hz >= fs / 2:
                raise InputError(f"corner {f_hz:g} Hz: expected below fs/2 = {fs / 2:g} Hz")
            return 2 * fs * np.tan(np.pi * f_hz / fs)

        secs = [(np.array([p.kp]), np.array([1.0]))]
        if p.f_i_hz > 0:
            secs.append((np.array([1.0, w(p.f_i_hz)]), np.array([1.0, 0.0])))
        secs.append(
            (np.array([1.0 / w(p.f_lead_zero_hz), 1.0]), np.array([1.0 / w(p.f_lead_pole_hz), 1.0]))
        )
        if p.f_lp_hz > 0:
            wl = w(p.f_lp_hz)
            secs.append((np.array([wl**2]), np.array([1.0, 2 * p.lp_damping * wl, wl**2])))
        for fn in self.notch_hz:
            if fs is not None and fn >= fs / 2:
                continue
            wn = w(fn)
            secs.append(
                (
                    np.array([1.0, 2 * self.notch_depth_damping * wn, wn**2]),
                    np.array([1.0, 2 * self.notch_width_damping * wn, wn**2]),
                )
            )
        return secs

    def transfer_function(self, fs: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) in s, highest power first (pre-warped for Tustin at ``fs`` if given)."""
        num, den = np.array([1.0]), np.array([1.0])
        for n_, d_ in self.sections(fs):
            num, den = np.polymul(num, n_), np.polymul(den, d_)
        return num, den

    def discrete_sections(self, fs: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """The sections mapped to z by Tustin at fs, one by one (well conditioned)."""
        return [scipy.signal.bilinear(n_, d_, fs=fs) for n_, d_ in self.sections(fs)]

    def discrete_frf(self, freq_hz, fs: float) -> np.ndarray:
        """K_i(e^{j w / fs}) at ``freq_hz`` (Hz), shape (n_f,).

        Tustin maps z = e^{j w / fs} to s = j 2 fs tan(pi f / fs), so the
        discrete response is the (pre-warped) continuous one evaluated there.
        """
        s = 2j * fs * np.tan(np.pi * np.asarray(freq_hz, float) / fs)
        out = np.ones(s.shape, complex)
        for n_, d_ in self.sections(fs):
            out *= np.polyval(n_, s) / np.polyval(d_, s)
        return out

    def discrete_ss(self, fs: float):
        """(A, B, C, D) of the discrete channel: the sections in series."""
        A, B, C, D = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))
        for n_, d_ in self.discrete_sections(fs):
            a, b, c, d = (np.atleast_2d(np.asarray(x, float)) for x in scipy.signal.tf2ss(n_, d_))
            if a.size == 0:
                a, b, c = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0))
            # x1 -> section: x2+ = a x2 + b (C x1 + D e), y = c x2 + d (C x1 + D e)
            n1, n2 = A.shape[0], a.shape[0]
            A = np.block([[A, np.zeros((n1, n2))], [b @ C, a]])
            B = np.vstack([B, b @ D])
            C = np.hstack([d @ C, c])
            D = d @ D
        return A, B, C, D


@dataclass(frozen=True)
class DecentralizedPidNotch:
    """Diagonal controller u_i = K_i(z) e_i; implements the Controller protocol (spec 5).

    The discrete block-diagonal state space is built on construction and held
    as a :class:`StateSpaceController` (``statespace()`` is exactly ``step``).
    ``delay_samples`` is the loop computation delay the design assumed
    (informational: it is not in the matrices).
    """

    channels: tuple[PidNotchChannel, ...]
    fs: float
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    delay_samples: int = 0

    def __post_init__(self):
        channels = tuple(self.channels)
        if not channels:
            raise InputError("channels: expected at least one PidNotchChannel")
        object.__setattr__(self, "channels", channels)
        blocks = [ch.discrete_ss(self.fs) for ch in channels]
        A = scipy.linalg.block_diag(*[b[0] for b in blocks])
        B = scipy.linalg.block_diag(*[b[1] for b in blocks])
        C = scipy.linalg.block_diag(*[b[2] for b in blocks])
        D = scipy.linalg.block_diag(*[b[3] for b in blocks])
        ss = StateSpaceController(
            A, B, C, D, fs=self.fs, input_names=self.input_names,
            output_names=self.output_names, delay_samples=self.delay_samples,
        )  # fmt: skip
        object.__setattr__(self, "fs", ss.fs)
        object.__setattr__(self, "_ss", ss)

    @property
    def n_u(self) -> int:
        return self._ss.n_u

    @property
    def n_y(self) -> int:
        return self._ss.n_y

    @property
    def linear(self) -> bool:
        return True

    @property
    def controller(self) -> StateSpaceController:
        """The discrete state-space form (spec-5 file contents)."""
        return self._ss

    def init(self):
        return self._ss.init()

    def step(self, state, e):
        return self._ss.step(state, e)

    def output(self, state):
        return self._ss.output(state)

    def statespace(self):
        """Discrete control.StateSpace e -> u, dt = 1/fs."""
        return self._ss.statespace()


@dataclass(frozen=True)
class PidNotchReport:
    """Per-DOF result of :func:`tune_pid_notch` and the MIMO loop analysis."""

    crossover_hz: tuple[float, ...]  # tuned crossover per DOF
    s_peak: tuple[float, ...]  # max |1 / (1 + G_ii K_i)|, the diagonal loop alone
    notch_hz: tuple[tuple[float, ...], ...]
    analysis: object  # workbench.loop.LoopAnalysis of the full loop

    def table(self) -> str:
        return self.analysis.table()


def _shape(fc, fs, notches, *, lead_ratio, integrator_ratio, lowpass_ratio, lp_damping,
           notch_depth_damping, notch_width_damping, kp=1.0) -> PidNotchChannel:  # fmt: skip
    pid = PidChannel(
        kp=kp, f_i_hz=fc / integrator_ratio, f_lead_zero_hz=fc / lead_ratio,
        f_lead_pole_hz=fc * lead_ratio, f_lp_hz=min(fc * lowpass_ratio, 0.45 * fs),
        lp_damping=lp_damping,
    )  # fmt: skip
    return PidNotchChannel(pid, tuple(notches), notch_depth_damping, notch_width_damping)


def _zfrf(num, den, f, fs):
    z = np.exp(2j * np.pi * np.asarray(f) / fs)
    return np.polyval(num, z) / np.polyval(den, z)


def _interp_complex(f, G, f0):
    """G at f0 by linear interpolation of log|G| and unwrapped phase over log f."""
    lf = np.log(f)
    mag = np.interp(np.log(f0), lf, np.log(np.abs(G)))
    ph = np.interp(np.log(f0), lf, np.unwrap(np.angle(G)))
    return np.exp(mag + 1j * ph)


def detect_modes(f, g, *, min_peak_ratio: float = 2.0) -> tuple[float, ...]:
    """Flexible-mode frequencies of a SISO FRF: peaks of |g| f^2 >= ratio x its low-frequency level.

    |g| f^2 is flat for a rigid body (1 / (m (2 pi f)^2)), so a resonance shows
    as a peak above the rigid-body line.
    """
    h = np.abs(g) * np.asarray(f) ** 2
    ref = np.median(h[: max(3, h.size // 20)])
    peaks, _ = scipy.signal.find_peaks(np.log(h), prominence=np.log(min_peak_ratio))
    return tuple(float(f[p]) for p in peaks if h[p] >= min_peak_ratio * ref)


def tune_pid_notch(
    plant,
    fs: float,
    *,
    ms_max: float = 2.0,
    loop_delay_samples: int = 0,
    notch_hz=None,
    lead_ratio=(3.0, 4.0, 5.0),
    integrator_ratio: float = 10.0,
    lowpass_ratio=(6.0, 8.0, 10.0),
    lp_damping: float = 0.7,
    notch_depth_damping: float = 0.02,
    notch_width_damping: float = 0.3,
    freq_hz=None,
    n_scan: int = 40,
    rel_tol: float = 1e-3,
    mimo_iterations: int = 30,
    mimo_step: float = 0.03,
) -> tuple[DecentralizedPidNotch, PidNotchReport]:
    """Tune the decentralized PID + low-pass + notches for the highest crossover per DOF.

    Parameters
    ----------
    plant : LTIModel, control.StateSpace or FrfData
        Square plant u -> y (the DOFs), continuous (exact ZOH at fs, with its
        delay_s) or discrete (dt = 1/fs), or measured FRF data (ZOH compensated).
    fs : float
        Controller sampling frequency, Hz.
    ms_max : float
        Bound on max |S_ii| (ratio; 2.0 = 6 dB).
    loop_delay_samples : int
        Computation delay of the real-time system, samples (in the loop, not in K).
    notch_hz : sequence (per DOF) of sequences of Hz, optional
        Notch centres; default detected per DOF with :func:`detect_modes`.
    lead_ratio, lowpass_ratio : float or sequence of float
        Shapes tried (every pair); per DOF the one reaching the highest fc is kept.
    integrator_ratio, lp_damping : float
        Shape relative to the crossover fc (see module docstring).
    freq_hz : (n_f,) array, optional
        Design lines for a model (default 4000 log lines fs/1e4 .. fs/2).
    n_scan, rel_tol
        Log-scan candidates and relative bisection tolerance on fc.
    mimo_iterations, mimo_step
        MIMO pass (square plants with n > 1): while a loop's |S_ii| with all the
        other loops closed exceeds ms_max, its crossover is re-tuned below
        (1 - mimo_step) times its current value, at most mimo_iterations rounds.

    Returns
    -------
    (DecentralizedPidNotch, PidNotchReport)

    Raises
    ------
    InputError
        A non-square plant, or a DOF where no crossover meets the bound.
    """
    from workbench import loop
    from workbench.core.lti import delay_frf, frf, zoh_frf
    from workbench.io.formats import FrfData

    fs = float(fs)
    m = loop._delay_check(loop_delay_samples)
    if isinstance(plant, FrfData):
        keep = plant.freq <= fs / 2
        f = plant.freq[keep]
        G = plant.G[keep] * (zoh_frf(f, fs) * delay_frf(f, m / fs))[:, None, None]

        def g_at(i, f0):
            return _interp_complex(f, G[:, i, i], f0)
    else:
        f = (
            np.logspace(np.log10(fs / 1e4), np.log10(fs / 2 * 0.9999), 4000)
            if freq_hz is None
            else np.asarray(freq_hz, float)
        )
        Gd = loop.discrete_plant(plant, fs, m)
        G = frf(Gd, f)

        def g_at(i, f0):
            return frf(Gd, [f0])[0, i, i]

    n = G.shape[1]
    if G.shape[2] != n:
        raise InputError(
            f"plant: expected a square plant (one actuator per DOF), got {G.shape[1:]}"
        )
    if notch_hz is None:  # detected modes: with their notches, and without (a notch costs phase)
        options = [[detect_modes(f, G[:, i, i]), ()] for i in range(n)]
    else:
        options = [[tuple(float(x) for x in np.atleast_1d(v))] for v in notch_hz]
    if len(options) != n:
        raise InputError(f"notch_hz: expected {n} entries (one per DOF), got {len(options)}")
    shapes = [
        (float(a), float(b))
        for a in np.atleast_1d(lead_ratio)
        for b in np.atleast_1d(lowpass_ratio)
    ]
    fixed = dict(
        integrator_ratio=integrator_ratio, lp_damping=lp_damping,
        notch_depth_damping=notch_depth_damping, notch_width_damping=notch_width_damping,
    )  # fmt: skip

    def design(i, fc, shape):
        lead, lowpass, notches = shape
        ch = _shape(fc, fs, notches, lead_ratio=lead, lowpass_ratio=lowpass, **fixed)
        gain = 1.0 / abs(g_at(i, fc) * ch.discrete_frf([fc], fs)[0])
        Li = G[:, i, i] * gain * ch.discrete_frf(f, fs)
        ok = np.max(np.abs(1 / (1 + Li))) <= ms_max and loop.nyquist_unstable_count(f, Li, fs) == 0
        return ok, gain, ch, Li

    def best_fc(i, shape, cap) -> float:
        """Largest fc <= cap meeting the bound for this shape (scan, then bisection); 0 if none."""
        f_hi = min(fs / 2 / max(shape[0], 1.0) * 0.95, cap)
        f_lo = max(f[0] * integrator_ratio * 3, fs / 5000)
        if f_hi <= f_lo:
            return 0.0
        cand = np.logspace(np.log10(f_lo), np.log10(f_hi), n_scan)
        good = np.flatnonzero([design(i, fc, shape)[0] for fc in cand])
        if good.size == 0:
            return 0.0
        j = int(good[-1])
        lo = cand[j]
        if j + 1 < cand.size:
            hi = cand[j + 1]
            while hi / lo - 1 > rel_tol:
                mid = np.sqrt(lo * hi)
                if design(i, mid, shape)[0]:
                    lo = mid
                else:
                    hi = mid
        return float(lo)

    def tune_dof(i, cap=np.inf):
        tried = {(a, b, nt) for a, b in shapes for nt in options[i]}
        found = [(best_fc(i, sh, cap), sh) for sh in sorted(tried)]
        fc, shape = max(found, key=lambda t: t[0])
        if fc <= 0:
            raise InputError(
                f"DOF {i}: no crossover and shape (lead_ratio, lowpass_ratio) in {shapes} "
                f"meets |S| <= {ms_max:g}" + ("" if np.isinf(cap) else f" below {cap:.4g} Hz")
            )
        _ok, gain, ch, Li = design(i, fc, shape)
        pid = ch.pid
        channel = PidNotchChannel(
            PidChannel(
                kp=gain, f_i_hz=pid.f_i_hz, f_lead_zero_hz=pid.f_lead_zero_hz,
                f_lead_pole_hz=pid.f_lead_pole_hz, f_lp_hz=pid.f_lp_hz,
                lp_damping=pid.lp_damping,
            ),
            ch.notch_hz, ch.notch_depth_damping, ch.notch_width_damping,
        )  # fmt: skip
        return fc, channel, float(np.max(np.abs(1 / (1 + Li))))

    dofs = [tune_dof(i) for i in range(n)]
    # MIMO pass: with every loop closed, loop-at-a-time |S_ii| may exceed the bound through
    # the coupling; lower the crossover of the offending loops until it does not
    for _ in range(mimo_iterations if n > 1 else 0):
        Kf = np.stack([ch.discrete_frf(f, fs) for _fc, ch, _p in dofs], axis=1)  # (n_f, n)
        S = np.linalg.inv(np.eye(n) + G * Kf[:, None, :])
        over = np.max(np.abs(np.diagonal(S, axis1=1, axis2=2)), axis=0) > ms_max * (1 + 1e-9)
        if not over.any():
            break
        for i in np.flatnonzero(over):
            dofs[i] = tune_dof(int(i), cap=dofs[i][0] * (1 - mimo_step))
    channels = [ch for _fc, ch, _p in dofs]
    fcs = [fc for fc, _ch, _p in dofs]
    peaks = [p for _fc, _ch, p in dofs]
    notch_used = [ch.notch_hz for ch in channels]
    K = DecentralizedPidNotch(
        tuple(channels), fs,
        input_names=tuple(loop._names(plant, "output")),
        output_names=tuple(loop._names(plant, "input")),
        delay_samples=m,
    )  # fmt: skip
    analysis = loop.analyze_loop(
        plant, K, loop_delay_samples=m, freq_hz=None if isinstance(plant, FrfData) else f
    )
    return K, PidNotchReport(tuple(fcs), tuple(peaks), tuple(notch_used), analysis)

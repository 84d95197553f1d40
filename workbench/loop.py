"""Frequency-domain analysis of a discrete feedback loop: L = G K, S, T, margins, stability.

The loop (spec section 5 sign convention): e = r - y, u = K e, y = G u, so the
loop gain at the plant output is ``L = G K`` (n_y x n_y), ``S = (I + L)^-1``
and ``T = L (I + L)^-1 = I - S``.

The plant is either

* a model (``LTIModel``, python-control ``StateSpace``; continuous with its
  ``delay_s``, or discrete with dt = 1/fs): it is discretized exactly behind a
  zero-order hold at the controller's rate (:func:`workbench.sim.discretize`,
  fractional delays included), so the analysis is that of the sampled loop,
  aliasing included; or
* a measured :class:`~workbench.io.formats.FrfData` (spec 1b, ZOH compensated):
  the loop uses ``G(jw) * ZOH(jw)`` (:func:`workbench.core.lti.zoh_frf`), i.e. the
  sampled loop without the aliasing of the plant's response above fs/2.

``loop_delay_samples`` adds the real-time system's computation delay
``z^-n`` between the controller output and the plant input.

Per-loop figures are *loop-at-a-time with the other loops closed*: loop i is
broken at output (sensor) i while every other loop stays closed, which gives
the SISO loop gain ``L_i = 1 / S_ii - 1`` with ``S_ii = [(I + G K)^-1]_ii``
(Skogestad & Postlethwaite, *Multivariable Feedback Control*, 2nd ed., sec. 10.6;
for a SISO loop L_i = L). Crossover, -3 dB bandwidth, |S|inf, the margins and
the Nyquist count of loop i all use this L_i; ``sigma_max_S_inf`` is the MIMO
peak of the largest singular value of S.

Disk margins (skew 0, "balanced", Seiler, Packard & Gahinet, "An Introduction
to Disk Margins", IEEE Control Systems Magazine 40(5), 2020, eq. 8-10): per loop

    alpha_i = 1 / max_w | (S_i - T_i) / 2 | = 1 / max_w | S_i - 1/2 |,

disk gain margin [(1 - alpha/2)/(1 + alpha/2), (1 + alpha/2)/(1 - alpha/2)]
(upper infinite when alpha >= 2) and disk phase margin 2 atan(alpha/2). On a
model, ``control.disk_margins`` of the state-space L_i gives them (checked
against the formula in the tests); on FRF data the formula is evaluated on the
measured lines.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from functools import cached_property

import numpy as np

from workbench.core.errors import InputError

__all__ = [
    "LoopFigures",
    "LoopAnalysis",
    "analyze_loop",
    "loop_frf",
    "save_loop_plots",
    "scaled_sigma_max",
    "screen_crossover",
    "screen_loops",
]


@dataclass(frozen=True)
class LoopFigures:
    """The figures of one loop (loop-at-a-time, the other loops closed).

    Frequencies in Hz, margins as ratios (gain) and degrees (phase); ``inf``
    when the loop has no such crossing, ``nan`` when not defined.
    """

    name: str
    crossover_hz: float
    bandwidth_hz: float  # lowest frequency where |S_i| rises through -3 dB
    s_peak: float  # max |S_i| (ratio; 2.0 = 6 dB)
    s_peak_hz: float
    gain_margin: float
    gain_margin_hz: float
    phase_margin_deg: float
    phase_margin_hz: float
    disk_margin: float  # alpha
    disk_gain_margin: float  # upper disk gain margin (ratio)
    disk_phase_margin_deg: float
    unstable_poles: int | None  # Nyquist count (FRF data) or None (model: see LoopAnalysis)


@dataclass(frozen=True)
class LoopAnalysis:
    """Result of :func:`analyze_loop`.

    Attributes
    ----------
    freq_hz : (n_f,) array
        Lines of the analysis, Hz.
    L, S, T : (n_f, n_y, n_y) complex arrays
        Loop gain G K at the plant output, sensitivity, complementary sensitivity.
    loops : tuple of LoopFigures
        One per output.
    sigma_max_S_inf : float
        max over the lines of the largest singular value of S. Depends on the
        outputs' units when they differ (m and rad on the stage).
    scaled_sigma_max_S_inf : float
        max over the lines of min over diagonal scalings D of sigma(D S D^-1)
        (:func:`scaled_sigma_max`): the same figure free of the outputs' units
        (and of any diagonal scaling); between max |S_ii| and sigma_max_S_inf.
    stable : bool or None
        Closed-loop stability: eigenvalues of the discrete closed loop (model)
        or the per-loop Nyquist counts (FRF data); None when undecided.
    stability_note : str
        How ``stable`` was decided, with its caveat.
    max_pole_radius : float or None
        Largest |eigenvalue| of the discrete closed loop (model only).
    source : str
        "model" or "frf".
    """

    freq_hz: np.ndarray
    L: np.ndarray
    S: np.ndarray
    T: np.ndarray
    loops: tuple[LoopFigures, ...]
    sigma_max_S_inf: float
    stable: bool | None
    stability_note: str
    max_pole_radius: float | None
    source: str
    fs: float
    loop_delay_samples: int

    @cached_property
    def scaled_sigma_max_S_inf(self) -> float:
        """max over the lines of min_D sigma(D S D^-1), :func:`scaled_sigma_max` (computed once)."""
        return float(np.max(scaled_sigma_max(self.S)))

    def summary(self) -> dict:
        """JSON-ready dict: the per-loop figures and the loop-wide ones (no arrays)."""
        return {
            "source": self.source,
            "fs": self.fs,
            "loop_delay_samples": self.loop_delay_samples,
            "stable": self.stable,
            "stability_note": self.stability_note,
            "max_pole_radius": self.max_pole_radius,
            "sigma_max_S_inf": self.sigma_max_S_inf,
            "scaled_sigma_max_S_inf": self.scaled_sigma_max_S_inf,
            "loops": [_json_floats(asdict(lp)) for lp in self.loops],
        }

    def to_json(self) -> str:
        """:meth:`summary` as a JSON string (inf / nan as strings)."""
        return json.dumps(self.summary(), indent=2)

    def table(self) -> str:
        """One row per loop: crossover, -3 dB bandwidth, |S|inf, margins, Nyquist count."""
        head = (
            f"{'loop':>6} {'fc Hz':>8} {'bw Hz':>8} {'|S|inf':>7} {'dB':>5} "
            f"{'GM dB':>6} {'PM deg':>7} {'DM':>5} {'DGM dB':>7} {'DPM deg':>7}"
        )
        rows = [head]
        for lp in self.loops:
            rows.append(
                f"{lp.name:>6} {lp.crossover_hz:8.1f} {lp.bandwidth_hz:8.1f} {lp.s_peak:7.3f} "
                f"{_db(lp.s_peak):5.1f} {_db(lp.gain_margin):6.1f} {lp.phase_margin_deg:7.1f} "
                f"{lp.disk_margin:5.2f} {_db(lp.disk_gain_margin):7.1f} "
                f"{lp.disk_phase_margin_deg:7.1f}"
            )
        rows.append(
            f"MIMO max sigma(S) = {self.sigma_max_S_inf:.3f} "
            f"({_db(self.sigma_max_S_inf):.1f} dB), scaled {self.scaled_sigma_max_S_inf:.3f} "
            f"({_db(self.scaled_sigma_max_S_inf):.1f} dB); "
            f"stable = {self.stable} ({self.stability_note})"
        )
        return "\n".join(rows)


def _db(x: float) -> float:
    return float(20 * np.log10(x)) if x > 0 else float("-inf")


def _json_floats(d: dict) -> dict:
    return {k: (str(v) if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


# ------------------------------------------------------------------ inputs
def _controller_ss(controller):
    """The discrete python-control StateSpace e -> u of a Controller or StateSpace."""
    import control

    sys = controller.statespace() if hasattr(controller, "step") else controller
    if not isinstance(sys, control.StateSpace):
        sys = control.ss(sys)
    if not sys.dt:
        raise InputError("controller: expected a discrete controller (dt = 1/fs), got dt = 0")
    return sys


def _is_frf(plant) -> bool:
    from workbench.io.formats import FrfData

    return isinstance(plant, FrfData)


def _delay_ss(n: int, m: int, dt: float):
    """z^-m on each of n channels as a discrete StateSpace."""
    import control

    if m == 0:
        return control.ss([], [], [], np.eye(n), dt)
    A = np.kron(np.eye(n), np.eye(m, k=-1))
    B = np.kron(np.eye(n), np.eye(m, 1))
    C = np.kron(np.eye(n), np.eye(1, m, m - 1))
    return control.ss(A, B, C, np.zeros((n, n)), dt)


def discrete_plant(plant, fs: float, loop_delay_samples: int = 0):
    """The sampled plant u_c -> y with the loop delay: a discrete StateSpace (dt = 1/fs).

    Continuous models are discretized exactly behind a ZOH with their own
    ``delay_s`` (:func:`workbench.sim.discretize`); the loop delay is
    ``loop_delay_samples`` shift states per input, ahead of the plant.
    """
    import control

    from workbench.core.model import as_model
    from workbench.sim import discretize

    model = as_model(plant)
    A, B, C, D = discretize(model, fs)
    G = control.ss(A, B, C, D, 1.0 / fs)
    if loop_delay_samples:
        G = G * _delay_ss(model.n_u, int(loop_delay_samples), 1.0 / fs)
    return G


def loop_frf(plant, controller, freq_hz=None, *, loop_delay_samples: int = 0):
    """(freq_hz, L) with L = G K (n_f, n_y, n_y) at the plant output, incl. ZOH and delays.

    ``freq_hz`` defaults to the FRF's own lines (FRF data) or 2000 log-spaced
    lines from fs/1e4 to fs/2 (models).
    """
    Ks = _controller_ss(controller)
    fs = 1.0 / float(Ks.dt)
    m = _delay_check(loop_delay_samples)
    if _is_frf(plant):
        f = plant.freq if freq_hz is None else np.asarray(freq_hz, float)
        if freq_hz is not None:
            raise InputError("freq_hz: FRF data is analysed on its own lines; give None")
        if f[-1] > fs / 2 * (1 + 1e-9):
            keep = f <= fs / 2
            f = f[keep]
            Gf = plant.G[keep]
        else:
            Gf = plant.G
        from workbench.core.lti import delay_frf, zoh_frf

        Gf = Gf * (zoh_frf(f, fs) * delay_frf(f, m / fs))[:, None, None]
    else:
        f = _default_grid(fs) if freq_hz is None else np.asarray(freq_hz, float)
        from workbench.core.lti import frf

        Gf = frf(discrete_plant(plant, fs, m), f)
    from workbench.core.lti import frf

    Kf = frf(Ks, f)
    if Gf.shape[2] != Kf.shape[1] or Kf.shape[2] != Gf.shape[1]:
        raise InputError(
            f"controller: expected {Gf.shape[1]} inputs (plant outputs) and {Gf.shape[2]} "
            f"outputs (plant inputs), got {Kf.shape[2]} inputs and {Kf.shape[1]} outputs"
        )
    return f, Gf @ Kf


def _delay_check(m) -> int:
    if int(m) != m or m < 0:
        raise InputError(f"loop_delay_samples: expected an integer >= 0, got {m!r}")
    return int(m)


def _default_grid(fs: float) -> np.ndarray:
    return np.logspace(np.log10(fs / 1e4), np.log10(fs / 2 * 0.9999), 2000)


def _names(obj, side: str) -> list[str]:
    """Channel names of a model / FrfData (``output_names``) or StateSpace (``output_labels``)."""
    got = getattr(obj, f"{side}_names", None) or getattr(obj, f"{side}_labels", None) or ()
    return [str(x) for x in got]


# ------------------------------------------------------------------ per-loop figures
def _first_crossing(f, x, level, *, rising: bool) -> float:
    """Lowest frequency where x passes ``level`` (rising or falling), log-interpolated."""
    above = x >= level
    idx = (
        np.flatnonzero(~above[:-1] & above[1:])
        if rising
        else np.flatnonzero(above[:-1] & ~above[1:])
    )
    if idx.size == 0:
        return float("nan")
    k = int(idx[0])
    lx0, lx1 = np.log(x[k]), np.log(x[k + 1])
    t = (np.log(level) - lx0) / (lx1 - lx0) if lx1 != lx0 else 0.0
    return float(np.exp(np.log(f[k]) + t * (np.log(f[k + 1]) - np.log(f[k]))))


def frf_margins(f, Li) -> tuple[float, float, float, float]:
    """(gm, f_gm, pm_deg, f_pm) of a SISO loop from its FRF, python-control's rule.

    Gain margins 1/|L| at every line pair where L crosses the negative real
    axis, phase margins 180 + arg L at every |L| = 1 crossing (linear
    interpolation between lines); like ``control.stability_margins`` the gain
    margin closest to 1 in log and the phase margin smallest in magnitude are
    returned (inf when there is no crossing).
    """
    gms, fgs, pms, fps = [], [], [], []
    im, re = Li.imag, Li.real
    for k in np.flatnonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0):
        t = im[k] / (im[k] - im[k + 1])
        r = re[k] + t * (re[k + 1] - re[k])
        if r < 0:
            gms.append(-1.0 / r)
            fgs.append(f[k] + t * (f[k + 1] - f[k]))
    mag = np.abs(Li)
    for k in np.flatnonzero(np.sign(mag[:-1] - 1) * np.sign(mag[1:] - 1) < 0):
        t = (1 - mag[k]) / (mag[k + 1] - mag[k])
        z = Li[k] + t * (Li[k + 1] - Li[k])
        pms.append(float(np.degrees(np.angle(-z))))
        fps.append(f[k] + t * (f[k + 1] - f[k]))
    gm = fgm = pm = fpm = float("inf")
    if gms:
        j = int(np.argmin(np.abs(np.log(gms))))
        gm, fgm = float(gms[j]), float(fgs[j])
    if pms:
        j = int(np.argmin(np.abs(pms)))
        pm, fpm = float(pms[j]), float(fps[j])
    return gm, fgm, pm, fpm


def disk_from_s(Si) -> tuple[float, float, float]:
    """(alpha, upper disk gain margin, disk phase margin deg) from S_i on a grid (skew 0)."""
    peak = float(np.max(np.abs(Si - 0.5)))
    alpha = 1.0 / peak if peak > 0 else float("inf")
    dgm = (1 + alpha / 2) / (1 - alpha / 2) if alpha < 2 else float("inf")
    dpm = float(np.degrees(2 * np.arctan(alpha / 2)))
    return alpha, dgm, dpm


def nyquist_unstable_count(f, Li, fs: float, open_loop_unstable: int = 0) -> int:
    """Closed-loop poles outside the unit circle of the SISO discrete loop L_i, by Nyquist.

    With k poles of L_i at z = 1 (integrators, from the low-frequency slope of
    |L_i|) and P open-loop poles outside the unit circle (given), the argument
    principle on the unit circle indented inside around z = 1 gives
    Z = k/2 + P - Delta / pi, Delta the net phase change of 1 + L_i from
    0+ to fs/2. Caveat: valid only when the lowest line lies on the
    low-frequency asymptote, the lines resolve every resonance, and the last
    line is near fs/2 (so 1 + L_i there is real).
    """
    if f.size < 3:
        raise InputError(f"Nyquist count: expected at least 3 lines, got {f.size}")
    slope = np.log(abs(Li[1]) / abs(Li[0])) / np.log(f[1] / f[0])
    k = max(int(round(-slope)), 0)
    ph = np.unwrap(np.angle(1 + Li))
    end = ph[-1]
    # close to fs/2 where 1 + L is real: finish the turn to the nearest multiple of pi
    delta = np.pi * round(end / np.pi) - ph[0]
    # start on the asymptote arg L(0+) = -k pi/2 (1 + L ~ L there)
    start_err = (ph[0] - (-k * np.pi / 2) + np.pi) % (2 * np.pi) - np.pi
    delta = delta + start_err
    return int(round(k / 2 + open_loop_unstable - delta / np.pi))


def _loop_figures(name, f, Si, Li, fs, *, count: bool, open_loop_unstable: int) -> dict:
    a = np.abs(Si)
    j = int(np.argmax(a))
    return dict(
        name=name,
        crossover_hz=_first_crossing(f, np.abs(Li), 1.0, rising=False),
        bandwidth_hz=_first_crossing(f, a, 1 / np.sqrt(2), rising=True),
        s_peak=float(a[j]),
        s_peak_hz=float(f[j]),
        unstable_poles=nyquist_unstable_count(f, Li, fs, open_loop_unstable) if count else None,
    )


def screen_loops(plant, controller, *, loop_delay_samples: int = 0, freq_hz=None):
    """(stable, s_peak (n,), crossover_hz (n,)): the fast per-loop score of design scans.

    ``stable`` from the eigenvalues of the model's exact ZOH closed loop with
    the loop delay; ``s_peak`` = max ``|S_ii|`` and ``crossover_hz`` the first
    fall of ``|L_i| = |1/S_ii - 1|`` through 1 on the lines (nan: none) - the
    figures :func:`analyze_loop` reports, without its margins. Models only.
    An unstable loop returns inf peaks and nan crossovers (no FRF computed).
    """
    from workbench.core.lti import as_matrices
    from workbench.sim import closed_loop_matrices

    m = _delay_check(loop_delay_samples)
    Ks = _controller_ss(controller)
    fs = 1.0 / float(Ks.dt)
    G = discrete_plant(plant, fs, m)
    n = G.noutputs
    Acl = closed_loop_matrices(as_matrices(G)[:4], as_matrices(Ks)[:4])[0]
    if Acl.size and np.max(np.abs(np.linalg.eigvals(Acl))) >= 1.0:
        return False, np.full(n, np.inf), np.full(n, np.nan)
    f, L = loop_frf(plant, controller, freq_hz, loop_delay_samples=m)
    S = np.linalg.inv(np.eye(L.shape[1]) + L)
    Sii = np.diagonal(S, axis1=1, axis2=2)
    peak = np.max(np.abs(Sii), axis=0)
    fc = np.array(
        [_first_crossing(f, np.abs(1 / Sii[:, i] - 1), 1.0, rising=False) for i in range(n)]
    )
    return True, peak, fc


def screen_crossover(
    plant, controller, *, loop_delay_samples: int = 0, freq_hz=None, ms_max: float = 2.0
) -> float:
    """Lowest per-loop crossover (Hz) of a stable loop meeting ``|S_ii| <= ms_max``, else 0.

    :func:`screen_loops` reduced to one number: 0.0 when unstable, over the
    bound, or when a loop has no crossover on the lines.
    """
    stable, peak, fc = screen_loops(
        plant, controller, loop_delay_samples=loop_delay_samples, freq_hz=freq_hz
    )
    if not stable or np.max(peak) > ms_max or not np.all(np.isfinite(fc)):
        return 0.0
    return float(np.min(fc))


def scaled_sigma_max(M) -> np.ndarray:
    """min over positive diagonal D of sigma_max(D M D^-1), per line; (n_f,) from (n_f, n, n).

    The largest singular value of a MIMO sensitivity depends on the outputs'
    units (m against rad on the stage: an off-diagonal S_ij has units of y_i / y_j);
    its minimum over diagonal similarity scalings does not, and lies between
    the spectral radius of M and sigma_max(M) (it is the D-scaled upper bound of
    the structured singular value for a diagonal uncertainty; Skogestad &
    Postlethwaite, *Multivariable Feedback Control*, 2nd ed., sec. 8.8).
    ``log sigma(e^L M e^-L)`` is convex in the diagonal L (Sezginer & Overton,
    "The largest singular value of e^X A e^-X is convex on convex sets of
    commuting matrices", IEEE TAC 35(2), 1990), so a local minimizer is global;
    the gradient is sigma (|u_i|^2 - |v_i|^2) with u, v the singular vectors.

    Every line gets the Perron scaling of |M| (D = sqrt(y / x), x and y the
    right and left Perron vectors: sigma(D M D^-1) <= rho(|M|) there, a cheap
    upper bound); the minimization then runs at the lines in decreasing order
    of that bound until no remaining bound exceeds the best minimum found, so
    the MAXIMUM over the lines is exact while most lines keep their bound.
    """
    from scipy.optimize import minimize

    M = np.asarray(M, complex)
    if M.ndim == 2:
        M = M[None]
    n_f, n, _ = M.shape
    if n == 1:
        return np.abs(M[:, 0, 0])

    def sigma(Mk, lv):
        d = np.exp(lv)
        return np.linalg.svd(d[:, None] * Mk / d[None, :], compute_uv=False)[0]

    def perron_scaling(Ak):
        w, V = np.linalg.eig(Ak)
        k = int(np.argmax(w.real))
        x = np.abs(V[:, k])
        w2, V2 = np.linalg.eig(Ak.T)
        y = np.abs(V2[:, int(np.argmax(w2.real))])
        tiny = 1e-300
        return 0.5 * (np.log(y + tiny) - np.log(x + tiny))

    starts = np.array([perron_scaling(np.abs(Mk)) for Mk in M])
    bound = np.array([sigma(Mk, lv) for Mk, lv in zip(M, starts)])
    plain = np.linalg.svd(M, compute_uv=False)[:, 0]
    starts = np.where((bound <= plain)[:, None], starts, 0.0)
    bound = np.minimum(bound, plain)
    out = bound.copy()

    def cost(lfree, Mk):
        lv = np.concatenate([[0.0], lfree])
        d = np.exp(lv)
        U, s, Vh = np.linalg.svd(d[:, None] * Mk / d[None, :])
        g = np.abs(U[:, 0]) ** 2 - np.abs(Vh[0, :]) ** 2
        return np.log(s[0]), g[1:]

    best = 0.0
    for k in np.argsort(bound)[::-1]:
        if bound[k] <= best:
            break
        l0 = starts[k][1:] - starts[k][0]
        res = minimize(cost, l0, args=(M[k],), jac=True, method="BFGS", options={"gtol": 1e-9})
        out[k] = min(bound[k], float(np.exp(res.fun)))
        best = max(best, out[k])
    return out


# ------------------------------------------------------------------ the analysis
def analyze_loop(
    plant,
    controller,
    *,
    loop_delay_samples: int = 0,
    freq_hz=None,
    loop_names=None,
    open_loop_unstable: int = 0,
) -> LoopAnalysis:
    """Analyse the loop of a plant (model or FRF data) with a discrete controller.

    Parameters
    ----------
    plant : LTIModel, control.StateSpace or FrfData
        Plant u -> y (m/N). A continuous model keeps its ``delay_s``.
    controller : Controller or discrete control.StateSpace
        e -> u, dt = 1/fs.
    loop_delay_samples : int
        Computation delay of the real-time system, samples.
    freq_hz : (n_f,) array, optional
        Analysis lines for a model (default 2000 log lines fs/1e4 .. fs/2).
    loop_names : sequence of str, optional
        Names of the loops (default the plant's output names, else y0, y1, ...).
    open_loop_unstable : int
        Poles of each L_i outside the unit circle (FRF data only; default 0).

    Returns
    -------
    LoopAnalysis
        Margins from ``control.stability_margins`` (on the FRD of the exact
        response of L_i on the lines) and ``control.disk_margins`` (of the
        state-space L_i) for a model or from the lines (FRF); stability from
        the closed loop's eigenvalues (model) or the Nyquist count per loop.
    """
    import control

    m = _delay_check(loop_delay_samples)
    Ks = _controller_ss(controller)
    fs = 1.0 / float(Ks.dt)
    f, L = loop_frf(plant, controller, freq_hz, loop_delay_samples=m)
    n = L.shape[1]
    if L.shape[2] != n:
        raise InputError(f"loop: expected a square loop G K, got {L.shape[1:]}")
    eye = np.eye(n)
    S = np.linalg.inv(eye + L)
    T = eye - S
    sig = float(np.max(np.linalg.svd(S, compute_uv=False)[:, 0]))
    names = list(loop_names) if loop_names else _names(plant, "output")
    if len(names) != n:
        names = [f"y{i}" for i in range(n)]
    is_frf = _is_frf(plant)
    loops = []
    if is_frf:
        for i in range(n):
            Si = S[:, i, i]
            Li = 1.0 / Si - 1.0
            d = _loop_figures(
                names[i], f, Si, Li, fs, count=True, open_loop_unstable=open_loop_unstable
            )
            gm, fgm, pm, fpm = frf_margins(f, Li)
            alpha, dgm, dpm = disk_from_s(Si)
            loops.append(
                LoopFigures(
                    **d, gain_margin=gm, gain_margin_hz=fgm, phase_margin_deg=pm,
                    phase_margin_hz=fpm, disk_margin=alpha, disk_gain_margin=dgm,
                    disk_phase_margin_deg=dpm,
                )
            )  # fmt: skip
        counts = [lp.unstable_poles for lp in loops]
        stable = all(c == 0 for c in counts)
        note = (
            "Nyquist per loop on the FRF lines (assumes the lines resolve every resonance, "
            f"the lowest on the integrator asymptote, {open_loop_unstable} open-loop unstable "
            "poles per loop; loop-at-a-time counts do not prove MIMO stability)"
        )
        radius = None
    else:
        G = discrete_plant(plant, fs, m)
        Lss = G * Ks
        w = 2 * np.pi * f
        for i in range(n):
            E = eye.copy()
            E[i, i] = 0.0
            Li_ss = control.feedback(Lss, control.ss([], [], [], E, Lss.dt))[i, i]
            Si = S[:, i, i]
            d = _loop_figures(
                names[i], f, Si, 1.0 / Si - 1.0, fs, count=False, open_loop_unstable=0
            )
            # python-control on the exact response of L_i: its polynomial path converts
            # to a transfer function, ill-conditioned for high-order discrete loops
            Li_frd = control.frd(1.0 / Si - 1.0, w, dt=Lss.dt, smooth=True)
            gm, pm, _sm, wg, wp, _ws = control.stability_margins(Li_frd)
            # control.disk_margins returns the disk gain margin in dB
            alpha, dgm_db, dpm = control.disk_margins(Li_ss, w, skew=0.0)
            dgm = 10 ** (float(dgm_db) / 20) if np.isfinite(dgm_db) else float("inf")
            loops.append(
                LoopFigures(
                    **d, gain_margin=float(gm), gain_margin_hz=float(wg) / (2 * np.pi),
                    phase_margin_deg=float(pm), phase_margin_hz=float(wp) / (2 * np.pi),
                    disk_margin=float(alpha), disk_gain_margin=float(dgm),
                    disk_phase_margin_deg=float(dpm),
                )
            )  # fmt: skip
        from workbench.core.lti import as_matrices
        from workbench.sim import closed_loop_matrices

        Acl = closed_loop_matrices(as_matrices(G)[:4], as_matrices(Ks)[:4])[0]
        radius = float(np.max(np.abs(np.linalg.eigvals(Acl)))) if Acl.size else 0.0
        stable = radius < 1.0
        note = "eigenvalues of the discrete closed loop (exact ZOH plant, loop delay as states)"
    return LoopAnalysis(
        freq_hz=f, L=L, S=S, T=T, loops=tuple(loops), sigma_max_S_inf=sig,
        stable=stable,
        stability_note=note, max_pole_radius=radius, source="frf" if is_frf else "model",
        fs=fs, loop_delay_samples=m,
    )  # fmt: skip


# ------------------------------------------------------------------ plots
def save_loop_plots(result: LoopAnalysis, out_dir) -> list[str]:
    """Bode of L_ii, |S_ii| / |T_ii| with max sigma(S), and Nyquist of L_i, as PNGs.

    Returns the written paths (``loop_bode.png``, ``loop_sensitivity.png``,
    ``loop_nyquist.png`` in ``out_dir``).
    """
    import os

    from workbench.plotting import new_figure, save_png

    os.makedirs(out_dir, exist_ok=True)
    f = result.freq_hz
    n = result.L.shape[1]
    paths = []

    fig = new_figure(8, 6)
    ax_m, ax_p = fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2)
    for i, lp in enumerate(result.loops):
        Li = 1.0 / result.S[:, i, i] - 1.0
        ax_m.loglog(f, np.abs(Li), label=lp.name)
        ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(Li))))
    ax_m.axhline(1.0, color="k", lw=0.5)
    ax_m.set_ylabel("|L_i|")
    ax_m.legend(fontsize=7, ncol=min(n, 6))
    ax_p.set_ylabel("phase L_i (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    paths.append(os.path.join(out_dir, "loop_bode.png"))
    save_png(fig, paths[-1])

    fig = new_figure(8, 4)
    ax = fig.add_subplot(1, 1, 1)
    for i, lp in enumerate(result.loops):
        ax.semilogx(f, 20 * np.log10(np.abs(result.S[:, i, i])), label=f"S {lp.name}")
        ax.semilogx(f, 20 * np.log10(np.abs(result.T[:, i, i]) + 1e-300), ls="--")
    sv = np.linalg.svd(result.S, compute_uv=False)[:, 0]
    ax.semilogx(f, 20 * np.log10(sv), "k", lw=1.5, label="max sigma(S)")
    ax.axhline(6.0, color="r", lw=0.5)
    ax.set_ylim(-60, 20)
    ax.set_ylabel("dB")
    ax.set_xlabel("frequency (Hz)")
    ax.legend(fontsize=7, ncol=3)
    paths.append(os.path.join(out_dir, "loop_sensitivity.png"))
    save_png(fig, paths[-1])

    fig = new_figure(6, 6)
    ax = fig.add_subplot(1, 1, 1)
    for i, lp in enumerate(result.loops):
        Li = 1.0 / result.S[:, i, i] - 1.0
        keep = np.abs(Li) < 10
        ax.plot(Li.real[keep], Li.imag[keep], label=lp.name)
    t = np.linspace(0, 2 * np.pi, 200)
    ax.plot(-1 + 0.5 * np.cos(t), 0.5 * np.sin(t), "r", lw=0.5)  # |S| = 2 circle
    ax.plot([-1], [0], "r+")
    ax.set_xlim(-3, 1)
    ax.set_ylim(-2, 2)
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    paths.append(os.path.join(out_dir, "loop_nyquist.png"))
    save_png(fig, paths[-1])
    return paths

"""Output-error least squares on a time record: B, D and x0, simulation fit, offsets.

One implementation of "simulate the model with its initial state estimated
and compute the fit", used by :func:`workbench.ident.identify_subspace`
(B, D, x0 jointly for open-loop methods), ``workbench identify --validate``,
the order scan and :func:`workbench.validate.compare.compare` on time data.

The output of a discrete model ``x[k+1] = A x[k] + B u[k]``,
``y[k] = C x[k] + D u[k]`` is linear in ``theta = [x0; vec(B); vec(D)]``
(``vec`` column-major):

    y[k] = C A^k x0 + sum_{t<k} u[t]^T kron C A^(k-1-t) vec(B) + (u[k]^T kron I) vec(D)

(SLICOT IB01CD; Van Overschee & De Moor 1996, sec. 4.3, "robust"
algorithm). The regressor rows for ``B`` are kept as *row states*
``S_p[k] = sum_{t<k} u_p[t] C A^(k-1-t)`` (l x n per input) obeying
``S_p[k+1] = S_p[k] A + u_p[k] C``, generated chunk by chunk (powers of A
for the carried part, a Toeplitz product for the forced part), so the
regressor never exists for the whole record. Each chunk of ``T`` samples,
``(T l) x (n + n m + l m)``, is folded into the normal equations, so the
memory is ``O(T l P + P^2)`` with ``P = n + n m + l m`` whatever N: for
N = 1e6, l = m = 6, n = 16 (``P = 148``) the dense regressor would take
7 GB; the chunks take a few MB. The normal equations square the condition
number, so the solution is refined on the residual (another pass over the
regenerated chunks), which restores the accuracy of a QR of the regressor
on a noise-free record (a chunked QR took 8x longer). Work is
``O(N l P^2)``, one matrix product per chunk.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.core.arrays import readonly
from workbench.core.errors import InputError
from workbench.io.formats import TimeData

__all__ = [
    "Fit",
    "Offsets",
    "fit_percent",
    "least_squares_bd_x0",
    "estimate_x0",
    "simulate",
    "simulation_fit",
    "remove_offsets",
    "offset_warning",
    "split_record",
    "DivergentModel",
    "check_growth",
]


# ----------------------------------------------------------------- regressor
def _regressor_chunks(A, C, u, *, su=None, with_x0=True, with_bd=True, feedthrough=True):
    """Yield ``(k0, Phi)`` with ``Phi`` (T, l, P): the regressor of samples k0 .. k0+T-1.

    Columns: ``x0`` (n, if ``with_x0``), ``vec(B)`` (n m, index ``q + n p``)
    and ``vec(D)`` (l m, index ``j + l p``, if ``feedthrough``), for the
    input ``u / su`` (scaled chunk by chunk: no copy of the record).

    Within a chunk starting at ``k0`` the row states are
    ``S_p[k0 + t] = S_p[k0] A^t + sum_{s<t} u_p[k0 + s] C A^(t-1-s)``: the
    carried part from the powers ``A^t`` (computed once), the forced part a
    lower-triangular Toeplitz matrix of the chunk's inputs times the Markov
    rows ``C A^tau``: two matrix products per chunk, no loop over samples.
    The chunk is short (``4 n`` samples, 64 to 256; longer for tiny models, to
    bound the per-chunk overhead) so that the Toeplitz product costs about
    what the carried part does.
    """
    n, l = A.shape[0], C.shape[0]
    N, m = u.shape
    m_b = m if with_bd else 0
    T = int(min(max(4 * n, 64, 4096 // max(1, m * l * n)), 256, N))
    # A^0 .. A^T and the Markov rows M[tau] = C A^tau, tau = 0 .. T-1
    Apow = np.empty((T + 1, n, n))
    Apow[0] = np.eye(n)
    for t in range(1, T + 1):
        Apow[t] = Apow[t - 1] @ A
    M = (C @ Apow[:T]).reshape(T, l * n)
    S = np.zeros((1 + m_b, l, n))  # S[0] = C A^k, S[1 + p] = row state of input p
    S[0] = C
    for k0 in range(0, N, T):
        uc = u[k0 : k0 + T]
        if su is not None:
            uc = uc / su
        Tc = uc.shape[0]
        # block[t] = S[k0 + t], t = 0 .. Tc (the last one carries to the next chunk)
        block = np.matmul(S.reshape(1, -1, n), Apow[: Tc + 1]).reshape(Tc + 1, 1 + m_b, l, n)
        if m_b:
            # Toeplitz U[t, p, tau] = u_p[k0 + t - 1 - tau] (0 before k0): reversed
            # windows of the zero-padded chunk, a strided view
            padded = np.zeros((2 * Tc, m))
            padded[Tc:] = uc
            win = np.lib.stride_tricks.sliding_window_view(padded, Tc, axis=0)  # (Tc+1, m, Tc)
            U = win[:, :, ::-1]
            forced = U.reshape((Tc + 1) * m, Tc) @ M[:Tc]
            block[:, 1:] += forced.reshape(Tc + 1, m, l, n)
        S = block[Tc].copy()
        block = block[:Tc]
        parts = []
        if with_x0:
            parts.append(block[:, 0])
        if with_bd:
            parts.append(block[:, 1:].transpose(0, 2, 1, 3).reshape(Tc, l, m * n))
            if feedthrough:
                Dp = np.zeros((Tc, l, m, l))
                idx = np.arange(l)
                Dp[:, idx, :, idx] = uc[None]  # advanced indices first: (l, Tc, m)
                parts.append(Dp.reshape(Tc, l, m * l))
        yield k0, np.concatenate(parts, axis=2)


class DivergentModel(ValueError):
    """The model's response grows beyond what the record's least squares can hold."""


def check_growth(A: np.ndarray, n_samples: int, *, limit: float = 1e8) -> None:
    """Raise :class:`DivergentModel` when ``rho(A)^N`` exceeds ``limit``.

    An unstable A makes the x0 and B columns grow as ``rho^k``: beyond
    ``1e8`` over the record the least squares loses the early samples to
    rounding (and overflows for long records), and the simulation fit is
    meaningless.
    """
    if A.size == 0:
        return
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    if rho > 1.0 and n_samples * np.log(rho) > np.log(limit):
        raise DivergentModel(
            f"the model is unstable (spectral radius {rho:.4g}): its response grows by "
            f"{rho:.4g}^{n_samples} over the record"
        )


def _solve_chunked(make_chunks, target, *, max_refine: int = 3) -> np.ndarray:
    """Least-squares ``theta`` of ``Phi theta = target`` from regressor chunks.

    ``make_chunks()`` returns a fresh generator of ``(k0, Phi)``;
    ``target(k0, T)`` the (T, l) right-hand side of a chunk. The normal
    equations are accumulated with one matrix product per chunk (``P x P``
    memory) and solved with the columns equilibrated; since they square the
    condition number, the solution is then refined on the residual
    (``Phi^T (target - Phi theta)``, one more pass over the regenerated
    chunks per step) until the correction is below 1e-10 of ``theta``: the
    accuracy of a QR of the regressor at a fraction of its cost.
    """
    G = g = None
    for k0, Phi in make_chunks():
        if not np.all(np.isfinite(Phi)):
            raise DivergentModel("the regressor overflows (an unstable model)")
        T, l, P = Phi.shape
        X = Phi.reshape(T * l, P)
        z = target(k0, T).reshape(T * l)
        if G is None:
            G, g = X.T @ X, X.T @ z
        else:
            G += X.T @ X
            g += X.T @ z
    d = np.sqrt(np.diag(G))
    d[d == 0] = 1.0
    lam, V = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > lam[-1] * 1e-14
    W = V[:, keep] / lam[keep]

    def solve(rhs):
        return (W @ (V[:, keep].T @ (rhs / d))) / d

    theta = solve(g)
    for _ in range(max_refine):
        r = np.zeros_like(theta)
        for k0, Phi in make_chunks():
            T, l, P = Phi.shape
            X = Phi.reshape(T * l, P)
            r += X.T @ (target(k0, T).reshape(T * l) - X @ theta)
        delta = solve(r)
        theta = theta + delta
        if np.linalg.norm(delta) <= 1e-10 * np.linalg.norm(theta):
            break
    return theta


def least_squares_bd_x0(A, C, u, y, *, su=None, sy=None, feedthrough=True):
    """``B``, ``D`` and ``x0`` jointly by least squares on the simulated output.

    Parameters
    ----------
    A : (n, n) array
    C : (l, n) array
        Estimated A and C (of the scaled data if ``su``, ``sy`` are given).
    u : (N, m) array
        Input record (not copied: scaled chunk by chunk by ``su``).
    y : (N, l) array
        Output record (scaled by ``sy``).
    su, sy : (m,), (l,) arrays, optional
        Channel scales; the model is that of ``u / su`` to ``y / sy``.
    feedthrough : bool
        Estimate D; else ``D = 0``.

    Returns
    -------
    B : (n, m), D : (l, m), x0 : (n,)

    Raises
    ------
    DivergentModel
        A is so unstable that its response grows by more than 1e8 over the record.
    """
    n, l = A.shape[0], C.shape[0]
    m = u.shape[1]
    check_growth(A, u.shape[0])

    def target(k0, T):
        yc = y[k0 : k0 + T]
        return yc / sy if sy is not None else yc

    theta = _solve_chunked(
        lambda: _regressor_chunks(
            A, C, u, su=su, with_x0=True, with_bd=True, feedthrough=feedthrough
        ),
        target,
    )
    x0 = theta[:n]
    B = theta[n : n + n * m].reshape(m, n).T
    D = theta[n + n * m :].reshape(m, l).T if feedthrough else np.zeros((l, m))
    return B, D, x0


def _matrices(model):
    from workbench.core.lti import as_matrices

    A, B, C, D, dt = as_matrices(model)
    if not dt:
        raise InputError(
            "model: expected a discrete model (dt > 0) for the simulation fit, got a continuous one"
        )
    return A, B, C, D, dt


def simulate(model, u: np.ndarray, x0=None) -> np.ndarray:
    """Output (N, l) of a discrete model for the input ``u`` (N, m) from the state ``x0``."""
    from workbench.sim import simulate_zoh

    _, _, _, _, dt = _matrices(model)
    return simulate_zoh(model, np.asarray(u, float), 1.0 / dt, x0=x0)


def estimate_x0(model, u: np.ndarray, y: np.ndarray, *, weighted: bool = True) -> np.ndarray:
    """Initial state (n,) minimizing ``||y - y_sim(x0)||`` for a known model (least squares).

    ``weighted``: each output's error divided by the rms of its ``y`` (outputs in their own
    units, as the simulation fit weighs them); False: the plain Frobenius norm over all
    outputs, the spec's relative error (compare's estimated start).
    """
    A, _, C, _, _ = _matrices(model)
    check_growth(A, u.shape[0])
    y_forced = simulate(model, u)
    if A.shape[0] == 0:
        return np.zeros(0)
    sy = np.sqrt(np.mean(y**2, axis=0)) if weighted else np.ones(y.shape[1])
    sy[sy == 0] = 1.0
    Cs = C / sy[:, None]  # each output in its own unit, as the fit weighs them

    def target(k0, T):
        return (y[k0 : k0 + T] - y_forced[k0 : k0 + T]) / sy

    return _solve_chunked(lambda: _regressor_chunks(A, Cs, u, with_x0=True, with_bd=False), target)


def fit_percent(y: np.ndarray, y_sim: np.ndarray) -> np.ndarray:
    """``100 (1 - ||y - y_sim|| / ||y - mean y||)`` per output (l,), percent."""
    y = np.asarray(y, float)
    num = np.linalg.norm(y - y_sim, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    return 100.0 * (1.0 - num / np.where(den > 0, den, np.inf))


@dataclass(frozen=True)
class Fit:
    """Simulation fit of a model on a record, initial state estimated.

    Attributes
    ----------
    fit : (l,) array
        ``100 (1 - ||y - y_sim|| / ||y - mean y||)`` per output, percent.
    mean : float
        Mean of ``fit`` over the outputs, percent.
    x0 : (n,) array
        Initial state, least squares (``x0_estimated``) or zero.
    y_sim : (N, l) array
        Simulated output (delay-aligned: ``y_sim[k]`` pairs with ``y[k + delay]``).
    x0_estimated : bool
    note : str
        Why the fit is ``-inf`` (a diverging, unstable model), else empty.
    """

    fit: np.ndarray
    mean: float
    x0: np.ndarray
    y_sim: np.ndarray = field(repr=False)
    x0_estimated: bool = True
    note: str = ""

    def __post_init__(self):
        for name in ("fit", "x0", "y_sim"):
            object.__setattr__(self, name, readonly(getattr(self, name), float))

    def as_dict(self) -> dict:
        return {
            "fit_percent": [float(v) for v in self.fit],
            "mean_fit_percent": float(self.mean),
            "initial_state": (
                "estimated by least squares" if self.x0_estimated else "zero (from rest)"
            ),
            **({"note": self.note} if self.note else {}),
        }

    def describe(self, names=None) -> str:
        names = names or [f"y{k}" for k in range(self.fit.size)]
        if self.note:
            return f"fit -inf ({self.note})"
        per = ", ".join(f"{n} {v:.1f} %" for n, v in zip(names, self.fit))
        how = "initial state by least squares" if self.x0_estimated else "from rest"
        return f"fit {self.mean:.1f} % (mean; {per}; {how})"


def simulation_fit(model, data: TimeData, *, input_delay: int = 0, estimate: bool = True) -> Fit:
    """Fit of ``model`` on ``data``: simulate with ``x0`` by least squares, compare.

    The model's own delay (an :class:`~workbench.core.model.LTIModel`'s ``delay_s``,
    a whole number of samples) plus ``input_delay`` (samples) pairs ``y[k]``
    with ``u[k - delay]`` as in identification; the first ``delay`` outputs
    are not scored.
    """
    from workbench.core.model import as_model

    lti_model = as_model(model)
    own = lti_model.delay_s / lti_model.dt if lti_model.dt else 0.0
    if lti_model.delay_s and (not lti_model.dt or abs(own - round(own)) > 1e-6):
        raise InputError(
            f"model: expected a discrete model delayed by whole samples, got delay_s = "
            f"{lti_model.delay_s:g} s with dt = {lti_model.dt:g} s"
        )
    if lti_model.delay_s:  # the delay is applied by trimming u and y, not in the simulation
        model = lti_model.without_delay()
    d = int(input_delay) + int(round(own))
    if d < 0 or d >= data.n_samples:
        raise InputError(f"input_delay: expected 0 <= delay < {data.n_samples}, got {d}")
    u = data.u[: data.n_samples - d]
    y = data.y[d:]
    A = _matrices(model)[0]
    n = A.shape[0]
    try:
        check_growth(A, u.shape[0])
        x0 = estimate_x0(model, u, y) if estimate else None
        with np.errstate(over="ignore", invalid="ignore"):
            y_sim = simulate(model, u, x0)
        if not np.all(np.isfinite(y_sim)):
            raise DivergentModel("the simulation overflows (an unstable model)")
    except DivergentModel as exc:
        return Fit(
            fit=np.full(y.shape[1], -np.inf),
            mean=-np.inf,
            x0=np.zeros(n),
            y_sim=np.full(y.shape, np.nan),
            x0_estimated=False,
            note=str(exc),
        )
    f = fit_percent(y, y_sim)
    return Fit(
        fit=f,
        mean=float(np.mean(f)),
        x0=np.zeros(n) if x0 is None else x0,
        y_sim=y_sim,
        x0_estimated=bool(estimate),
    )


# ------------------------------------------------------------------ offsets
@dataclass(frozen=True)
class Offsets:
    """Per-channel offset (and slope) removed from a record before identification.

    The model maps ``u - u_offset - u_slope t`` to ``y - y_offset - y_slope t``
    (``t`` in s from the first sample of the identification record); a
    prediction adds ``y_offset + y_slope t`` back.
    """

    mode: str
    u_offset: np.ndarray
    y_offset: np.ndarray
    u_slope: np.ndarray
    y_slope: np.ndarray

    def __post_init__(self):
        for name in ("u_offset", "y_offset", "u_slope", "y_slope"):
            object.__setattr__(self, name, readonly(getattr(self, name), float))

    def apply(self, data: TimeData, *, t0: float = 0.0) -> TimeData:
        """``data`` with the offsets removed; ``t0`` (s): its first sample's time."""
        import dataclasses

        t = t0 + np.arange(data.n_samples) / data.fs
        u = data.u - self.u_offset - np.outer(t, self.u_slope)
        y = data.y - self.y_offset - np.outer(t, self.y_slope)
        r = data.r
        if r is not None:
            r = r - self.u_offset - np.outer(t, self.u_slope)
        return dataclasses.replace(data, u=u, y=y, r=r)

    def as_dict(self) -> dict:
        return {
            "mode": self.mode,
            "u_offset": self.u_offset.tolist(),
            "y_offset": self.y_offset.tolist(),
            "u_slope_per_s": self.u_slope.tolist(),
            "y_slope_per_s": self.y_slope.tolist(),
            "note": "the model maps u - (u_offset + u_slope t) to y - (y_offset + y_slope t), "
            "t in s from the first identification sample; predictions add "
            "y_offset + y_slope t back",
        }


def _line(x: np.ndarray, fs: float):
    """Per-channel least-squares line ``a + b t`` (t in s): (a, b)."""
    N = x.shape[0]
    t = np.arange(N) / fs
    tc = t - t.mean()
    b = tc @ (x - x.mean(axis=0)) / (tc @ tc) if N > 1 else np.zeros(x.shape[1])
    a = x.mean(axis=0) - b * t.mean()
    return a, b


def remove_offsets(data: TimeData, mode: str) -> tuple[TimeData, Offsets]:
    """Remove per-channel means (``"mean"``) or lines (``"linear"``) from u, y (and r)."""
    if mode not in ("none", "mean", "linear"):
        raise InputError(f"detrend: expected 'none', 'mean' or 'linear', got {mode!r}")
    zu, zy = np.zeros(data.n_u), np.zeros(data.n_y)
    if mode == "none":
        return data, Offsets("none", zu, zy, zu, zy)
    if mode == "mean":
        off = Offsets("mean", data.u.mean(axis=0), data.y.mean(axis=0), zu, zy)
    else:
        au, bu = _line(data.u, data.fs)
        ay, by = _line(data.y, data.fs)
        off = Offsets("linear", au, ay, bu, by)
    return off.apply(data), off


def offset_warning(
    data: TimeData, *, mean_threshold: float = 0.1, trend_threshold: float = 0.25
) -> str | None:
    """One line naming the channels whose mean or linear trend is large against their rms.

    The size of a trend is its change over the record (``|b| T``); the rms is
    that of the channel with its line removed. A mean above
    ``mean_threshold`` x rms or a trend above ``trend_threshold`` x rms is
    reported (a coloured stationary signal fits a line of a few tenths of its
    rms over a short record by chance, hence the larger trend threshold).
    None when no channel exceeds.
    """
    found = []
    for key, x in (("u", data.u), ("y", data.y)):
        a, b = _line(x, data.fs)
        span = np.abs(b) * (data.n_samples - 1) / data.fs
        resid = x - a - np.outer(np.arange(data.n_samples) / data.fs, b)
        rms = np.sqrt(np.mean(resid**2, axis=0))
        rms[rms == 0] = np.inf
        mean = np.abs(x.mean(axis=0))
        for k in range(x.shape[1]):
            what = []
            if mean[k] > mean_threshold * rms[k]:
                what.append(f"mean {x[:, k].mean():.3g}")
            if span[k] > trend_threshold * rms[k]:
                what.append(f"trend {span[k]:.3g} over the record")
            if what:
                found.append(f"{key}{k} ({', '.join(what)}; rms {rms[k]:.3g})")
    if not found:
        return None
    return (
        "non-zero mean or trend in "
        + "; ".join(found)
        + ": use --detrend mean or --detrend linear to remove it (kept in the report)"
    )


def split_record(data: TimeData, fraction: float) -> tuple[TimeData, TimeData]:
    """First ``1 - fraction`` of the samples for identification, the rest for validation.

    A periodic record is cut at the period boundary nearest to the fraction, so
    that both parts stay periodic.
    """
    import dataclasses

    if not 0.0 < float(fraction) < 1.0:
        raise InputError(f"--validate: expected a fraction between 0 and 1, got {fraction}")
    N = data.n_samples
    k = int(round(N * (1.0 - float(fraction))))
    if k < 2 or N - k < 2:
        raise InputError(
            f"--validate {fraction}: expected at least 2 samples on each side, got {k} and {N - k}"
        )

    P = data.period
    if P is not None and k % P:
        k_p = int(round(k / P)) * P  # keep whole periods on both sides when there are any
        if P <= k_p <= N - P:
            k = k_p
    period = P if P is not None and k % P == 0 else None

    def part(sl):
        return dataclasses.replace(
            data,
            u=data.u[sl],
            y=data.y[sl],
            r=None if data.r is None else data.r[sl],
            period=period,
        )

    return part(slice(0, k)), part(slice(k, N))

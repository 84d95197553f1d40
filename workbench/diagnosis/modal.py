"""A model as a sum of modal terms, with the effects the diagnosis can add.

Every linear effect of the vocabulary is a change to one field of
:class:`ExtendedModel`::

    G(s) = T_out Hy(s) [ D + sum_k (N1_k s + N0_k) / d_k(s) ] Hu(s) T_in exp(-s delay_s)

where ``d_k`` is ``s^2 + a1 s + a0`` for a flexible mode (``s^2`` for the
rigid-body modes), ``s + a0`` for a real pole; ``Hu = diag(1/(1 + s tau_in))``
(actuator lag), ``Hy = diag(1/(1 + s tau_out))`` (sensor lag), ``T_out`` and
``T_in`` static coupling (crosstalk). A missing mode adds a term, a modal
mismatch changes a term's denominator, a suspension changes the rigid-body
denominator, residual compliance adds to ``D``.

The same object gives the frequency response, an exact zero-order-hold
simulation (each term filtered per input by ``scipy.signal.lfilter``, so a
10,000-sample 6x6 record takes milliseconds) and a state-space realization.

Relation to the one modal model, :class:`workbench.modal.model.ModalModel`: it holds
the same content (modes with exact numerators, D, delay, lags, coupling), and
:meth:`ExtendedModel.from_modal` / :meth:`ExtendedModel.to_modal` convert
losslessly. An ExtendedModel is the diagnosis's working view of it: the
rigid-body modes grouped into the one ``s^2`` term whose full-rank residue is
the linear parameter, denominators edited per term, per-term filters cached.
:func:`decompose` is ``from_modal`` of the one decomposition,
``ModalModel.from_statespace(sys, exact=True)``; the lags, coupling and delay
are computed by :func:`workbench.modal.model.apply_outer` /
:func:`workbench.modal.model.wrap_outer`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg
import scipy.signal

from workbench.core.lti import as_matrices
from workbench.modal.model import apply_outer, lag_factor, wrap_outer
from workbench.sim import c2d_zoh, split_delay

__all__ = ["Term", "ExtendedModel", "decompose"]


@dataclass(frozen=True)
class Term:
    """One modal term (N1 s + N0) / den(s).

    Parameters
    ----------
    den : (2,) or (1,) array
        ``(a1, a0)`` for ``s^2 + a1 s + a0`` (rad/s, rad^2/s^2), or ``(a0,)``
        for ``s + a0``.
    N0, N1 : (n_y, n_u) arrays
        Numerator matrices (N1 is zero for a first-order term).
    kind : {"rigid", "flex", "real", "added"}
    """

    den: np.ndarray
    N0: np.ndarray
    N1: np.ndarray
    kind: str = "flex"

    @property
    def order(self) -> int:
        return len(self.den)

    @property
    def freq_hz(self) -> float:
        """Undamped natural frequency, Hz (0 for rigid-body terms)."""
        a0 = self.den[-1]
        return (
            float(np.sqrt(max(a0, 0.0)) / (2 * np.pi))
            if self.order == 2
            else float(abs(a0) / (2 * np.pi))
        )

    @property
    def damping(self) -> float:
        """Damping ratio (0 for rigid-body terms)."""
        if self.order != 2 or self.den[1] <= 0:
            return 0.0
        return float(self.den[0] / (2 * np.sqrt(self.den[1])))

    @classmethod
    def mode(cls, freq_hz: float, damping: float, N0, N1=None, *, kind: str = "added") -> Term:
        w = 2 * np.pi * freq_hz
        N0 = np.asarray(N0, float)
        N1 = np.zeros_like(N0) if N1 is None else np.asarray(N1, float)
        return cls(den=np.array([2 * damping * w, w * w]), N0=N0, N1=N1, kind=kind)

    def with_den(self, den) -> Term:
        return replace(self, den=np.asarray(den, float))

    def response(self, s: np.ndarray) -> np.ndarray:
        """(n_f, n_y, n_u) complex response at the complex frequencies ``s``."""
        d = s**2 + self.den[0] * s + self.den[1] if self.order == 2 else s + self.den[0]
        return (self.N0[None] + s[:, None, None] * self.N1[None]) / d[:, None, None]


@dataclass(frozen=True)
class ExtendedModel:
    """A modal model with the effects of the vocabulary as fields (see module docstring).

    Parameters
    ----------
    terms : tuple of Term
    D : (n_y, n_u) array
        Feedthrough, m/N.
    delay_s : float
        Input-output delay, s.
    tau_in : (n_u,) array
        Actuator lag time constants, s (0: no lag).
    tau_out : (n_y,) array
        Sensor lag time constants, s (0: no lag).
    T_out : (n_y, n_y) array, T_in : (n_u, n_u) array
        Static coupling at the outputs and inputs (identity: none).
    """

    terms: tuple[Term, ...]
    D: np.ndarray
    delay_s: float = 0.0
    tau_in: np.ndarray | None = None
    tau_out: np.ndarray | None = None
    T_out: np.ndarray | None = None
    T_in: np.ndarray | None = None
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self):
        n_y, n_u = self.D.shape
        if self.tau_in is None:
            object.__setattr__(self, "tau_in", np.zeros(n_u))
        if self.tau_out is None:
            object.__setattr__(self, "tau_out", np.zeros(n_y))

    @property
    def n_y(self) -> int:
        return self.D.shape[0]

    @property
    def n_u(self) -> int:
        return self.D.shape[1]

    def replace(self, **changes) -> ExtendedModel:
        return replace(self, **changes)

    # ------------------------------------------------------------ modal model
    @classmethod
    def from_modal(cls, model) -> ExtendedModel:
        """The terms of a :class:`workbench.modal.model.ModalModel`, with D, delay, lags, coupling.

        The rigid modes share ``s^2``: they become one term whose numerator is
        their sum (full rank for one rigid mode per DOF). Flexible and real
        modes give one term each with their numerator (:meth:`Mode.numerator`).
        Terms are ordered rigid first, then by frequency.
        """
        terms: list[Term] = []
        if model.modes_of_kind("rigid"):
            N0, N1 = model.rigid_residue()
            terms.append(Term(den=np.zeros(2), N0=N0, N1=N1, kind="rigid"))
        for m in model.modes:
            if m.kind == "rigid":
                continue
            N0, N1 = m.numerator()
            kind = "flex" if m.kind == "flexible" else "real"
            terms.append(Term(den=m.denominator(), N0=np.array(N0), N1=np.array(N1), kind=kind))
        terms.sort(key=lambda t: (t.kind != "rigid", t.freq_hz))
        return cls(
            terms=tuple(terms),
            D=np.array(model.D, float),
            delay_s=model.delay_s,
            tau_in=None if model.tau_in is None else np.array(model.tau_in),
            tau_out=None if model.tau_out is None else np.array(model.tau_out),
            T_in=None if model.T_in is None else np.array(model.T_in),
            T_out=None if model.T_out is None else np.array(model.T_out),
        )

    def to_modal(self, *, input_names=(), output_names=()):
        """This model as a :class:`workbench.modal.model.ModalModel`, lossless (same FRF).

        The terms become modes with their exact numerators where these are not
        ``c b^T``; D, delay, lags and coupling are carried over. The rigid term
        is split into one mode per DOF (per output when its rank allows,
        otherwise by SVD); a suspended rigid term (its ``s^2`` denominator
        changed) is a flexible mode with the full residue; ``"added"`` terms
        become flexible modes.
        """
        from workbench.modal.model import ModalModel, Mode

        modes: list[Mode] = []
        for t in self.terms:
            N0, N1 = np.asarray(t.N0, float), np.asarray(t.N1, float)
            U, sv, Vt = np.linalg.svd(N0)
            if t.kind == "rigid" and not np.any(t.den):
                n_r = max(int(np.sum(sv > 1e-12 * max(sv[0], 1e-300))) if sv.size else 0, 1)
                if n_r == self.n_y and np.all(np.any(N0, axis=1)):
                    d = np.sqrt(np.linalg.norm(N0, axis=1))
                    C, B = np.diag(d), N0 / d[:, None]
                else:
                    C = U[:, :n_r] * np.sqrt(sv[:n_r])
                    B = np.sqrt(sv[:n_r])[:, None] * Vt[:n_r]
                rest = N0 - C @ B  # rounding, or N0 beyond rank n_r: kept on the first mode
                ideal = not np.any(N1) and np.linalg.norm(rest) <= 1e-12 * max(sv[0], 1e-300)
                for k in range(n_r):
                    num = (None, None)
                    if k == 0 and not ideal:
                        num = (rest + np.outer(C[:, k], B[k]), N1)
                    modes.append(Mode("rigid", 0.0, 0.0, B[k], C[:, k], N0=num[0], N1=num[1]))
                continue
            c = U[:, 0] * np.sqrt(sv[0]) if sv.size else np.zeros(self.n_y)
            b = Vt[0] * np.sqrt(sv[0]) if sv.size else np.zeros(self.n_u)
            ideal = np.allclose(np.outer(c, b), N0, rtol=0, atol=1e-12 * max(sv[0], 1e-300))
            ideal = ideal and not np.any(N1)
            if t.order == 1:
                p = -float(t.den[0])
                kind, f, z = "real", abs(p) / (2 * np.pi), (1.0 if p < 0 else -1.0)
                N1 = None
            else:
                kind, f, z = "flexible", t.freq_hz, t.damping
            modes.append(Mode(kind, f, z, b, c, N0=None if ideal else N0, N1=None if ideal else N1))
        order = {"rigid": 0, "flexible": 1, "real": 2}
        modes.sort(key=lambda m: order[m.kind])
        return ModalModel(
            modes=tuple(modes),
            D=self.D,
            input_names=input_names,
            output_names=output_names,
            delay_s=self.delay_s,
            tau_in=self.tau_in if np.any(self.tau_in) else None,
            tau_out=self.tau_out if np.any(self.tau_out) else None,
            T_in=self.T_in,
            T_out=self.T_out,
        )

    # ------------------------------------------------------------- frequency
    def core_frf(self, freq_hz: np.ndarray, terms=None, *, with_d: bool = True) -> np.ndarray:
        """D + sum of terms at ``freq_hz`` (no lags, coupling or delay), (n_f, n_y, n_u)."""
        s = 2j * np.pi * np.asarray(freq_hz, float)
        G = np.zeros((s.size, self.n_y, self.n_u), complex)
        if with_d:
            G += self.D[None]
        for t in self.terms if terms is None else terms:
            G += t.response(s)
        return G

    def outer(self, freq_hz: np.ndarray, G: np.ndarray) -> np.ndarray:
        """Apply lags, coupling and delay to a core response ``G`` (n_f, n_y, n_u)."""
        return apply_outer(
            freq_hz,
            G,
            tau_in=self.tau_in,
            tau_out=self.tau_out,
            T_in=self.T_in,
            T_out=self.T_out,
            delay_s=self.delay_s,
        )

    def channel_factor(self, freq_hz: np.ndarray) -> np.ndarray:
        """Per-channel outer factor Hy_i Hu_j exp(-s delay), (n_f, n_y, n_u) (coupling ignored)."""
        f = np.asarray(freq_hz, float)
        s = 2j * np.pi * f
        h = lag_factor(s, self.tau_out)[:, :, None] * lag_factor(s, self.tau_in)[:, None, :]
        return h * np.exp(-s * self.delay_s)[:, None, None]

    def frf(self, freq_hz: np.ndarray) -> np.ndarray:
        """Frequency response at ``freq_hz`` (Hz), (n_f, n_y, n_u) complex, m/N."""
        return self.outer(freq_hz, self.core_frf(freq_hz))

    # ------------------------------------------------------------ simulation
    def filtered_inputs(self, term_den, u: np.ndarray, fs: float, *, numerator_s: bool = True):
        """Inputs filtered through the outer factors and 1/den, s/den.

        Parameters
        ----------
        term_den : array or None
            Denominator of the term (see :class:`Term`); None for the feedthrough (den = 1).
        u : (N, n_u) array
            Inputs after the static input coupling.

        Returns
        -------
        X : (n_groups, N, n_u, 2) array and ``groups``: list of output-index
            arrays sharing one sensor lag (X[g, :, j, 0] is u_j through
            Hy Hu_j exp(-s delay)/den; [..., 1] the same times s).
        """
        taus = np.round(self.tau_out, 15)
        uniq = np.unique(taus)
        groups = [np.flatnonzero(taus == t) for t in uniq]
        N = u.shape[0]
        two = term_den is not None and len(term_den) == 2 and numerator_s
        X = np.zeros((len(uniq), N, self.n_u, 2))
        tin = np.round(self.tau_in, 15)
        base = np.array([1.0]) if term_den is None else np.concatenate([[1.0], term_den])
        for g, ty in enumerate(uniq):
            for ti in np.unique(tin):
                cols = np.flatnonzero(tin == ti)
                den = base
                for lag in (ty, ti):
                    if lag > 0:
                        den = np.polymul(den, [lag, 1.0])
                nums = [np.array([1.0, 0.0]), np.array([1.0])] if two else [np.array([1.0])]
                for k, num in enumerate(nums[::-1]):
                    X[g, :, cols, k] = zoh_filter(num, den, u[:, cols], 1.0 / fs, self.delay_s).T
        return X, groups

    def simulate(self, u: np.ndarray, fs: float) -> np.ndarray:
        """Zero-order-hold response from rest to ``u`` (N, n_u), sampled at ``fs``: (N, n_y)."""
        u = np.asarray(u, float)
        if self.T_in is not None:
            u = u @ self.T_in.T
        y = np.zeros((u.shape[0], self.n_y))
        parts = [(None, self.D, None)] if np.any(self.D) else []
        parts += [(t.den, t.N0, t.N1) for t in self.terms]
        for den, N0, N1 in parts:
            X, groups = self.filtered_inputs(den, u, fs)
            for g, rows in enumerate(groups):
                y[:, rows] += X[g, :, :, 0] @ N0[rows].T
                if N1 is not None and np.any(N1):
                    y[:, rows] += X[g, :, :, 1] @ N1[rows].T
        if self.T_out is not None:
            y = y @ self.T_out.T
        return y

    # ----------------------------------------------------------- state space
    def to_statespace(self):
        """Continuous ``control.StateSpace`` of everything but the delay (returned apart).

        Returns
        -------
        sys : control.StateSpace, delay_s : float
        """
        import control

        A_blocks, B_rows, C_cols = [], [], []
        for t in self.terms:
            A, B, C = _realize(t)
            if A.shape[0]:
                A_blocks.append(A)
                B_rows.append(B)
                C_cols.append(C)
        A = scipy.linalg.block_diag(*A_blocks) if A_blocks else np.zeros((0, 0))
        B = np.vstack(B_rows) if B_rows else np.zeros((0, self.n_u))
        C = np.hstack(C_cols) if C_cols else np.zeros((self.n_y, 0))
        A, B, C, D = wrap_outer(
            A, B, C, np.array(self.D, float), self.tau_in, self.tau_out, self.T_in, self.T_out
        )
        return control.ss(A, B, C, D) if A.size else control.ss([], [], [], D), self.delay_s


def _realize(t: Term):
    """Minimal-ish real realization of one term (rank-revealing SVD of [N0; N1])."""
    n_y, n_u = t.N0.shape
    V = np.vstack([t.N0, t.N1])
    U, S, Qt = np.linalg.svd(V, full_matrices=False)
    r = int(np.sum(S > 1e-10 * max(S[0], 1e-300))) if S.size else 0
    if r == 0:
        return np.zeros((0, 0)), np.zeros((0, n_u)), np.zeros((n_y, 0))
    Bq = Qt[:r]
    US = U[:, :r] * S[:r]
    if t.order == 1:
        return -t.den[0] * np.eye(r), Bq, US[:n_y]
    a1, a0 = t.den
    Z, I = np.zeros((r, r)), np.eye(r)
    # scale the position states by w so that the matrices stay balanced
    w = np.sqrt(a0) if a0 > 0 else 1.0
    A = np.block([[Z, w * I], [-a0 / w * I, -a1 * I]])
    B = np.vstack([np.zeros((r, n_u)), Bq])
    C = np.hstack([US[:n_y] / w, US[n_y:]])
    return A, B, C


def _charpoly(M: np.ndarray) -> np.ndarray:
    """Characteristic polynomial det(zI - M), highest power first (Faddeev-LeVerrier, small n)."""
    n = M.shape[0]
    c = np.zeros(n + 1)
    c[0] = 1.0
    Mk = np.zeros_like(M)
    eye = np.eye(n)
    for k in range(1, n + 1):
        Mk = M @ Mk + c[k - 1] * eye
        c[k] = -np.trace(M @ Mk) / k
    return c


def zoh_filter(num, den, u: np.ndarray, dt: float, delay_s: float = 0.0) -> np.ndarray:
    """Exact ZOH response of num(s)/den(s) (proper) to u, with an input delay, from rest."""
    num = np.atleast_1d(np.asarray(num, float))
    den = np.atleast_1d(np.asarray(den, float))
    num, den = num / den[0], den / den[0]
    n = den.size - 1
    num = np.concatenate([np.zeros(n + 1 - num.size), num])
    d = num[0]
    m_int, frac = split_delay(delay_s, dt)
    u = np.asarray(u, float)
    N = u.shape[0]
    y = np.zeros(u.shape)
    if n > 0:
        strict = num[1:] - d * den[1:]
        # controllable canonical form of the strictly proper part
        A = np.zeros((n, n))
        A[0, :] = -den[1:]
        if n > 1:
            A[1:, :-1] = np.eye(n - 1)
        B = np.zeros((n, 1))
        B[0, 0] = 1.0
        C = strict[None, :]
        # balance the companion matrix: a0 ~ w^2 makes expm costly and inaccurate
        A, Tb = scipy.linalg.matrix_balance(A, permute=False)
        B = B / np.diag(Tb)[:, None]
        C = C * np.diag(Tb)[None, :]
        Ad, B0, B1, _ = c2d_zoh(A, B, dt, delay_s=frac)
        # SISO transfer functions of (Ad, B0, C) and (Ad, B1, C): numerator
        # det(zI - Ad + B C) - det(zI - Ad) (what scipy's ss2tf computes, without its overhead)
        a = _charpoly(Ad)
        b0 = _charpoly(Ad - B0 @ C) - a
        b1 = _charpoly(Ad - B1 @ C) - a
        b = np.concatenate([b0, [0.0]]) + np.concatenate([[0.0], b1])
        y = scipy.signal.lfilter(b, a, u, axis=0)
        if m_int:
            y = np.concatenate([np.zeros((min(m_int, N),) + u.shape[1:]), y[: max(N - m_int, 0)]])
    if d:
        # the held input delayed by m_int + frac samples, sampled at k dt
        shift = m_int + (1 if frac > 0 else 0)
        ud = np.zeros(u.shape)
        if shift < N:
            ud[shift:] = u[: N - shift]
        y = y + d * ud
    return y


def decompose(sys) -> ExtendedModel:
    """Write a state-space model as a sum of modal terms.

    Parameters
    ----------
    sys : control.StateSpace or workbench.core.model.LTIModel
        Continuous, or discrete (converted by the exact ZOH inverse,
        :func:`workbench.core.d2c.d2c`, which refuses poles at z = 0 and on the
        negative real axis with an InputError). An LTIModel's delay is kept.

    Returns
    -------
    ExtendedModel with no effects added: :meth:`ExtendedModel.from_modal` of
    the one modal decomposition, ``ModalModel.from_statespace(sys,
    exact=True)`` (lossless: the rigid-body modes at s = 0 as one term over
    ``s^2`` with their summed residue ``N0`` and the ``1/s`` part ``N1``;
    every pole pair ``(N1 s + N0) / (s^2 + a1 s + a0)`` with its exact
    numerator; real poles; D). Raises InputError when A has Jordan chains
    other than rigid-body double integrators (not representable).
    """
    from workbench.modal.model import ModalModel

    _, _, _, _, dt = as_matrices(sys)
    notes = []
    if dt > 0:
        notes.append(
            f"discrete model (dt = {dt:g} s) converted to continuous time by the exact ZOH inverse"
        )
    em = ExtendedModel.from_modal(ModalModel.from_statespace(sys, exact=True))
    return em.replace(notes=tuple(notes))

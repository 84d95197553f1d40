"""The data side of a fit: weighted residuals and the linear sub-problems.

A *problem* holds one measurement and knows, in its own domain, how to

- predict the data from a :class:`~workbench.modal.model.ModalModel` (the
  FRF at the measured lines, or a ZOH simulation from rest driven by the
  recorded input), with a cache of per-mode contributions so that a fit that
  changes one mode does not recompute the others;
- turn the misfit into a weighted real residual vector (FRF with ``G_var``:
  (G - G_model)/sqrt(G_var), a chi-square statistic per line that averages
  about 1 when the model is right; FRF without: per-line relative weighting
  1/||G_f||_F; time: 1/rms(y));
- solve the parts of an effect that enter linearly (variable projection): the
  numerator of an added mode, an added feedthrough, a static coupling matrix.

``FrfProblem`` and ``TimeProblem`` offer the same methods, so every effect
structure works on both kinds of data.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workbench.core.errors import InputError
from workbench.core.lti import relative_error_frf, relative_error_time
from workbench.diagnosis.fit import NUMERICAL_FAILURES, cholesky_qr2
from workbench.io.formats import FrfData, TimeData
from workbench.modal.model import ModalModel, Mode, left_product
from workbench.modal.simulate import (
    filtered_inputs,
    filtered_lines,
    mixed_inputs,
    mixed_lines,
    mode_line_responses,
)
from workbench.sim import split_delay

__all__ = [
    "FrfProblem",
    "LineTerms",
    "PeriodicProblem",
    "RecordBlock",
    "TimeProblem",
    "make_problem",
    "moving_start",
    "record_block",
]


def _key(*arrays) -> tuple:
    return tuple(np.asarray(a, float).tobytes() if a is not None else b"" for a in arrays)


def _solve_channels(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve M[..., p, p] x = r[..., p] for every channel, with a tiny ridge."""
    p = M.shape[-1]
    ridge = 1e-12 * np.trace(M, axis1=-2, axis2=-1)[..., None, None] / p * np.eye(p)
    return np.linalg.solve(M + ridge + 1e-300 * np.eye(p), r[..., None])[..., 0]


def _normal_parts(phi: np.ndarray, hw: np.ndarray, ew: np.ndarray):
    """Normal equations of real coefficients per channel for the basis ``phi_p(f) h(f)``.

    The weighted least squares ``min sum_f w2 |e - sum_p x_p phi_p h|^2`` per channel, with
    the per-line factors ``phi`` (n_f, p) complex shared by the channels and, per channel,
    ``hw = w2 |h|^2`` (n_f, n_y, n_u) real and ``ew = w2 conj(h) e`` (n_f, n_y, n_u) complex
    (they do not depend on ``phi``: a screening computes them once per model). Since
    ``w2 |h|^2`` is real, ``M_pq = sum_f hw Re(conj(phi_p) phi_q)`` and
    ``r_p = Re sum_f conj(phi_p) ew``: two products over the lines.

    Returns M (n_y, n_u, p, p) and r (n_y, n_u, p).
    """
    n_f, n_y, n_u = hw.shape
    p = phi.shape[1]
    P = (np.conj(phi)[:, :, None] * phi[:, None, :]).real.reshape(n_f, p * p)
    M = (hw.reshape(n_f, -1).T @ P).reshape(n_y, n_u, p, p)
    r = (ew.reshape(n_f, -1).T @ np.conj(phi)).real.reshape(n_y, n_u, p)
    return M, r


def _solve_basis(M: np.ndarray, r: np.ndarray):
    """Solution x (n_y, n_u, p) of the normal equations (:func:`_normal_parts`) per channel
    and its unit-noise std, by the diagonally scaled system (the columns' scales differ
    by orders of magnitude)."""
    d = np.sqrt(np.maximum(np.einsum("ijpp->ijp", M), 1e-300))
    Ms = M / (d[..., :, None] * d[..., None, :])
    x = _solve_channels(Ms, r / d) / d
    p = M.shape[-1]
    cov = np.linalg.inv(Ms + 1e-12 * np.eye(p))
    std = np.sqrt(np.abs(np.einsum("ijpp->ijp", cov))) / d
    return x, std


class LineTerms:
    """The weighted FRF residual of a model family ``P = fixed + sum_k phi_k(f) terms_k``,
    compressed line by line.

    A structure whose parameters reach the prediction only through per-line scalar
    factors of fixed channel terms (a moved mode: its ``1/den(s)`` times its numerator
    through the outer factors; a delay: ``exp(-s tau)`` times the prediction; a lag on
    one input: ``1/(1 + s tau_j)`` times that column) has at line f the weighted residual
    ``A_f [-phi_f; 1]``, ``A_f = w_f [terms_f | G_f - fixed_f]`` (n_ch = n_y n_u rows,
    m + 1 columns). With the thin QR ``A_f = Q_f R_f`` (orthonormal ``Q_f``) the residual
    and every derivative of it with respect to ``phi`` keep their norms and inner products
    as ``R_f [-phi_f; 1]``, k = min(n_ch, m + 1) complex numbers instead of n_ch: the
    cost, ``J^T J`` and ``J^T r`` of a fit are those of :meth:`FrfProblem.residual`
    (exact arithmetic; the QR's rounding, ~1e-16 of ``|A_f|``), an evaluation costs
    O(n_f k m) and no model is built. The vector itself is not the residual's (its
    entries are the ``Q_f`` coordinates): only norms and products of it are meaningful.

    Parameters
    ----------
    problem : FrfProblem
    fixed : (n_f, n_y, n_u) complex
        The prediction's part that does not move.
    terms : (m, n_f, n_y, n_u) complex
        The terms the factors scale (outer factors, lags, coupling, delay applied).
    """

    def __init__(self, problem: FrfProblem, fixed: np.ndarray, terms: np.ndarray):
        n_f = problem.freq.size
        m = terms.shape[0]
        w = problem.w.reshape(n_f, -1)
        A = np.empty((n_f, w.shape[1], m + 1), complex)
        A[:, :, :m] = np.moveaxis(terms.reshape(m, n_f, -1), 0, -1) * w[:, :, None]
        A[:, :, m] = (problem.data.G - fixed).reshape(n_f, -1) * w
        if A.shape[1] <= m + 1:
            # as many terms as channels: the QR would not shorten a line's residual (k =
            # n_ch), and A itself keeps the norms and inner products (Q = I); a pattern of
            # many modes on a beam (15 channels, 19 terms, 7 000 lines) spent 0.2 s a QR
            R = A
        else:
            R = np.linalg.qr(A, mode="r")  # (n_f, k, m + 1), batched over the lines
        self.terms = np.ascontiguousarray(R[:, :, :m])  # (n_f, k, m)
        self.by_term = np.ascontiguousarray(np.moveaxis(R[:, :, :m], -1, 0))  # (m, n_f, k)
        self.target = np.ascontiguousarray(R[:, :, m])  # (n_f, k)

    def residual(self, phi: np.ndarray) -> np.ndarray:
        """Compressed residual (2 n_f k,) real, for the factors ``phi`` (m, n_f) complex."""
        if phi.shape[0] == 1:
            r = self.target - self.by_term[0] * phi[0][:, None]
        else:  # one small product per line (einsum's generic loop was 2-3x slower)
            r = self.target - (self.terms @ np.ascontiguousarray(phi.T)[:, :, None])[:, :, 0]
        return r.view(float).ravel()

    def cost(self, phi: np.ndarray) -> float:
        """Sum of squared weighted residuals, as :meth:`FrfProblem.cost` of the model."""
        r = self.residual(phi)
        return float(r @ r)

    def jacobian(self, dphi: np.ndarray, terms: np.ndarray | None = None) -> np.ndarray:
        """Compressed Jacobian (2 n_f k, n_theta) for ``dphi`` = d phi / d theta.

        ``dphi`` (n_theta, m, n_f); or, with ``terms`` (n_theta,) term indices, (n_theta, n_f):
        parameter t moves the factor of term ``terms[t]`` only (a mode's frequency, one
        channel's lag), one product per column instead of m.
        """
        # built as J^T, one row per parameter laid out as residual() lays out its vector
        n_theta = dphi.shape[0]
        Jt = np.empty((n_theta,) + self.target.shape, complex)  # (n_theta, n_f, k)
        for t in range(n_theta):
            if terms is not None:
                np.multiply(self.by_term[terms[t]], -dphi[t][:, None], out=Jt[t])
            else:
                Jt[t] = -(self.terms @ dphi[t].T[:, :, None])[:, :, 0]
        return Jt.view(float).reshape(n_theta, -1).T


#: cores kept by FrfProblem (each n_f n_y n_u complex), and mode sums summed directly
CORE_CACHE = 16
CORE_ANCHORS = 4


class FrfProblem:
    """Fit to a measured FRF (spec 1b)."""

    kind = "frf"
    #: where a fit evaluates the model: "frequency" (a response at lines, cheap) or "time" (a
    #: simulation of the record); structures with many parameters are offered by it
    domain = "frequency"

    def __init__(self, data: FrfData):
        self.data = data
        self.freq = data.freq
        self.s = 2j * np.pi * data.freq
        G = data.G
        if data.G_var is not None and np.any(data.G_var > 0):
            var = np.array(data.G_var, float)
            floor = 1e-6 * np.median(var[var > 0])
            self.w = 1.0 / np.sqrt(np.maximum(var, floor))
            self.has_var = True
            norm = np.linalg.norm(G, axis=(1, 2))
            self.noise_floor = float(
                np.mean(np.sqrt(var.sum(axis=(1, 2))) / np.where(norm > 0, norm, np.inf))
            )
        else:
            norm = np.linalg.norm(G, axis=(1, 2))
            norm = np.where(norm > 0, norm, np.max(norm) + 1e-300)
            self.w = np.broadcast_to((1.0 / norm)[:, None, None], G.shape).copy()
            self.has_var = False
            self.noise_floor = None
        self.w2 = self.w**2
        self.n_obs = 2 * G.size
        self.band_hz = (float(data.freq[0]), float(data.freq[-1]))
        self._cache: dict = {}  # mode key -> its response
        self._mode_keys: dict = {}  # id(mode) -> (mode, its key), see _mode_key
        self._core_cache: dict = {}  # (mode keys, D) -> core, oldest first
        self._anchors: dict = {}  # mode keys -> (modes, sum of responses summed directly)
        self._linear_last = None  # [model, w2 |h|^2, w2 conj(h) e, w2 |e|^2, e], _linear_data
        self._factors: dict = {}  # (delay, lags) -> channel factor, see _channel_factor
        self._weights_last = None  # (channel factor, its weighted forms), _factor_weights
        self._term_last = None  # (model, den key, M, r) of the last fit_new_term
        self._added_last = None  # (model, w e, w h), see added_term_residual
        self.lines_cache: dict = {}  # ids -> (structure, base, its lines), see structure_lines

    # ------------------------------------------------------------ prediction
    def _mode_key(self, m: Mode) -> tuple:
        """The values a mode's response depends on (denominator, numerator) as bytes, kept
        per mode object (a model's modes are frozen; a fit rebuilds models that share all
        but one or two of them, and every core() asks for every mode's key)."""
        hit = self._mode_keys.get(id(m))
        if hit is not None and hit[0] is m:  # the object itself is kept: its id is not reused
            return hit[1]
        if len(self._mode_keys) > 4096:
            self._mode_keys.clear()
        k = _key(m.denominator(), *m.numerator())
        self._mode_keys[id(m)] = (m, k)
        return k

    def _mode_response(self, m: Mode) -> np.ndarray:
        k = self._mode_key(m)
        out = self._cache.get(k)
        if out is None:
            out = m.response(self.s)
            if len(self._cache) > 400:
                self._cache.clear()
            self._cache[k] = out
        return out

    def core(self, model: ModalModel) -> np.ndarray:
        """``D + sum_k modes`` at the measured lines, (n_f, n_y, n_u), read-only.

        Cached by the modes' and D's values: a fit that moves the delay, a lag or the
        coupling reuses it. A model whose modes differ from an :data:`CORE_ANCHORS` sum
        summed directly in a few places (a moved mode, an added one: most of a fit's
        evaluations) starts from that sum: the changed modes' responses are subtracted
        and added (rounding ~1e-16 of the anchor's largest line, never chained: a sum
        derived so is not an anchor).
        """
        keys = tuple(self._mode_key(m) for m in model.modes)
        full = (keys, _key(model.D))
        G = self._core_cache.get(full)
        if G is None:
            G = self._modes_sum(model, keys)  # a new array: D added in place
            G += model.D
            G.flags.writeable = False
            if len(self._core_cache) >= CORE_CACHE:
                self._core_cache.pop(next(iter(self._core_cache)))
            self._core_cache[full] = G
        return G

    def _modes_sum(self, model: ModalModel, keys: tuple) -> np.ndarray:
        """``sum_k`` mode responses, (n_f, n_y, n_u), from a near anchor or directly."""
        for anchor, (modes, S) in reversed(self._anchors.items()):
            if len(anchor) <= len(keys) and len(keys) - len(anchor) <= 2:
                changed = [k for k in range(len(anchor)) if anchor[k] != keys[k]]
                if len(changed) + len(keys) - len(anchor) <= 2:
                    out = S.copy()
                    for k in changed:
                        out -= self._mode_response(modes[k])
                        out += self._mode_response(model.modes[k])
                    for m in model.modes[len(anchor) :]:
                        out += self._mode_response(m)
                    return out
        # every mode in one product (model.core_frf): a new anchor is mostly a model whose
        # modes all moved (a shared frequency scale), their responses not cached
        out = model.core_frf(self.freq, with_d=False)
        if len(self._anchors) >= CORE_ANCHORS:
            self._anchors.pop(next(iter(self._anchors)))
        self._anchors[keys] = (model.modes, out.copy())
        return out

    def predict(self, model: ModalModel) -> np.ndarray:
        """Model FRF at the measured lines, (n_f, n_y, n_u)."""
        G = self.core(model)
        if model.T_in is None and model.T_out is None:
            if model.delay_s or np.any(model.lags("in")) or np.any(model.lags("out")):
                # the outer factor is per channel: one product with the kept factor
                return G * self._channel_factor(model)
        return model.outer(self.freq, G)

    def residual(self, model: ModalModel) -> np.ndarray:
        e = self.data.G - self.predict(model)
        e *= self.w  # in place: the residual is evaluated thousands of times a diagnosis
        return e.view(float).ravel()

    def cost(self, model: ModalModel) -> float:
        r = self.residual(model)
        return float(r @ r)

    def record_cost(self, model: ModalModel) -> float:
        """The cost on the measurement as recorded (here the fitted cost itself)."""
        return self.cost(model)

    def error(self, model: ModalModel) -> float:
        return relative_error_frf(self.data.G, self.predict(model))

    def line_chi2(self, model: ModalModel) -> np.ndarray:
        """Weighted squared misfit per line, summed over channels, (n_f,)."""
        e = (self.data.G - self.predict(model)) * self.w
        return np.sum(e.real**2 + e.imag**2, axis=(1, 2))

    # --------------------------------------------------------- linear parts
    def _channel_factor(self, model: ModalModel) -> np.ndarray:
        """``model.channel_factor`` at the lines, (n_f, n_y, n_u), read-only, kept by the
        delay and lags (a joint refit's linear parts see the same lags hundreds of times)."""
        k = _key([model.delay_s], model.lags("in"), model.lags("out"))
        h = self._factors.get(k)
        if h is None:
            h = model.channel_factor(self.freq)
            h.flags.writeable = False
            if len(self._factors) >= 8:
                self._factors.pop(next(iter(self._factors)))
            self._factors[k] = h
        return h

    def _factor_weights(self, model: ModalModel):
        """``(w2 |h|^2, w2 conj(h), w h)`` of the channel factor ``h`` of ``model``, (n_f,
        n_y, n_u) each, kept for the last factor asked (a joint refit's evaluations see one
        delay and lags while they move modes; each was three passes over the lines)."""
        h = self._channel_factor(model)
        last = self._weights_last
        if last is None or last[0] is not h:
            last = (h, self.w2 * (h.real**2 + h.imag**2), self.w2 * np.conj(h), self.w * h)
            for a in last[1:]:
                a.flags.writeable = False  # shared by every evaluation on this factor
            self._weights_last = last
        return last[1:]

    def _linear_data(self, model: ModalModel):
        """``(w2 |h|^2, w2 conj(h) e)`` of the misfit ``e`` and channel factor ``h`` of
        ``model`` (:func:`_normal_parts`), kept for the last model asked (a grid screens
        hundreds of added terms on one model)."""
        last = self._linear_last
        if last is None or last[0] is not model:
            e = self._unmixed(model, self.data.G - self.predict(model))
            hw, w2h, _ = self._factor_weights(model)
            # the per-channel cost w2 |e|^2 (added_term_cost) is summed when first asked
            last = [model, hw, w2h * e, None, e]
            self._linear_last = last
        return last[1], last[2]

    def fit_new_term(self, model: ModalModel, den: np.ndarray):
        """Real numerators N0, N1 of an added mode (N1 s + N0)/den(s), per channel.

        Returns N0, N1 (n_y, n_u) and their standard deviations (unit noise scale).
        """
        d = self.s**2 + den[0] * self.s + den[1]
        wr = np.sqrt(max(den[1], 1e-300))
        M, r = _normal_parts(np.stack([1.0 / d, self.s / (wr * d)], -1), *self._linear_data(model))
        self._term_last = (model, _key(den), M, r)  # for added_term_cost
        x = _solve_channels(M, r)
        cov = np.linalg.inv(M + 1e-300 * np.eye(2))
        std = np.sqrt(np.abs(np.stack([cov[..., 0, 0], cov[..., 1, 1]], -1)))
        return x[..., 0], x[..., 1] / wr, std[..., 0], std[..., 1] / wr

    def added_terms_exact(self, model: ModalModel) -> bool:
        """True where :meth:`added_term_cost` and :meth:`added_term_residual` are exact: a
        model without coupling (the channel factor of :meth:`fit_new_term` is then the
        model's outer factor)."""
        return model.T_in is None and model.T_out is None

    def added_term_cost(self, model: ModalModel, den: np.ndarray, N0, N1) -> float:
        """:meth:`cost` of ``model`` plus the mode ``(N1 s + N0) / (s^2 + den[0] s + den[1])``.

        From the normal equations of :meth:`fit_new_term` (``den`` = (a1, a0), N0 and N1
        (n_y, n_u), any values: a projected residue too): per channel ``sum_f w2 |e|^2 -
        2 x.r + x^T M x`` with ``x = (N0, N1 sqrt(a0))``, no prediction formed (a screening
        evaluates hundreds). Exact for a model without coupling (``T_in``, ``T_out`` None:
        the channel factor of :meth:`fit_new_term` is then the model's outer factor); the
        rounding is ~1e-16 of the base model's cost.
        """
        if model.T_in is not None or model.T_out is not None:
            raise ValueError("added_term_cost: a model with coupling (use cost)")
        self._linear_data(model)  # the misfit below is this model's
        last = self._term_last
        if last is not None and last[0] is model and last[1] == _key(den):
            M, r = last[2], last[3]
        else:
            d = self.s**2 + den[0] * self.s + den[1]
            wr = np.sqrt(max(den[1], 1e-300))
            phi = np.stack([1.0 / d, self.s / (wr * d)], -1)
            M, r = _normal_parts(phi, *self._linear_data(model))
        x = np.stack([N0, N1 * np.sqrt(max(den[1], 1e-300))], -1)  # (n_y, n_u, 2)
        last = self._linear_last
        if last[3] is None:
            e = last[4]
            last[3] = np.sum(self.w2 * (e.real**2 + e.imag**2), axis=0)  # (n_y, n_u)
        e2 = last[3]
        quad = np.einsum("ijp,ijpq,ijq->", x, M, x)
        return float(np.sum(e2) - 2.0 * np.sum(x * r) + quad)

    def appended_residual(self, model: ModalModel, parent: ModalModel) -> np.ndarray:
        """:meth:`residual` of ``model``, formed from ``parent`` where ``model`` is ``parent``
        with one mode appended (and its D changed), the outer factors the same and no
        coupling (:meth:`added_term_residual`); directly otherwise."""
        same_outer = (
            model.T_in is None
            and model.T_out is None
            and parent.T_in is None
            and parent.T_out is None
            and model.delay_s == parent.delay_s
            and np.array_equal(model.lags("in"), parent.lags("in"))
            and np.array_equal(model.lags("out"), parent.lags("out"))
        )
        n = len(parent.modes)
        if (
            same_outer
            and len(model.modes) == n + 1
            and all(a is b for a, b in zip(model.modes, parent.modes))
        ):
            return self.added_term_residual(parent, model.modes[-1], model.D - parent.D)
        return self.residual(model)

    def added_term_residual(self, model: ModalModel, mode: Mode, dD=None) -> np.ndarray:
        """:meth:`residual` of ``model`` with ``mode`` (a Mode, or a tuple of them) appended
        (and ``dD`` (n_y, n_u) added to its D), (n_obs,).

        The model's weighted misfit minus the mode's response through the channel factor
        (both kept for the last model asked: a fit adds hundreds of trial modes to one
        model), no prediction formed. Exact for a model without coupling (``T_in``,
        ``T_out`` None); rounding ~1e-16 of the model's misfit.
        """
        if model.T_in is not None or model.T_out is not None:
            raise ValueError("added_term_residual: a model with coupling (use residual)")
        last = self._added_last
        if last is None or last[0] is not model:
            lin = self._linear_last  # the misfit a linear fit on this model formed, if any
            e = lin[4] if lin is not None and lin[0] is model else self.data.G - self.predict(model)
            last = (model, e * self.w, self._factor_weights(model)[2])
            self._added_last = last
        modes = mode if isinstance(mode, tuple) else (mode,)  # an upper residual's several
        r = modes[0].response(self.s)
        for m in modes[1:]:
            r += m.response(self.s)
        if dD is not None:
            r += dD
        r *= last[2]
        np.subtract(last[1], r, out=r)
        return r.view(float).ravel()

    def fit_upper_residual(self, model: ModalModel, den: np.ndarray):
        """Residual terms of modes above the band: D + (N1 s + N0) / den(s), jointly per channel.

        ``den`` = (a1, a0) of a pseudo-mode above the band (``s^2 + a1 s + a0``), or (k, 2):
        k pseudo-modes, each with its numerators, all solved jointly with D.
        Returns dD, N0, N1 (n_y, n_u; N0, N1 (k, n_y, n_u) for k pseudo-modes) and their
        standard deviations (unit noise scale).
        """
        dens = np.atleast_2d(den)
        cols, scale = [np.ones_like(self.s)], [1.0]
        for a1, a0 in dens:
            d = self.s**2 + a1 * self.s + a0
            wr = np.sqrt(max(a0, 1e-300))
            cols += [wr**2 / d, self.s * wr / d]
            scale += [wr**2, wr]  # N0 = x w^2, N1 = x w
        x, std = _solve_basis(*_normal_parts(np.stack(cols, -1), *self._linear_data(model)))
        return _upper_parts(x * np.array(scale), std * np.array(scale), np.ndim(den) == 1)

    @staticmethod
    def _unmixed(model: ModalModel, e: np.ndarray) -> np.ndarray:
        """A misfit (n_f, n_y, n_u) as a term added to ``model`` sees it: ``T_out^-1 e
        T_in^-1`` (the coupling, per line, outside the channel factor: ``apply_outer``);
        ``e`` itself without coupling. The weights stay the mixed channels' (exact for
        equal weights, ``T`` near I: second order in its off-diagonal), see
        :func:`_unmixed_misfit`."""
        # one inverse each, not a solve per line (numpy factors the matrix once per line)
        if model.T_out is not None:
            e = left_product(np.linalg.inv(model.T_out), e)
        if model.T_in is not None:
            e = e @ np.linalg.inv(model.T_in)
        return e

    def fit_feedthrough(self, model: ModalModel):
        """Real matrix added to D, per channel; returns dD and its std (unit noise scale)."""
        e = self._unmixed(model, self.data.G - self.predict(model))
        h = self._channel_factor(model)
        m = np.sum(self.w2 * np.abs(h) ** 2, axis=0)
        r = np.sum(self.w2 * (np.conj(h) * e).real, axis=0)
        return r / m, 1.0 / np.sqrt(m)

    def fit_crosstalk(self, model: ModalModel, side: str):
        """Off-diagonal static coupling E with G = (I + E) G_model (side "out") or G_model (I + "
        "E)."""
        Gm = self.predict(model)
        e = self.data.G - Gm
        if side != "out":  # G_model (I + E) = ((I + E^T) G_model^T)^T: the outputs' case
            Gm, e = np.swapaxes(Gm, 1, 2), np.swapaxes(e, 1, 2)
            w2 = np.swapaxes(self.w2, 1, 2)
        else:
            w2 = self.w2
        n_f, n, n_o = Gm.shape
        # row i of E by weighted least squares over the lines and the other channels: its
        # normal equations for every row at once (one product each, not a solve's X per row)
        # M[i, k, l] = sum_f,o w2[f, i, o] Re(conj G[f, k, o] G[f, l, o])
        Go = np.moveaxis(Gm, 2, 1).reshape(n_f * n_o, n)
        X = np.concatenate([Go.real, Go.imag])  # (2 n_f n_o, n): Re(a^H b) = a_r b_r + a_i b_i
        W = np.moveaxis(w2, 1, 0).reshape(n, n_f * n_o)
        M = np.stack([(X.T * np.tile(W[i], 2)) @ X for i in range(n)])
        # rhs[i, k] = sum_f,o w2[f, i, o] Re(conj G[f, k, o] e[f, i, o])
        we = np.moveaxis(w2 * e, 1, 0).reshape(n, n_f * n_o)
        rhs = we.real @ Go.real + we.imag @ Go.imag
        E = np.zeros((n, n))
        S = np.zeros((n, n))
        for i in range(n):
            others = np.arange(n) != i
            E[i, others], S[i, others] = _normal_std(M[i][np.ix_(others, others)], rhs[i, others])
        return (E, S) if side == "out" else (E.T, S.T)

    def residual_peaks(self, model: ModalModel, n: int = 6) -> list[float]:
        """Frequencies (Hz) of the n largest separated peaks of the misfit per line."""
        return _peaks(self.freq, self.line_chi2(model), n)

    def model_frf(self, model: ModalModel, freq=None) -> np.ndarray:
        return model.frf(self.freq if freq is None else freq)

    def lines(self, fixed: np.ndarray, terms: np.ndarray) -> LineTerms:
        """The residual of ``fixed + sum_k phi_k terms_k``, compressed per line (LineTerms)."""
        return LineTerms(self, fixed, terms)


def _peaks(freq: np.ndarray, power: np.ndarray, n: int) -> list[float]:
    """Up to n local maxima of ``power``, largest first, at least 3 % apart in frequency.

    ``freq`` (n_f,) Hz, ascending; ``power`` (n_f,). Only lines at least as high as both
    neighbours count: the flank of one broad misfit (a model mode far from its place,
    lines a few % apart) would otherwise fill all n places and hide a second resonance.
    """
    power = np.asarray(power, float)
    left = np.concatenate([[-np.inf], power[:-1]])
    right = np.concatenate([power[1:], [-np.inf]])
    local = (power >= left) & (power >= right)
    out: list[float] = []
    for k in np.argsort(power)[::-1]:
        if power[k] <= 0:
            break
        if not local[k]:
            continue
        f = float(freq[k])
        if all(abs(f / g - 1) > 0.03 for g in out):
            out.append(f)
        if len(out) == n:
            break
    return out


def _upper_parts(x: np.ndarray, std: np.ndarray, one: bool) -> tuple:
    """(dD, N0, N1, sD, s0, s1) from the coefficients (n_y, n_u, 1 + 2k) of an upper residual
    ordered [D, N0_1, N1_1, N0_2, ...]; N0, N1 of k pseudo-modes stacked first (k, n_y, n_u),
    of one (``one``) as (n_y, n_u)."""

    def split(a):
        N0, N1 = np.moveaxis(a[..., 1::2], -1, 0), np.moveaxis(a[..., 2::2], -1, 0)
        return (a[..., 0], N0[0], N1[0]) if one else (a[..., 0], N0, N1)

    return split(x) + split(std)


def _orthonormal_columns(B: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Orthonormal basis (N, r) of the span of B's columns (N >> n_b), C-contiguous.

    :func:`~workbench.diagnosis.fit.cholesky_qr2` on the column-scaled B while
    ``cond(B) < 1e4`` (there as accurate as Householder QR, ~4x faster for a tall B),
    else Householder QR with rank detection (columns whose R_ii < rtol max R_ii are
    dropped).
    """
    norms = np.sqrt(np.einsum("ij,ij->j", B, B))  # np.linalg.norm(axis=0): ~3x slower, tall B
    Bs = B[:, norms > 0] / norms[norms > 0]
    try:
        Q, R = cholesky_qr2(Bs)
        if np.linalg.cond(R) < 1e4:
            return Q
    except np.linalg.LinAlgError:
        pass
    Q, R = np.linalg.qr(Bs)
    keep = np.abs(np.diag(R)) > rtol * np.max(np.abs(np.diag(R)))
    return np.ascontiguousarray(Q[:, keep])


def _lstsq_std(X: np.ndarray, b: np.ndarray, normal: list | None = None):
    """Least squares by the normal equations of the column-scaled X; x and its unit-noise std.

    ``X`` (n, p); ``b`` (n,) or (n, k) (k right-hand sides sharing X: one factorization);
    returns x (p,) or (p, k) and std (p,). ``normal``: a list the normal equations are
    appended to, ``(M, Xs^T b, scale)`` with ``Xs = X / scale`` and ``M = Xs^T Xs``: the
    cost of any coefficients without X (:meth:`_FilteredProblem.added_term_cost`).
    """
    if X.shape[1] == 0:
        if normal is not None:
            normal.append((np.zeros((0, 0)), np.zeros((0,) + b.shape[1:]), np.zeros(0)))
        return np.zeros((0,) + b.shape[1:]), np.zeros(0)
    scale = np.sqrt(np.einsum("ij,ij->j", X, X))  # np.linalg.norm(axis=0): ~3x slower, tall X
    scale = np.where(scale > 0, scale, 1.0)
    Xs = X / scale
    M = Xs.T @ Xs
    Xb = Xs.T @ b
    if normal is not None:
        normal.append((M.copy(), Xb, scale))
    return _scaled_solve(M, Xb, scale)


def _normal_std(M: np.ndarray, r: np.ndarray):
    """:func:`_lstsq_std` from the normal equations ``M = X^T X`` (p, p), ``r = X^T b``
    (p,): the same column scaling, x (p,) and its unit-noise std (p,)."""
    scale = np.sqrt(np.maximum(np.diag(M), 0.0))
    scale = np.where(scale > 0, scale, 1.0)
    return _scaled_solve(M / np.outer(scale, scale), r / scale, scale)


def _scaled_solve(M: np.ndarray, Xb: np.ndarray, scale: np.ndarray):
    """x and its std of the column-scaled normal equations ``M x_s = Xb`` (``x = x_s /
    scale``); M is not kept."""
    M = M + 1e-12 * np.eye(M.shape[0])
    # np.linalg.pinv(M, hermitian=True) (its default cutoff 1e-15 of the largest eigenvalue)
    # from one eigh, without pinv's SVD wrapper (a screen solves hundreds of these)
    lam, V = np.linalg.eigh(M)
    keep = np.abs(lam) > 1e-15 * np.max(np.abs(lam))
    cov = (V * np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)) @ V.T
    x = cov @ Xb
    s = 1.0 / scale if Xb.ndim == 1 else (1.0 / scale)[:, None]
    return x * s, np.sqrt(np.abs(np.diag(cov))) / scale


#: a record starts in motion when some output's first value exceeds this many noise standard
#: deviations: at rest the state is zero and a position sensor's first sample is its noise. (An
#: rms fraction as the bound besides, 10 %, missed a record cut while the shaft passed near
#: zero at speed: its first samples 5-9 noise std, 4 % of the rms; simulated from rest, the
#: true model's error was 98 and the diagnosis named a suspension at 80x the noise floor)
MOVING_START = 5.0


def moving_start(data: TimeData) -> bool:
    """True when the record does not start at rest (from the data alone).

    At rest every output's first sample is noise; a record cut from a running
    experiment starts at some position. The noise standard deviation is
    estimated from the second differences (``var = 6 sigma^2`` for white noise;
    a smooth signal sampled fast adds little, and a fast one only raises the
    bound). The first step is not used: for a signal slow against fs it is
    comparable to the noise. A record that starts within the noise of zero while
    moving is not recognized (then compared from rest, the spec's measure).
    """
    y = np.asarray(data.y, float)
    if y.shape[0] < 4:
        return False
    noise = np.sqrt(np.mean(np.diff(y, 2, axis=0) ** 2, axis=0) / 6.0)
    return bool(np.any(np.abs(y[0]) > MOVING_START * noise))


def _remove(Q: np.ndarray | None, X: np.ndarray) -> np.ndarray:
    """X (n_rows, ...) minus its projection on the orthonormal columns Q (n_rows, r); None: X."""
    if Q is None:
        return X
    flat = X.reshape(X.shape[0], -1)
    return (flat - Q @ (Q.T @ flat)).reshape(X.shape)


#: new transient columns :func:`_appended` orthonormalizes one by one, at most
SMALL_BLOCK = 12


def _appended(Q_rest: np.ndarray, W: np.ndarray) -> np.ndarray | None:
    """``Q_rest`` (n_rows, r) orthonormal extended by the span of the columns ``W`` (n_rows,
    m): (n_rows, r + m), or None where a new column lies within :data:`NEAR_SPAN` of the
    span of ``Q_rest`` and the other new columns.

    The new columns orthogonalized against ``Q_rest`` twice (classical Gram-Schmidt,
    twice is enough; Giraud et al. 2005), then among themselves: up to
    :data:`SMALL_BLOCK` columns (a pole's 1-2, a few moved together) by Gram-Schmidt
    twice per column, which is Householder QR's Q (up to signs) and |diag R| at a tenth
    of np.linalg.qr's call overhead; more (a delay line's 60-80 further terms) by
    :func:`~workbench.diagnosis.fit.cholesky_qr2`, the same in exact arithmetic and as
    accurate below the :data:`NEAR_SPAN` limit, in batched products where the column loop
    passes over the rows m^2 / 2 times (for 2-6 columns it was 2x slower: 16 000 rows).
    """
    if W.shape[1] == 0:
        return Q_rest
    # column norms by einsum: np.linalg.norm(axis=0) of a tall array of 1-2 columns
    # reduces across the rows at ~3x the cost
    W = W / np.sqrt(np.einsum("ij,ij->j", W, W))
    for _ in range(2):
        W = W - Q_rest @ (Q_rest.T @ W)
    norms = np.sqrt(np.einsum("ij,ij->j", W, W))
    if np.min(norms) < NEAR_SPAN:
        return None
    # the new columns' own span (a pair's two may be near parallel for a pole near the
    # real axis; then the whole basis afresh): d, the columns' distances from the previous
    # ones (|diag R|)
    W = W / norms
    if W.shape[1] > SMALL_BLOCK:
        try:
            Q_new, R = cholesky_qr2(W)
        except np.linalg.LinAlgError:
            return None
        d = np.abs(np.diag(R))
    else:
        Q_new = np.empty_like(W)
        d = np.empty(W.shape[1])
        for j in range(W.shape[1]):
            w = W[:, j]
            for _ in range(2 if j else 0):
                w = w - Q_new[:, :j] @ (Q_new[:, :j].T @ w)
            d[j] = np.linalg.norm(w)
            Q_new[:, j] = w / d[j] if d[j] > 0 else 0.0
    if np.min(d) < NEAR_SPAN * np.max(d):
        return None
    return np.ascontiguousarray(np.column_stack([Q_rest, Q_new]))


#: directly summed model outputs the time-record problems keep as anchors
#: (:meth:`_FilteredProblem._parts_sum`)
ROW_ANCHORS = 4


def _unmixed_misfit(problem, model: ModalModel) -> np.ndarray:
    """The weighted misfit ``(target - fitted) / scale`` (n_rows, n_y) a term added to
    ``model`` is regressed on: with an output coupling, ``T_out^-1`` applied first.

    A term added to a coupled model (a mode, a compliance) reaches the outputs through
    ``T_out`` like the model's own modes (``fitted``): its numerators are fitted to what
    ``T_out`` mixed, unmixed (the misfit's weights read before the unmixing: exact for
    equal weights, ``T_out`` near I: rounding second order in its off-diagonal). Regressed
    on the mixed misfit, they took the coupling's share as their own: an output crosstalk
    of 8 % and a compliance a scipy-ZOH oracle left at 1.47x the noise floor
    (tests/test_crosstalk_stack.py).
    """
    e = problem.target - problem.fitted(model)
    if model.T_out is not None:
        e = np.linalg.solve(model.T_out, e.T).T
    return e / problem.scale


class _FilteredProblem:
    """The time-record problems' shared part: the model's output as filtered inputs mixed by
    the modes' numerators, on *rows* (time samples, or the real and imaginary parts of DFT
    lines), with a free-response basis projected out (variable projection: the start is a
    nuisance parameter).

    A subclass sets ``target`` (n_rows, n_y) real, ``u_rows`` (n_in, n_u) (its inputs in the
    rows' domain), ``scale``, ``n_obs`` and implements ``_filter(model, den, u_in)``
    -> (X (n_groups, n_rows, n_u, 2) real, groups) and ``_start_basis(model)`` -> (n_rows, r)
    orthonormal or None.
    """

    kind = "time"
    domain = "time"

    def _project(self, model: ModalModel, X: np.ndarray) -> np.ndarray:
        """X (n_rows, ...) with its component along the free responses removed."""
        return _remove(self._start_basis(model), X)

    @staticmethod
    def _channels_key(model: ModalModel) -> tuple:
        """What a mode's filtered inputs depend on besides its denominator: the delay, the
        lags and the input coupling (one key per model, shared by its modes' parts)."""
        return _key([model.delay_s], model.lags("in"), model.lags("out"), model.T_in)

    def _filtered(self, model: ModalModel, den, u_in, channels: tuple | None = None):
        """``_filter``, cached by what it depends on: a fit's linear parts and its cost see
        the same denominator with different numerators. ``channels``: the model's
        :meth:`_channels_key`, when the caller has it."""
        if channels is None:
            channels = self._channels_key(model)
        k = _key(den) + channels
        out = self._filter_cache.get(k)
        if out is None:
            out = self._filter(model, den, u_in)
            if len(self._filter_cache) > 32:
                self._filter_cache.clear()
            self._filter_cache[k] = out
        return out

    def _part(self, model: ModalModel, den, N0, N1, u_in, channels: tuple) -> np.ndarray:
        """One mode's (or D's) output on the rows, cached; ``channels`` is the model's
        :meth:`_channels_key`."""
        k = _key(den, N0, N1) + channels
        out = self._cache.get(k)
        if out is None:
            out = self._mixed(model, den, N0, N1, u_in, channels)
            if len(self._cache) > 200:
                self._cache.clear()
            self._cache[k] = out
        return out

    def _mixed(self, model: ModalModel, den, N0, N1, u_in, channels: tuple) -> np.ndarray:
        """One mode's (or D's) output on the rows, (n_rows, n_y): its filtered inputs mixed
        by its numerators ``N0``, ``N1`` (n_y, n_u; ``N1`` None for D)."""
        X, groups = self._filtered(model, den, u_in, channels)
        out = np.zeros(self.target.shape)
        for g, rows in enumerate(groups):
            out[:, rows] = X[g, :, :, 0] @ N0[rows].T
            if N1 is not None and np.any(N1):
                out[:, rows] += X[g, :, :, 1] @ N1[rows].T
        return out

    def _products_of(self, model: ModalModel, store: dict | None = None) -> dict:
        """The cache of inputs mixed by each numerator for the model's input coupling
        (``u_in``'s only variable): :func:`mixed_inputs` / :func:`mixed_lines` fill it.
        ``store``: another per-coupling store than ``_products`` (the filters' outputs)."""
        store = self._products if store is None else store
        T_in = _key(model.T_in)
        products = store.get(T_in)
        if products is None:
            if len(store) > 8:
                store.clear()
            products = store[T_in] = {}
        return products

    def _u_in(self, model: ModalModel) -> np.ndarray:
        return self.u_rows if model.T_in is None else self.u_rows @ model.T_in.T

    def _parts_sum(self, model: ModalModel, u_in, channels: tuple) -> np.ndarray:
        """``D`` and every mode's output on the rows summed, (n_rows, n_y), a new array.

        From a near anchor when there is one: a sum summed directly (kept, with its parts,
        for the last :data:`ROW_ANCHORS` models so summed) of a model with the same
        channels whose parts differ from this model's in at most two places (a screen or a
        fit moving or adding one mode: most evaluations), the changed parts subtracted and
        added; the unchanged parts are recognised by identity (a structure's ``build``
        keeps the other modes' objects), which costs nothing, where looking each part up by
        its values (the parts' cache) costs a key per mode. Rounding ~1e-16 of the
        anchor's largest row, never chained: a sum derived so is not an anchor.
        """
        items = ((model.D if np.any(model.D) else None),) + model.modes
        for anchor in reversed(self._anchors):
            a_channels, a_items, a_parts, a_sum = anchor
            extra = len(items) - len(a_items)
            if a_channels != channels or not 0 <= extra <= 2:
                continue
            changed = [k for k in range(1, len(a_items)) if a_items[k] is not items[k]]
            if a_items[0] is not items[0] and not (
                # D: a model's copy, compared by value (None where it is zero)
                a_items[0] is not None
                and items[0] is not None
                and np.array_equal(a_items[0], items[0])
            ):
                changed.insert(0, 0)
            if len(changed) + extra > 2:
                continue
            y = a_sum.copy()
            for k in changed:
                if a_parts[k] is not None:
                    y -= a_parts[k]
                part = self._item_part(model, items[k], u_in, channels)
                if part is not None:
                    y += part
            for item in items[len(a_items) :]:
                y += self._item_part(model, item, u_in, channels)
            return y
        parts = [self._item_part(model, item, u_in, channels) for item in items]
        y = np.zeros(self.target.shape)
        for part in parts:
            if part is not None:
                y += part
        if len(self._anchors) >= ROW_ANCHORS:
            self._anchors.pop(0)
        self._anchors.append((channels, items, parts, y.copy()))
        return y

    def _item_part(self, model: ModalModel, item, u_in, channels: tuple):
        """The output of one item of :meth:`_parts_sum` (the feedthrough ``D``, None when it
        is zero, or a mode) on the rows, or None."""
        if item is None:
            return None
        if isinstance(item, np.ndarray):
            return self._part(model, None, item, None, u_in, channels)
        return self._part(model, item.denominator(), *item.numerator(), u_in, channels)

    def fitted(self, model: ModalModel) -> np.ndarray:
        """The model's output on the rows (n_rows, n_y), its start fitted when there is a basis."""
        u_in = self._u_in(model)
        channels = self._channels_key(model)
        y = self._parts_sum(model, u_in, channels)
        if model.T_out is not None:
            y = y @ model.T_out.T
        Q = self._start_basis(model)
        if Q is not None:
            y = self.target - _remove(Q, self.target - y)
        return y

    def residual(self, model: ModalModel) -> np.ndarray:
        return ((self.target - self.fitted(model)) / self.scale).ravel()

    def cost(self, model: ModalModel) -> float:
        return float(np.sum(((self.target - self.fitted(model)) / self.scale) ** 2))

    # ------------------------------------------------------ transient basis
    def _keep_basis(self, key: tuple, Q: np.ndarray) -> None:
        if len(self._basis_cache) > 50:
            self._basis_cache.clear()
        self._basis_cache[key] = Q

    def _cached_basis(self, key: tuple) -> np.ndarray:
        """The transient basis of ``key`` = (head terms, poles) (the subclass's
        ``_start_basis``): kept, extended from a kept one (:meth:`_basis_near`), or afresh
        (``_basis_of``)."""
        Q = self._basis_cache.get(key)
        if Q is None:
            Q = self._basis_near(key)
            if Q is None:
                Q = self._basis_of(key)
            self._keep_basis(key, Q)
        return Q

    def _basis_near(self, key: tuple) -> np.ndarray | None:
        """The basis of ``key`` = (head terms, poles) from a kept basis of a part of its
        terms, or None.

        A fit or a screen moves one mode (or adds one, or moves a few together: a
        suspension's stiffness moves every rigid-body DOF's pole) or lengthens the delay
        line (the head: a whole record's delay-line terms, ``_head_columns``), and the
        other terms stay: the basis of those (kept: the same poles with a shorter head,
        or the most of its poles, at least half; or computed once here when the previous
        new key differed from this one in the same places) is extended by the new terms' columns
        (``_pole_columns``, :func:`_appended`). The same span as ``_basis_of``'s, at a
        fraction of its cost. None where a new column lies within :data:`NEAR_SPAN` of
        the others' span (there :func:`_orthonormal_columns`'s rank decision on all
        columns applies).
        """
        last, self._last_new = self._last_new, key
        n_head, poles = key
        # a delay's grid (ascending) and its fit lengthen the delay line of the same poles:
        # its further terms z^-j appended (a 300-term line afresh was 0.3 s)
        shorter = [k[0] for k in self._basis_cache if k[1] == poles and k[0] < n_head]
        if shorter:
            m = max(shorter)
            return _appended(self._basis_cache[(m, poles)], self._head_columns(m, n_head))
        # at most half the poles new (one of one): where most move (a coupled suspension's
        # refit on a record, 6 of 10 modes) their columns appended cost more than the whole
        # basis afresh (indep3 beam record: 6.0 against 4.6 ms)
        most = max(1, len(poles) // 2)
        have = set(poles)
        rest = None  # (the kept key's poles, its basis), the fewest poles missing
        for k, Q_rest in self._basis_cache.items():
            if k[0] != n_head or not 0 < len(poles) - len(k[1]) <= most or not have >= set(k[1]):
                continue
            if rest is None or len(k[1]) > len(rest[0]):
                rest = (k[1], Q_rest)
        if rest is None and last is not None and last[0] == n_head and len(last[1]) == len(poles):
            differ = [i for i in range(len(poles)) if last[1][i] != poles[i]]
            if 0 < len(differ) <= most:
                kept = tuple(p for i, p in enumerate(poles) if i not in differ)
                Q_rest = self._basis_of((n_head, kept))
                self._keep_basis((n_head, kept), Q_rest)
                rest = (kept, Q_rest)
        if rest is None:
            return None
        kept = set(rest[0])
        return _appended(rest[1], self._pole_columns([p for p in poles if p not in kept]))

    # --------------------------------------------------------- linear parts
    def _regress_basis(self, model: ModalModel, den) -> np.ndarray | None:
        """The free-response basis the regressors of a term over ``den`` are projected on
        (:meth:`_regress`): the model's (:meth:`_start_basis`)."""
        return self._start_basis(model)

    def _misfit(self, model: ModalModel) -> np.ndarray:
        """:func:`_unmixed_misfit` of ``model`` (n_rows, n_y), kept for the last model asked: a
        screen regresses hundreds of added terms on it."""
        last = self._residual_last
        if last is None or last[0] is not model:
            last = self._residual_last = (model, _unmixed_misfit(self, model))
        return last[1]

    def _regress(self, model, X, groups, den=None, term=None):
        """Per output: LS of the residual on the columns of X[g] (n_rows, n_reg); coef, std.

        ``den``: the denominator of the term the regressors filter through, or None
        (:meth:`_regress_basis`). ``term``: a key of the added term the regressors are; its
        normal equations are then kept for :meth:`added_term_cost`."""
        e = self._misfit(model)
        n_reg = X.shape[-1]
        coef = np.zeros((self.target.shape[1], n_reg))
        std = np.zeros_like(coef)
        Q = self._regress_basis(model, den)
        normal = [] if term is not None and Q is None and model.T_out is None else None
        for g, rows in enumerate(groups):
            Xg = _remove(Q, X[g]) / self.scale
            # the outputs of a group share their regressors
            x, sd = _lstsq_std(Xg, e[:, rows], normal)
            coef[rows], std[rows] = x.T, sd
        self._normal_last = None if normal is None else (model, term, groups, normal)
        return coef, std

    def added_terms_exact(self, model: ModalModel) -> bool:
        """True where :meth:`added_term_cost` and :meth:`added_term_residual` are the cost and
        the residual of ``model`` with the terms added (:meth:`TimeProblem.added_terms_exact`);
        not where a start basis spans the added term's own poles (the lines)."""
        return False

    def _added_residual(self, model: ModalModel, terms) -> np.ndarray:
        """The weighted misfit (n_rows, n_y) of ``model`` with ``terms`` ((den, N0, N1): a
        mode's; den None, N1 None: a feedthrough) added: the model's misfit less the terms'
        output, their inputs filtered for their linear fits (cached) mixed by their
        numerators; no recursion run."""
        u_in = self._u_in(model)
        channels = self._channels_key(model)
        y = 0.0
        for den, N0, N1 in terms:
            y = y + _FilteredProblem._mixed(self, model, den, N0, N1, u_in, channels)
        return self._misfit(model) - y / self.scale

    def added_term_residual(self, model: ModalModel, mode, dD=None, late=None) -> np.ndarray:
        """:meth:`residual` of ``model`` with ``mode`` (and a feedthrough ``dD`` (n_y, n_u), or
        the mode ``late``) appended, (n_obs,), where :meth:`added_terms_exact`: the model's
        weighted misfit minus the terms' output (rounding ~1e-16 of the misfit)."""
        modes = mode if isinstance(mode, tuple) else (mode,)  # an upper residual's several
        terms = [(m.denominator(), *m.numerator()) for m in modes]
        if dD is not None:
            terms.append((None, dD, None))
        if late is not None:
            terms.append((late.denominator(), *late.numerator()))
        return self._added_residual(model, terms).ravel()

    def added_term_cost(self, model: ModalModel, den: np.ndarray, N0, N1) -> float:
        """:meth:`cost` of ``model`` plus the mode ``(N1 s + N0) / (s^2 + den[0] s + den[1])``
        where :meth:`added_terms_exact` (N0, N1 (n_y, n_u), any values: a projected residue
        too).

        From the normal equations :meth:`fit_new_term` solved for ``den`` on this model
        when it was the last linear fit: per output group ``|e|^2 - 2 c.(X^T e) + c^T X^T X c``
        with ``c = (N0, N1)`` of each output, no output formed (a screening evaluates
        hundreds); else from the output (:meth:`added_term_residual`). The rounding is
        ~1e-16 of the model's cost.
        """
        kept = self._normal_last
        if kept is None or kept[0] is not model or kept[1] != ("term", _key(den)):
            r = self._added_residual(model, [(den, N0, N1)])
            return float(np.sum(r * r))
        e = self._misfit(model)
        coef = np.concatenate([N0, N1], axis=1)
        cost = float(np.sum(e * e))
        for rows, (M, Xb, scale) in zip(kept[2], kept[3]):
            c = coef[rows] * scale  # (n_rows_g, p), in the scaled columns
            cost += float(np.einsum("ip,pq,iq->", c, M, c) - 2.0 * np.sum(c * Xb.T))
        return cost

    def fit_new_term(self, model: ModalModel, den: np.ndarray):
        X, groups = self._filtered(model, den, self._u_in(model))
        n_u = model.n_u
        Xc = np.concatenate([X[..., 0], X[..., 1]], axis=-1)  # [u_0..u_{n-1} | s u_0..]
        coef, std = self._regress(model, Xc, groups, den, term=("term", _key(den)))
        return coef[:, :n_u], coef[:, n_u:], std[:, :n_u], std[:, n_u:]

    def fit_feedthrough(self, model: ModalModel):
        X, groups = self._filtered(model, None, self._u_in(model))
        coef, std = self._regress(model, X[..., 0], groups)
        return coef, std

    def fit_upper_residual(self, model: ModalModel, den: np.ndarray, late=None):
        """As :meth:`FrfProblem.fit_upper_residual`, on the record's rows.

        ``late``: the denominator (a1, a0) of a mode far above Nyquist that carries the
        static part instead of ``D`` (what the samples see of it: ``L u[k-1]``, not
        ``D u[k]``); the first matrix returned is then ``L`` (its static gain)."""
        u_in = self._u_in(model)
        X0, groups = self._filtered(model, late, u_in)
        if late is not None:
            X0 = X0 * late[1]  # 1/den has the static gain 1/a0
        cols = [X0[..., 0]]
        for d in np.atleast_2d(den):
            X, _ = self._filtered(model, d, u_in)
            cols += [X[..., 0], X[..., 1]]
        n_u, n_y = model.n_u, self.target.shape[1]
        coef, std = self._regress(model, np.concatenate(cols, axis=-1), groups, den)
        # (n_y, n_u * (1 + 2k)) as (n_y, n_u, 1 + 2k): [D, N0_1, N1_1, ...] per input
        coef = np.moveaxis(coef.reshape(n_y, -1, n_u), 1, -1)
        std = np.moveaxis(std.reshape(n_y, -1, n_u), 1, -1)
        return _upper_parts(coef, std, np.ndim(den) == 1)

    def fit_crosstalk(self, model: ModalModel, side: str):
        ym = self.fitted(model)
        e = (self.target - ym) / self.scale
        n_y, n_u = model.n_y, model.n_u
        if side == "out":
            E = np.zeros((n_y, n_y))
            S = np.zeros((n_y, n_y))
            for i in range(n_y):
                others = [k for k in range(n_y) if k != i]
                X = self._project(model, ym[:, others]) / self.scale
                E[i, others], S[i, others] = _lstsq_std(X, e[:, i])
            return E, S
        # input side: regressor of E[j, k] = column j of the model driven by u_k
        u_in = self._u_in(model)
        parts = [(None, model.D, None)] if np.any(model.D) else []
        parts += [(m.denominator(), *m.numerator()) for m in model.modes]
        R = np.zeros((self.target.shape[0], n_y, n_u, n_u))  # (n_rows, n_y, j, k)
        # per output group, every part's filtered inputs (slots) stacked as Z (n_rows, n_u,
        # P) and their numerators' rows as W (P, rows, n_u): R[:, rows, :, k] = Z[:, k] W,
        # one product per input k (an outer product per part, slot and channel wrote the
        # whole (n_rows, n_y, n_u, n_u) array each time: most of a joint fit's evaluation)
        stacks: dict = {}  # group -> ([filtered inputs], [numerator rows])
        groups = None
        for den, N0, N1 in parts:
            X, groups = self._filtered(model, den, u_in)
            for g, rows in enumerate(groups):
                Zs, Ws = stacks.setdefault(g, ([], []))
                for slot, N in ((0, N0), (1, N1)):
                    if N is not None and (slot == 0 or np.any(N)):
                        Zs.append(X[g, :, :, slot])
                        Ws.append(N[rows])
        for g, (Zs, Ws) in stacks.items():
            rows = groups[g]
            Z = np.stack(Zs, axis=-1)  # (n_rows, n_u, P)
            W = np.stack(Ws).reshape(len(Ws), -1)  # (P, rows n_u)
            Rg = np.empty((Z.shape[0], rows.size, n_u, n_u))
            for k in range(n_u):
                Rg[..., k] = (Z[:, k, :] @ W).reshape(-1, rows.size, n_u)
            R[:, rows] = Rg
        if model.T_out is not None:
            R = np.einsum("ab,nbjk->najk", model.T_out, R)
        R = self._project(model, R)
        pairs = [(j, k) for j in range(n_u) for k in range(n_u) if j != k]
        Xr = np.stack([R[:, :, j, k].ravel() for j, k in pairs], -1) / self.scale
        x, s = _lstsq_std(Xr, e.ravel())
        E = np.zeros((n_u, n_u))
        S = np.zeros((n_u, n_u))
        for (j, k), xv, sv in zip(pairs, x, s):
            E[j, k], S[j, k] = xv, sv
        return E, S

    def model_frf(self, model: ModalModel, freq=None) -> np.ndarray:
        f = np.geomspace(*self.band_hz, 400) if freq is None else freq
        return model.frf(f)


class TimeProblem(_FilteredProblem):
    """Fit to a time record (spec 1a): ZOH simulation driven by the recorded u.

    From rest (the spec's measure) when the record starts at rest. A record that
    starts in motion (:func:`moving_start`) is compared from an estimated start:
    the model's free response, the sampled modes' ``Re, Im lambda^k`` and the
    rigid body's ``1, k`` (position and velocity), is fitted to the misfit by least
    squares per output and added to the prediction; regressors of the linear fits
    are projected the same way (variable projection: the start is a nuisance
    parameter). ``transient`` says which. Not compare's
    :func:`workbench.ident.validate.estimate_x0` (one state vector shared by the
    outputs): every candidate structure's linear fits need the projector itself,
    and a per-output basis of the modal model's poles gives it in one QR.
    """

    def __init__(self, data: TimeData, transient: bool | None = None):
        self.data = data
        self.u = self.u_rows = data.u
        self.y = self.target = data.y
        self.fs = data.fs
        self.scale = float(np.sqrt(np.mean(data.y**2))) or 1.0
        self.n_obs = data.y.size
        self.has_var = False
        self.noise_floor = None
        self.band_hz = _time_band(data)
        self.transient = moving_start(data) if transient is None else bool(transient)
        self._cache: dict = {}
        self._filter_cache: dict = {}
        self._basis_cache: dict = {}
        self._last_new: tuple | None = None  # the last key whose basis was not kept
        self._anchors: list = []  # (channels, items, parts, sum), see _parts_sum
        self._residual_last = None  # (model, its weighted residual), see _misfit
        self._normal_last = None  # (model, term, groups, normal equations), see _regress
        self._products: dict = {}  # T_in -> numerator, rows, cols -> mixed inputs (_mixed)
        self._outputs: dict = {}  # T_in -> filter, its inputs -> its output (_mixed)

    def _filter(self, model, den, u_in):
        return filtered_inputs(model, den, u_in, self.fs)

    def _mixed(self, model, den, N0, N1, u_in, channels):
        """A mode's output on the record by :func:`mixed_inputs` (its inputs mixed by the
        numerators, one recursion per output group); the filtered inputs (:meth:`_filter`)
        only where a linear fit needs them as regressors. The feedthrough (``den`` None):
        the delayed inputs mixed (:meth:`_FilteredProblem._mixed`)."""
        if den is None:
            return super()._mixed(model, den, N0, N1, u_in, channels)
        products = self._products_of(model)
        outputs = self._products_of(model, self._outputs)
        return mixed_inputs(model, den, N0, N1, u_in, self.fs, products=products, outputs=outputs)

    def added_terms_exact(self, model: ModalModel) -> bool:
        """On a record from rest without output coupling: no start fitted, and the terms are
        fitted to the misfit as the outputs see it. :meth:`added_term_cost` and
        :meth:`added_term_residual` are then the model's cost and residual with the terms
        added, at a fraction of building the model and simulating it."""
        return model.T_out is None and not self.transient

    def _start_basis(self, model: ModalModel) -> np.ndarray | None:
        """Orthonormal basis (N, n_b) of the model's free responses, or None (from rest)."""
        if not self.transient:
            return None
        poles = tuple((m.freq_hz, m.damping) for m in model.modes if m.freq_hz > 0)
        return self._cached_basis((0, poles))

    def _basis_of(self, key: tuple) -> np.ndarray:
        """Orthonormal basis (N, r) of the rigid body's position and velocity and the free
        responses of ``key`` = (0, ((freq Hz, damping), ..)) (:meth:`_start_basis`), afresh."""
        k = np.arange(self.y.shape[0], dtype=float)
        drift = np.column_stack([np.ones_like(k), k / k[-1]])
        return _orthonormal_columns(np.column_stack([drift, self._pole_columns(key[1])]))

    def _pole_columns(self, poles) -> np.ndarray:
        """Free responses (N, k) real, ``Re, Im lambda^n`` of each (freq Hz, damping) of
        ``poles`` but those gone within a sample.

        ``lambda^n = lambda^(B a) lambda^b`` (n = B a + b, b < B): two short tables of
        powers (complex exponentials of ``n log lambda``, as accurate as those of every
        sample) and one product per sample, where an exp, a cos and a sin per sample
        were most of a fresh basis (10 modes, 16 384 samples: 4.3 against 0.6 ms).
        """
        N = self.y.shape[0]
        logs = []
        for f, z in poles:
            w = 2 * np.pi * f
            z = min(z, 0.999)
            sigma, wd = -z * w / self.fs, w * np.sqrt(1 - z * z) / self.fs
            if sigma < np.log(1e-3):  # gone within a sample
                continue
            logs.append(complex(sigma, wd))
        if not logs:
            return np.zeros((N, 0))
        s = np.array(logs)[:, None]
        # a growing response (a trial point's negative damping) counted back from the last
        # sample, lambda^(n - N + 1): the same column scaled, where lambda^n overflowed
        back = np.where(s.real > 0, N - 1, 0)
        B = int(np.ceil(np.sqrt(N)))
        powers = (
            np.exp(s * (B * np.arange(-(-N // B)) - back))[:, :, None]
            * np.exp(s * np.arange(B))[:, None]
        )
        powers = powers.reshape(len(logs), -1)[:, :N]
        C = np.empty((N, 2 * len(logs)))
        C[:, 0::2], C[:, 1::2] = powers.real.T, powers.imag.T
        return C

    def predict(self, model: ModalModel) -> np.ndarray:
        """Simulated output (N, n_y): from rest, or from the estimated start (``transient``)."""
        return self.fitted(model)

    def record_cost(self, model: ModalModel) -> float:
        """The cost on the measurement as recorded (here the fitted cost itself)."""
        return self.cost(model)

    def error(self, model: ModalModel) -> float:
        return relative_error_time(self.y, self.predict(model))

    def residual_peaks(self, model: ModalModel, n: int = 6) -> list[float]:
        """Peaks (Hz) of the residual spectrum over the input spectrum, a crude |dG|^2."""
        e = self.y - self.predict(model)
        P = self.data.period
        N = self.y.shape[0]
        rec = _periodic(self.data)
        if rec is not None:
            seg_e, seg_u, L = e[N - P :], self.u[N - P :], P
        else:
            win = np.hanning(N)[:, None]
            seg_e, seg_u, L = e * win, self.u * win, N
        E = np.sum(np.abs(np.fft.rfft(seg_e, axis=0)) ** 2, axis=1)
        U = np.sum(np.abs(np.fft.rfft(seg_u, axis=0)) ** 2, axis=1)
        f = np.fft.rfftfreq(L, 1 / self.fs)
        if rec is not None:  # the lines the excitation drives (workbench.signals.periodic's rule)
            excited = np.zeros(f.size, bool)
            excited[rec.lines] = True
            excited &= U > 0
        else:
            excited = U > 1e-6 * U.max()
        ok = excited & (f >= self.band_hz[0]) & (f <= self.band_hz[1])
        if not ok.any():
            return []
        return _peaks(f[ok], E[ok] / U[ok], n)


def _sampled_poles(m: Mode, fs: float) -> list[complex]:
    """A mode's poles sampled at ``fs`` (Hz), ``exp(lambda / fs)``: upper half plane or real.

    A rigid mode gives none (its drift is a term of its own).
    """
    if m.kind == "rigid":
        return []
    den = m.denominator()
    if den.size == 1:
        return [complex(np.exp(-den[0] / fs))]
    h, a0 = 0.5 * den[0], den[1]
    disc = h * h - a0
    if disc < 0:
        return [complex(np.exp(complex(-h, np.sqrt(-disc)) / fs))]
    r = np.sqrt(disc)
    return [complex(np.exp((-h + r) / fs)), complex(np.exp((-h - r) / fs))]


#: a sampled pole whose free response falls below this share of its start value over the
#: dropped transient periods needs no transient term (1e-6: far below any record's noise)
SETTLED = 1e-6


#: a moved pole's unit transient columns at most this far from the other poles' span are
#: not appended to their basis (the whole basis is computed afresh): the limit of
#: _orthonormal_columns' Cholesky path, cond < 1e4 (the beam's poles near z = 1 leave 1-4 %)
NEAR_SPAN = 1e-4

#: a moved pole's unit transient column whose part orthogonal to the other poles' span is
#: shorter than this is evaluated alone (:meth:`PeriodicProblem._extension`)
SCHUR_CLEAR = 1e-3


class PeriodicProblem(_FilteredProblem):
    """Fit to a periodic time record in the frequency domain, on its steady-state periods.

    The record's mean kept period per experiment block
    (:class:`~workbench.signals.periodic.PeriodicRecord`, the first period of every
    block dropped) is taken at its excited lines: there the model's output is
    ``H(z_l) U_l`` (:func:`~workbench.modal.simulate.filtered_lines`, the same exact ZOH
    filters as the time-domain simulation) plus the leakage of whatever has not
    settled (a lightly damped mode's free response, the rigid body's drift), which
    is the frequency-domain transient term ``sum_p c_p / (1 - p z^-1)`` over the
    model's sampled poles ``p`` (rigid: ``1/(1 - z^-1)``, ``1/(1 - z^-1)^2``), fitted per
    output and block and projected out like the time domain's estimated start
    (Pintelon & Schoukens, *System Identification*, 2nd ed., 2012, section 6.3:
    the transient term of a periodic record). Rows are the real and imaginary parts
    of the lines, uniformly weighted as the time domain weights its samples.

    Costs and residuals (what the fits minimize) are on the lines; ``predict``,
    ``error`` and ``residual_peaks`` stay the time-domain ones (:class:`TimeProblem`:
    the spec's error measure, the detectors' simulated record), so every number a
    finding reports is the same measure as before. About N / (2 n_lines) times
    fewer rows than the record and no recursive filter: a 10,000-sample record's
    fit evaluates in a fraction of the simulation's time. A fit's evaluations reuse
    what did not change: each filter's line responses (a lag moved on one channel
    recomputes that channel's filters), the inputs mixed by each numerator (a moved
    mode keeps its residues), each mode's output, the sum of the unchanged modes'
    outputs (:meth:`_parts_sum`: a moved or added mode costs its own output only), and
    the transient basis of the other poles when one pole moves or is added
    (:meth:`_basis_near`); a mode's output is computed from its filters' responses
    (:func:`~workbench.modal.simulate.mixed_lines`), its filtered inputs only where a
    linear fit needs them as regressors. The fit engine refines on these rows as on
    FRF data (Levenberg-Marquardt on normal equations,
    :func:`workbench.diagnosis.fit.levenberg_marquardt`).

    Without ``rec`` the whole record is the one block (:func:`record_block`, period = N,
    nothing dropped: ``domain="frequency"`` for a record that is not steady-state
    periodic): its DFT obeys ``Y = H U + T`` exactly at every line, ``T`` over every pole of
    the model (modes, lags) and the delay line's ``1, z^-1, ..`` (:meth:`_start_basis`).
    Its lines are about as many as the samples: it keeps the time domain's solver and
    structures (``domain`` "time") and its residual peaks (:meth:`residual_peaks`).
    """

    #: the record's data, its costs on the lines (FrfProblem's domain; ``kind`` stays "time")
    domain = "frequency"

    def __init__(self, data: TimeData, rec=None):
        self.data = data
        self.fs = data.fs
        self.time = TimeProblem(data)
        self.band_hz = self.time.band_hz
        self.transient = self.time.transient
        self.has_var = False
        self.noise_floor = None
        #: the whole record is the one block (``rec`` None): nothing settles, every pole and
        #: the delay line leak (:meth:`_start_basis`), and residual_peaks is the time domain's
        self.whole = rec is None
        if rec is None:
            rec = record_block(data)
            # its lines are about as many as the record's samples: an evaluation costs about
            # what a simulation does, and the fits are those of the time domain (scipy's trust
            # region; no structure offered for cheap evaluations only, fit.py, effects.py)
            self.domain = "time"
        # samples every kept period lies after its block's start: a free response that falls
        # below SETTLED of its start value within them leaks nothing the noise would not hide
        self.settle = int(rec.period * rec.n_dropped.min())
        blocks = [np.flatnonzero(rec.excited[b]) for b in range(rec.n_blocks)]
        self.block_of = np.concatenate([np.full(ln.size, b) for b, ln in enumerate(blocks)])
        lines = np.concatenate(blocks)
        self.z = np.exp(2j * np.pi * lines / rec.period)
        self._zi = 1.0 / self.z
        self._lines, self._period = lines, rec.period  # z = exp(2j pi lines / period)
        self._blocks = [self.block_of == b for b in np.unique(self.block_of)]
        #: the excited lines' frequencies (every block's), Hz, ascending
        self.line_hz = np.unique(lines) * self.fs / rec.period
        U = np.concatenate([rec.U[b, ln] for b, ln in enumerate(blocks)])
        Y = np.concatenate([rec.Y[b, ln] for b, ln in enumerate(blocks)])
        self.u_rows = U
        self.target = np.concatenate([Y.real, Y.imag])
        self.scale = float(np.sqrt(np.mean(self.target**2))) or 1.0
        self.n_obs = self.target.size
        self._cache: dict = {}
        self._filter_cache: dict = {}
        self._basis_cache: dict = {}
        self._anchors: list = []  # (channels, items, parts, sum), see _parts_sum
        self._residual_last = None  # (model, its weighted residual), see _misfit
        self._normal_last = None  # (model, term, groups, normal equations), see _regress
        self._basis_key: dict = {}  # the model's poles and channels -> (delay terms, poles)
        self._last_new: tuple | None = None  # the last key whose basis was not kept
        self._responses: dict = {}  # filter -> its responses at z (filtered_lines' cache)
        self._products: dict = {}  # T_in -> numerator -> inputs mixed by it (mixed_lines')

    def _filter(self, model, den, u_in):
        X, groups = filtered_lines(model, den, u_in, self.z, self.fs, responses=self._responses)
        return np.concatenate([X.real, X.imag], axis=1), groups

    def _mixed(self, model, den, N0, N1, u_in, channels):
        """The part on the lines from the filters' responses (:func:`mixed_lines`), the real
        parts of the lines stacked over the imaginary ones; the filtered inputs
        (:meth:`_filter`) only where a linear fit needs them as regressors."""
        products = self._products_of(model)
        Y = mixed_lines(
            model, den, N0, N1, u_in, self.z, self.fs, responses=self._responses, products=products
        )
        return np.concatenate([Y.real, Y.imag])

    def _start_basis(self, model: ModalModel) -> np.ndarray:
        """Orthonormal basis (2 n_l, r) of the transient terms of the model's poles, per block.

        The poles are the modes' and the channels' lags' (first-order, real: the filters'
        denominators are a mode's times its channel's lags) where they have not settled
        (:data:`SETTLED` over :attr:`settle` samples), and, on the whole record
        (:attr:`settle` 0), the delay line's: its ``ceil(delay fs)`` held inputs from
        before the record and at its end leak the polynomial ``1, z^-1, .., z^-(m-1)``
        (a pole of order m at z = 0). A kept period of a periodic record starts with the
        delay line holding the previous period's inputs, the same as at its end: nothing.
        """
        return self._cached_basis(self._transient_key(model))

    def _transient_key(self, model: ModalModel) -> tuple:
        """What :meth:`_start_basis` spans for ``model``: (the delay line's number of
        terms, the unsettled sampled poles rounded to 1e-15), kept per model's poles and
        channels."""
        channels = (
            tuple((m.kind, m.freq_hz, m.damping) for m in model.modes),
            model.delay_s,
            _key(model.lags("in"), model.lags("out")),
        )
        key = self._basis_key.get(channels)
        if key is None:
            poles = [p for m in model.modes for p in _sampled_poles(m, self.fs)]
            taus = np.unique(np.concatenate([model.lags("in"), model.lags("out")]))
            poles += [complex(np.exp(-1.0 / (tau * self.fs))) for tau in taus if tau > 0]
            # keyed by the unsettled poles only: a fit moving a fast mode reuses the basis
            poles = [p for p in poles if abs(p) ** self.settle > SETTLED]
            n_delay = 0
            if self.settle == 0:
                m_int, frac = split_delay(model.delay_s, 1.0 / self.fs)
                n_delay = m_int + (1 if frac > 0 else 0)
            # a pole met twice (two modes at one frequency and damping, a suspension's DOFs
            # started together) once: the same span, where its columns twice are singular
            key = (n_delay, tuple(dict.fromkeys(np.round(poles, 15).tolist())))
            if len(self._basis_key) > 2000:
                self._basis_key.clear()
            self._basis_key[channels] = key
        return key

    def _regress_basis(self, model: ModalModel, den) -> np.ndarray:
        """The basis of ``model`` with a mode over ``den`` (a1, a0) added: the term a linear
        fit adds leaks from its own poles too, and the model it builds is costed with them
        (:meth:`_start_basis`); without them its numerator is biased by that leakage (on the
        whole record, ~1 % for a 170 Hz mode of tests/test_record_problem.py)."""
        dens = None if den is None else np.atleast_2d(den)
        if dens is None or dens.shape[1] != 2 or not np.all(dens[:, 1] > 0):
            return self._start_basis(model)
        terms = []
        for a1, a0 in dens:  # every pseudo-mode of an upper residual's (k, 2)
            w = float(np.sqrt(a0))
            terms.append(
                Mode(
                    "flexible",
                    w / (2 * np.pi),
                    float(a1) / (2 * w),
                    np.zeros(model.n_u),
                    np.zeros(model.n_y),
                )
            )
        return self._start_basis(replace(model, modes=model.modes + tuple(terms)))

    def _columns(self, poles, drift: bool, n_delay: int = 0, first_delay: int = 0) -> np.ndarray:
        """Transient columns (n_l, k) complex: the rigid body's drift (``drift``), the delay
        line's ``z^-j``, ``first_delay`` <= j < ``n_delay``, and the sampled ``poles``' free
        responses, one set per block."""
        zi = self._zi
        cols = [1.0 / (1.0 - zi), 1.0 / (1.0 - zi) ** 2] if drift else []
        if n_delay > first_delay:
            # z^-j = exp(-2j pi (lines j mod period) / period): one exp per entry with the phase
            # reduced exactly (complex powers zi**j one column at a time were most of a long
            # delay line's basis: 300 terms, 0.25 s)
            j = np.arange(first_delay, n_delay)
            phase = (self._lines[:, None] * j) % self._period
            cols.append(np.exp((-2j * np.pi / self._period) * phase))  # (n_l, m): m columns
        for pk in poles:
            b = 1.0 / (1.0 - pk * zi)
            if pk.imag > 0:  # a pair: c b + conj(c) b(conj(p)) with c complex
                bc = 1.0 / (1.0 - np.conj(pk) * zi)
                cols += [b + bc, 1j * (b - bc)]
            else:
                cols.append(b)
        C = np.column_stack(cols)
        if len(self._blocks) == 1:
            return C
        # one set of coefficients per block (each block starts from its own state)
        return np.column_stack([C * blk[:, None] for blk in self._blocks])

    def _basis_of(self, key: tuple) -> np.ndarray:
        """Orthonormal basis (2 n_l, r) of the rigid drift, the delay line and the poles of
        ``key`` = (delay terms, poles) (:meth:`_start_basis`), afresh."""
        C = self._columns(key[1], drift=True, n_delay=key[0])
        return _orthonormal_columns(np.concatenate([C.real, C.imag]))

    def _pole_columns(self, poles) -> np.ndarray:
        """The transient columns of ``poles`` (sampled, upper half plane or real), real and
        imaginary parts of the lines stacked, (2 n_l, k)."""
        C = self._columns(poles, drift=False)
        return np.concatenate([C.real, C.imag])

    def _head_columns(self, first: int, n: int) -> np.ndarray:
        """The delay line's terms ``z^-j``, ``first`` <= j < ``n``, stacked as
        :meth:`_pole_columns`, (2 n_l, n - first)."""
        C = self._columns((), drift=False, n_delay=n, first_delay=first)
        return np.concatenate([C.real, C.imag])

    def costs(self, models: list) -> np.ndarray:
        """:meth:`cost` of each model (inf for None or a numerical failure), (n_models,).

        A screen's grid (:func:`workbench.diagnosis.fit.screen`) moves the same modes of
        one model, their numerators kept (a modal mismatch, a modal pattern, a
        suspension): those models are evaluated together (:meth:`_moved_costs`), the
        moved modes' line responses for the whole grid in one call
        (:func:`~workbench.modal.simulate.mode_line_responses`), added to the other
        modes' outputs summed once, the transient basis of the other poles extended by
        the moved poles' columns per point as :meth:`_basis_near` extends it. Every
        other model (and a point where a moved pole's columns come near the others'
        span) is evaluated alone by :meth:`cost`.
        """
        out = np.full(len(models), np.nan)
        # in batches of about TOGETHER_ROWS / n_obs points: a whole record's rows (~ its
        # samples) times a grid's hundreds of points made arrays of hundreds of MB, each
        # pass over them bound by memory (a planar record's 360-point suspension grid: 12 s)
        n_batches = -(-len(models) // self.batch)
        for batch in np.array_split(np.arange(len(models)), max(n_batches, 1)):
            together = self._moved_costs([models[i] for i in batch])
            if together is not None:
                idx, values = together
                out[batch[idx]] = values
        for i, m in enumerate(models):
            if np.isnan(out[i]):
                try:
                    out[i] = np.inf if m is None else self.cost(m)
                except NUMERICAL_FAILURES:
                    out[i] = np.inf
        out[~np.isfinite(out)] = np.inf
        return out

    @property
    def batch(self) -> int:
        """Models :meth:`costs` evaluates together, at most (and a screen builds at a time:
        :func:`workbench.diagnosis.fit.screen`): about :data:`TOGETHER_ROWS` / n_obs."""
        return max(2 * self.MIN_TOGETHER, self.TOGETHER_ROWS // self.n_obs)

    #: fewest models of one pattern that :meth:`_moved_costs` evaluates together
    MIN_TOGETHER = 8
    #: real numbers of the residual (:attr:`n_obs`) times points that :meth:`costs` evaluates
    #: in one batch (a whole record: 16 points; a periodic record's lines: the whole grid)
    TOGETHER_ROWS = 2**20

    def _moved_costs(self, models: list):
        """The costs of the models that differ from the first only in moved modes, or None.

        Together: every model has the first's channels (delay, no lags, no output
        coupling), its feedthrough and its other modes (the same objects), and its
        moved modes are second-order modes with the first's numerators (the same
        objects). Returns (indices, costs); a cost is NaN where the point must be
        evaluated alone (coinciding poles, an overdamped slow pole, a moved pole's
        columns within :data:`NEAR_SPAN` of the span).
        """
        ms = [(i, m) for i, m in enumerate(models) if m is not None]
        if len(ms) < self.MIN_TOGETHER:
            return None
        ref = ms[0][1]
        if ref.T_out is not None or np.any(ref.lags("in")) or np.any(ref.lags("out")):
            return None
        n = len(ref.modes)
        channels = self._channels_key(ref)
        moved: set = set()
        for _, m in ms:
            # a model's arrays are its own copies (read-only): compared by value; its modes
            # are kept as objects by a structure's build (Mode.moved: a new one)
            if len(m.modes) != n or m.T_out is not None or not np.array_equal(m.D, ref.D):
                return None
            if self._channels_key(m) != channels:
                return None
            moved.update(k for k in range(n) if m.modes[k] is not ref.modes[k])
        if not moved:
            return None
        ks = sorted(moved)

        def same_numerator(a, b):
            return all(
                (x is None and y is None)
                or (x is not None and y is not None and np.array_equal(x, y))
                for x, y in ((a.b, b.b), (a.c, b.c), (a.N0, b.N0), (a.N1, b.N1))
            )

        keep = [
            (i, m)
            for i, m in ms
            if all(
                m.modes[k].kind == "flexible" and same_numerator(m.modes[k], ref.modes[k])
                for k in ks
            )
        ]
        if len(keep) < self.MIN_TOGETHER:
            return None
        idx = np.array([i for i, _ in keep])
        u_in = self._u_in(ref)
        # the other items' outputs summed once (as _parts_sum sums a model directly)
        rest = np.zeros(self.target.shape)
        items = ((ref.D if np.any(ref.D) else None),) + ref.modes
        for j, item in enumerate(items):
            if j - 1 not in moved:
                part = self._item_part(ref, item, u_in, channels)
                if part is not None:
                    rest += part
        n_l, n_y = self.z.size, self.target.shape[1]
        P = len(keep)
        # rows first, points second: every projection one matrix product
        Y = np.zeros((n_l, P, n_y), complex)
        ok = np.ones(P, bool)
        w = np.empty((P, len(ks)))
        zeta = np.empty((P, len(ks)))
        for c, k in enumerate(ks):
            w[:, c] = [2 * np.pi * m.modes[k].freq_hz for _, m in keep]
            zeta[:, c] = [m.modes[k].damping for _, m in keep]
            H, ok_k = mode_line_responses(
                2 * zeta[:, c] * w[:, c], w[:, c] ** 2, self.z, self.fs, ref.delay_s
            )
            ok &= ok_k
            for h, N in zip((H[:, 0], H[:, 1]), ref.modes[k].numerator()):
                if np.any(N):
                    Y += h.T[:, :, None] * (u_in @ N.T)[:, None, :]
        # the residual rows as the target's: real parts first, then imaginary (one array)
        R = np.empty((2 * n_l, P, n_y))
        np.subtract((self.target - rest)[:n_l, None, :], Y.real, out=R[:n_l])
        np.subtract((self.target - rest)[n_l:, None, :], Y.imag, out=R[n_l:])
        del Y
        # the transient basis: the unmoved modes' poles, and each moved mode's where it has
        # not settled (the same test as _start_basis)
        others = replace(ref, modes=tuple(m for k, m in enumerate(ref.modes) if k not in moved))
        Q_rest = self._start_basis(others)
        Rf = R.reshape(2 * n_l, P * n_y)
        Rf -= Q_rest @ (Q_rest.T @ Rf)
        lam = -zeta * w + 1j * w * np.sqrt(np.maximum(1.0 - zeta**2, 0.0))  # upper half plane
        poles = np.exp(lam / self.fs)
        slow = np.abs(poles) ** self.settle > SETTLED
        ok &= ~np.any(slow & (zeta >= 1.0), axis=1)  # an overdamped slow pole: alone
        # a pole equal to another moved one adds nothing to the span (two modes' terms over
        # one pole are one term; :meth:`_transient_key` drops it alike): its columns are left
        # out, where they would make the point's columns singular and send it to be evaluated
        # alone (a suspension's grid starts its DOFs at one shared frequency)
        rounded = np.round(poles, 15)
        for c in range(1, len(ks)):
            slow[:, c] &= ~np.any(rounded[:, :c] == rounded[:, c : c + 1], axis=1)
        costs = np.full(P, np.nan)
        for pattern in {tuple(row) for row in slow}:
            sel = np.flatnonzero(np.all(slow == np.array(pattern, bool), axis=1) & ok)
            if sel.size == 0:
                continue
            # every point at once (the usual case): R itself, not a copy of its columns
            Rs = R if sel.size == P else R[:, sel]  # (2 n_l, p, n_y)
            total = np.einsum("ipy,ipy->p", Rs, Rs)
            if any(pattern):
                W, G, fine = self._extension(Q_rest, poles[sel][:, np.array(pattern, bool)])
                # Rs is orthogonal to Q_rest: its part along W's columns with Q_rest removed
                # (W~) has W~^T Rs = W^T Rs, and |P_W~ Rs|^2 = (W^T Rs)^T G^-1 (W^T Rs),
                # G = W~^T W~ (Pythagoras: the cost is what is left of |Rs|^2)
                # (optimize: a batched matrix product, 7x the plain loop's speed)
                along = np.einsum("ipm,ipy->pmy", W, Rs, optimize=True)
                X = np.linalg.solve(G[fine], along[fine])
                sel, total = sel[fine], total[fine] - np.einsum("pmy,pmy->p", along[fine], X)
            costs[sel] = np.maximum(total, 0.0) / self.scale**2
        return idx, costs

    def _extension(self, Q_rest: np.ndarray, poles: np.ndarray):
        """The transient columns of each point's ``poles`` (P, k) (upper half plane,
        :meth:`_columns`) that extend ``Q_rest``: (W, G, fine).

        ``W`` (2 n_l, P, m) the columns, each of unit length; ``G`` (P, m, m) the Gram
        matrix of their parts orthogonal to ``Q_rest`` (W~ = W - Q_rest Q_rest^T W, so G =
        W^T W - (Q_rest^T W)^T (Q_rest^T W): W~ itself is never formed, a pass over the
        rows per column saved, as are its orthonormalization's); ``fine`` (P,) which points'
        columns stay clear of the span, to be evaluated together (the others alone): every
        column of W~ at least :data:`SCHUR_CLEAR` long (the subtraction in G loses up to
        2 |log10 SCHUR_CLEAR| = 6 of its 16 digits: the costs stay within the 1e-9 the
        tests ask of them against the points evaluated alone), and each at least
        :data:`NEAR_SPAN` of its length from the previous ones (the diagonal of G's
        Cholesky factor, as :meth:`_basis_near` tests).
        """
        zi = self._zi[:, None]
        cols = []
        for j in range(poles.shape[1]):
            pk = poles[None, :, j]
            b = 1.0 / (1.0 - pk * zi)
            bc = 1.0 / (1.0 - np.conj(pk) * zi)
            cols += [b + bc, 1j * (b - bc)]
        C = np.stack(cols, axis=-1)  # (n_l, P, 2k)
        if len(self._blocks) > 1:
            C = np.concatenate([C * blk[:, None, None] for blk in self._blocks], axis=-1)
        W = np.concatenate([C.real, C.imag])  # (2 n_l, P, m)
        n_rows, P, m = W.shape
        W /= np.sqrt(np.einsum("ipk,ipk->pk", W, W))
        QW = (Q_rest.T @ W.reshape(n_rows, P * m)).reshape(-1, P, m)
        G = np.einsum("ipk,ipj->pkj", W, W, optimize=True) - np.einsum("rpk,rpj->pkj", QW, QW)
        d = np.diagonal(G, axis1=1, axis2=2)  # squared lengths of W~'s columns
        fine = np.min(d, axis=1) >= SCHUR_CLEAR**2
        scale = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
        L = self._cholesky(G * scale[:, :, None] * scale[:, None, :], fine)
        dL = np.diagonal(L, axis1=1, axis2=2)  # the columns' distances from the previous ones
        fine &= np.min(dL, axis=1) >= NEAR_SPAN * np.max(dL, axis=1)
        return W, G, fine

    @staticmethod
    def _cholesky(G: np.ndarray, fine: np.ndarray) -> np.ndarray:
        """Lower Cholesky factors (P, m, m) of the Gram matrices ``G`` (P, m, m); a point whose
        ``G`` is not positive definite (columns in each other's span) gets the identity and
        ``fine`` (P,) False, in place."""
        try:
            return np.linalg.cholesky(G)
        except np.linalg.LinAlgError:
            L = np.empty_like(G)
            for p in range(G.shape[0]):
                try:
                    L[p] = np.linalg.cholesky(G[p])
                except np.linalg.LinAlgError:
                    L[p] = np.eye(G.shape[1])
                    fine[p] = False
            return L

    def steady_lines(self, model: ModalModel | None = None):
        """The excited lines' steady state: (freq (n_l,) Hz, U (n_l, n_u), Y (n_l, n_y)),
        complex, every block's lines in turn; ``Y`` the record's, or with ``model`` the
        model's output there (its filters' responses times ``U``, no transient term).
        The lines' frequencies repeat where blocks share a line. On a whole record
        (:attr:`whole`) the record's lines hold its transient too."""
        freq = self._lines * self.fs / self._period
        n_l = self.z.size
        if model is None:
            y = self.target
        else:
            y = self._parts_sum(model, self._u_in(model), self._channels_key(model))
            if model.T_out is not None:
                y = y @ model.T_out.T
        return freq, self.u_rows, y[:n_l] + 1j * y[n_l:]

    def predict(self, model: ModalModel) -> np.ndarray:
        """The time-domain simulated output (N, n_y), as :meth:`TimeProblem.predict`."""
        return self.time.predict(model)

    def error(self, model: ModalModel) -> float:
        return self.time.error(model)

    def record_cost(self, model: ModalModel) -> float:
        """The time-domain cost of the whole record (:meth:`TimeProblem.cost`): whether a
        finding explains a large share of the misfit is judged on the record, not on the
        excited lines alone (a static distortion's best linear fit on the lines can halve
        their misfit and leave the record's error almost where it was)."""
        return self.time.cost(model)

    def residual_peaks(self, model: ModalModel, n: int = 6) -> list[float]:
        """Peaks (Hz) of the misfit per line over the input power per line (the whole
        record: :meth:`TimeProblem.residual_peaks`, as before, its lines being the record's)."""
        if self.whole:
            return self.time.residual_peaks(model, n)
        E = (self.target - self.fitted(model)) ** 2
        n_l = self.z.size
        e = np.sum(E[:n_l] + E[n_l:], axis=1)
        u = np.sum(np.abs(self.u_rows) ** 2, axis=1)
        f = np.angle(self.z) / (2 * np.pi) * self.fs
        ok = (u > 0) & (f >= self.band_hz[0]) & (f <= self.band_hz[1])
        if not ok.any():
            return []
        order = np.argsort(f[ok], kind="stable")
        return _peaks(f[ok][order], (e[ok] / u[ok])[order], n)


def _periodic(data: TimeData, n_transient: int = 0):
    """The record's :class:`workbench.signals.periodic.PeriodicRecord`, or None.

    ``n_transient`` periods dropped at the start of every block (0: all periods). None
    when the record is not periodic, has fewer than 2 periods, or no excitation.
    """
    from workbench.signals.periodic import periodic_record

    if not data.period or data.n_samples // data.period < 2:
        return None
    try:
        return periodic_record(data, n_transient=n_transient)
    except InputError:
        return None


def _time_band(data: TimeData) -> tuple[float, float]:
    """Excited band of a time record, Hz (from the periodic excitation if there is one)."""
    N = data.n_samples
    rec = _periodic(data)
    if rec is not None:  # the excited lines of the periodic record, all experiment blocks
        f, lines = rec.freq_hz, rec.lines
    else:
        x = data.r if data.r is not None else data.u
        x = x - x.mean(0)
        f = np.fft.rfftfreq(N, 1 / data.fs)
        pw = np.sum(np.abs(np.fft.rfft(x, axis=0)) ** 2, axis=1)
        lines = np.flatnonzero(pw > 1e-6 * pw.max())
        lines = lines[lines > 0]
        # the top through a Hann window: unwindowed, the step between the record's two ends
        # leaks a floor ~ 1 / sin^2(pi f / fs) up to Nyquist (an indep3 shaft record, noise
        # low-passed at 2600 Hz, sampled at 6900 Hz: -56 dB at Nyquist, over the threshold,
        # its band "to 3450 Hz"; windowed, the floor falls away with the filter)
        pw = np.sum(np.abs(np.fft.rfft(x * np.hanning(N)[:, None], axis=0)) ** 2, axis=1)
        top = np.flatnonzero(pw > 1e-6 * pw.max())
        if lines.size and top.size:
            lines = lines[lines <= max(top[-1], lines[0])]
    if lines.size == 0:
        return float(data.fs / N), float(data.fs / 2)
    return float(f[lines[0]]), float(min(f[lines[-1]], 0.5 * data.fs))


#: fewest excited lines (over all blocks) for the frequency-domain problem: below it the
#: transient terms would take most of the lines' degrees of freedom
MIN_PERIODIC_LINES = 20

#: the whole record's lines :class:`PeriodicProblem` fits: "band", those within the
#: record's excited band (:func:`_time_band`), or "all", 1 .. N/2 - 1
RECORD_LINES = "band"


@dataclass(frozen=True)
class RecordBlock:
    """The whole record as :class:`PeriodicProblem`'s one block: the fields it reads of a
    :class:`~workbench.signals.periodic.PeriodicRecord`, with the record's length as the
    period and nothing dropped (:func:`record_block`)."""

    period: int  # N, samples
    n_dropped: np.ndarray  # (1,) int: 0
    excited: np.ndarray  # (1, N // 2 + 1) bool: the lines fitted
    U: np.ndarray  # (1, N // 2 + 1, n_u) complex: np.fft.rfft of u, unnormalized
    Y: np.ndarray  # (1, N // 2 + 1, n_y) complex: of y

    @property
    def n_blocks(self) -> int:
        return 1


def record_block(data: TimeData, lines: str | None = None) -> RecordBlock:
    """The DFT of the whole record (N samples) as one block (:class:`RecordBlock`).

    For a sampled LTI system it obeys exactly ``Y(k) = G(z_k) U(k) + T(z_k)`` at every
    line, ``z_k = exp(2j pi k / N)``, with ``T`` the transient (leakage) term: for a
    state space (A, B, C, D) ``T(z) = C (zI - A)^-1 z (x_0 - x_N)``, rational with the
    system's own poles (Pintelon & Schoukens, *System Identification*, 2nd ed., 2012,
    section 6.3), whatever the record's input and start. ``lines`` ("band" or "all",
    default :data:`RECORD_LINES`): the lines marked excited; never the DC line (the rigid
    body's drift terms are infinite there) nor the Nyquist line.
    """
    lines = RECORD_LINES if lines is None else lines
    N = data.n_samples
    k = np.arange(N // 2 + 1)
    excited = (k > 0) & (2 * k < N)
    if lines == "band":
        f = k * data.fs / N
        lo, hi = _time_band(data)
        excited &= (f >= lo * (1 - 1e-9)) & (f <= hi * (1 + 1e-9))
    elif lines != "all":
        raise InputError(f"lines: expected 'band' or 'all', got {lines!r}")
    U = np.fft.rfft(np.asarray(data.u, float), axis=0)
    Y = np.fft.rfft(np.asarray(data.y, float), axis=0)
    return RecordBlock(N, np.zeros(1, int), excited[None], U[None], Y[None])


DOMAINS = ("auto", "time", "frequency")


def make_problem(data, *, domain: str = "auto"):
    """The problem for a measurement: FrfProblem, PeriodicProblem or TimeProblem.

    ``domain`` (time records): "time" fits the simulated record (:class:`TimeProblem`, the
    reference); "frequency" fits DFT lines (:class:`PeriodicProblem`): the steady-state
    periods' excited lines when every experiment block of the record repeats its
    excitation at least twice and there are :data:`MIN_PERIODIC_LINES` excited lines,
    else the whole record's DFT as one block (:func:`record_block`: a record that is not
    periodic, has fewer periods or starts in motion; refused with fewer than
    :data:`MIN_PERIODIC_LINES` lines in its band). "auto" takes the steady-state lines
    where there are, else the whole record's lines for a record that starts in motion
    (:func:`moving_start`) and the simulation for one from rest: the whole record's lines
    are about as many as its samples and every evaluation projects out their leakage
    terms (every pole, the delay line), which the simulation of a record from rest does
    not have; from a moving start both have them, and the lines' are cheaper to update
    (indep3 time suite, CPU, session 30: from rest the lines took 0.9-2.3x the simulation's
    time, 11 of 13 records more; in motion 0.5-0.9x in 5 of 6 records, 1.5x in one; README.
    With the compiled simulation of session 31, one evaluation from a moving start: 5.9 ms
    simulated, its start basis not updated incrementally, against 2.9 ms on the lines).
    """
    if domain not in DOMAINS:
        raise InputError(f"domain: expected one of {DOMAINS}, got {domain!r}")
    if isinstance(data, FrfData):
        return FrfProblem(data)
    if isinstance(data, TimeData):
        if domain == "time":
            return TimeProblem(data)
        rec = _periodic(data, n_transient=1)
        # steady state: every experiment block repeats its excitation (a period dropped, one
        # kept at least), and enough lines to carry the transient terms
        if (
            rec is not None
            and np.all(rec.n_dropped >= 1)
            and rec.excited.sum() >= MIN_PERIODIC_LINES
        ):
            return PeriodicProblem(data, rec)
        few = record_block(data).excited.sum() < MIN_PERIODIC_LINES
        if domain == "auto" and (few or not moving_start(data)):
            return TimeProblem(data)
        if few:
            raise InputError(
                f"domain 'frequency': expected >= {MIN_PERIODIC_LINES} lines in the record's "
                f"band, got a record of {data.n_samples} samples"
            )
        return PeriodicProblem(data)
    raise TypeError(f"data: expected FrfData or TimeData, got {type(data).__name__}")

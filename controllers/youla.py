"""Convex design on the Youla parameter: limits of performance, and controllers that reach them.

Every controller that stabilizes the loop can be written around one stabilizing
``K0`` as (Boyd & Barratt, *Linear Controller Design: Limits of Performance*,
1991, ch. 7; Zhou, Doyle & Glover 1996, ch. 12)::

    K = K0 + Q (I - H Q)^-1,     H = S0 G = G (I + K0 G)^-1   (stable),   Q stable,

and then every closed-loop map is AFFINE in Q (loop e = r - y, u = K e, y = G u,
an input force d at the plant input, z = Gz (u + d) a performance output)::

    S   = (I + G K)^-1         = S0 - H Q S0                  (n_y, n_y)
    T_dz = Gz (I + K G)^-1     = Gz Si0 - Gz Si0 Q H          (n_z, n_u)

(S0, Si0 the output / input sensitivities with K0). Bounds on |S_ii(f)| and
peaks of |T_dz(f)| are then second-order cone constraints in the parameters of
Q: the best achievable figure over ALL stabilizing controllers is a convex
program, and its solution is a controller. Q is a finite expansion

    Q(z) = Theta_0 + sum_k Theta_k phi_k(z),    phi_k  Laguerre functions with pole ``pole``
    (``pole = 0``: phi_k = z^-k, an FIR Q),

so each solve gives an achievable design (a lower bound on the optimum, up to
the frequency grid), which rises to the optimum as the number of basis functions
grows: a study reports it for several sizes and calls the figure a limit when it
has stopped moving. Constraints hold on the frequency grid only; every result is
re-checked by :func:`workbench.loop.analyze_loop` on its own dense grid.

Two designs::

    maps = youla_maps(G, K0, f)                 # G discrete (incl. ZOH and loop delay)
    d = max_bandwidth(maps, ms_max=2.0)         # largest -3 dB sensitivity bandwidth
    d = min_band_peak(maps, band_hz, ms_max=2.0)  # smallest peak of |T_dz| in a band
    d.controller                                # StateSpaceController e -> u (K0's names)

Units: Hz, the plant's units; dt = 1/fs of G and K0.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from controllers.protocol import StateSpaceController
from workbench.core.errors import DataWarning, InputError

__all__ = [
    "ModelError",
    "YoulaMaps",
    "YoulaDesign",
    "interaction_bound",
    "laguerre_basis",
    "model_error",
    "youla_maps",
    "youla_controller",
    "max_bandwidth",
    "min_band_peak",
    "relative_error",
    "rms_weights",
    "scan_error_affine",
    "z_rms",
    "z_rms_exact",
    "min_mixed_sensitivity",
]


def laguerre_basis(n: int, pole: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, M): n discrete Laguerre functions as one state-space chain.

    x+ = A x + B e,  s = M x  with  s_k = phi_k(z) e,
    phi_k(z) = sqrt(1 - a^2) / (z - a) * ((1 - a z) / (z - a))^k,  a = ``pole``;
    orthonormal on the unit circle; a = 0 gives the delays z^-(k+1).
    Shapes (n, n), (n,), (n, n).
    """
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise InputError(f"n_basis: expected an integer >= 1, got {n!r}")
    if not -1 < pole < 1:
        raise InputError(f"pole: expected -1 < pole < 1 (a stable Laguerre pole), got {pole}")
    a = float(pole)
    M = np.zeros((n, n))
    M[0, 0] = np.sqrt(1 - a * a)
    for k in range(1, n):  # s_k = -a s_{k-1} + (1 - a^2) x_k (the all-pass section)
        M[k] = -a * M[k - 1]
        M[k, k] = 1 - a * a
    A = a * np.eye(n)
    A[1:] += M[:-1]  # x_k+ = a x_k + s_{k-1}
    B = np.zeros(n)
    B[0] = 1.0
    return A, B, M


def _basis_frf(n: int, pole: float, f: np.ndarray, fs: float) -> np.ndarray:
    """(n_f, n + 1) complex: [1, phi_0, ..., phi_{n-1}] at ``f`` (closed form)."""
    z = np.exp(2j * np.pi * np.asarray(f, float) / fs)
    first = np.sqrt(1 - pole * pole) / (z - pole)
    allpass = (1 - pole * z) / (z - pole)
    k = np.arange(n)
    return np.column_stack([np.ones_like(z), first[:, None] * allpass[:, None] ** k[None, :]])


@dataclass(frozen=True)
class ModelError:
    """The design model's additive error against the measured plant, G_meas = G + Delta.

    Both sides discrete (ZOH, delays and aliasing in), u -> y as the design plant.
    ``freq`` (n_f,) Hz, ``delta`` (n_f, n_y, n_u) on those lines; ``spread``
    (n_f, n_y, n_u) a bound on the error of each element of ``delta`` itself
    (k standard deviations of the measurement), zero for an exact error.
    ``exact`` = (G_meas, G) discrete StateSpaces evaluates Delta at any
    frequency (studies on a known truth); otherwise :meth:`at` interpolates
    linearly between the measured lines, holds the end values up to a line
    spacing beyond them and is zero (nothing measured) further above.
    """

    freq: np.ndarray
    delta: np.ndarray
    spread: np.ndarray
    exact: tuple | None = field(default=None, repr=False)
    model: object = field(default=None, repr=False)

    def measured_at(self, f) -> np.ndarray:
        """G_meas = G + Delta at the lines ``f``, (n_f, n_y, n_u)."""
        from workbench.core.lti import frf

        if self.exact is not None:
            return frf(self.exact[0], np.asarray(f, float))
        return frf(self.model, np.asarray(f, float)) + self.at(f)[0]

    def at(self, f) -> tuple[np.ndarray, np.ndarray]:
        """(Delta (n_f, n_y, n_u) complex, spread (n_f, n_u)) at the lines ``f`` (Hz).

        The spread per input column a is ||spread[:, a]||: what the measurement
        does not know of Delta's column a, in that column's units.
        """
        from workbench.core.lti import frf

        f = np.asarray(f, float)
        if self.exact is not None:
            d = frf(self.exact[0], f) - frf(self.exact[1], f)
            return d, np.zeros((f.size, d.shape[2]))
        col = np.linalg.norm(self.spread, axis=1)  # (n_f, n_u)
        return self.on_lines(self.delta, f), self.on_lines(col, f)

    def on_lines(self, values: np.ndarray, f) -> np.ndarray:
        """``values`` (n_freq, ...) on the measured lines, at the lines ``f`` (Hz).

        Linear interpolation (real and imaginary parts), the end values held up to
        a line spacing beyond the measured lines; more than a line spacing above
        the last line nothing is measured and nothing is claimed: zero there (the
        model; tune_youla holds the loops to the baseline there).
        """
        f = np.asarray(f, float)
        flat = np.asarray(values).reshape(len(self.freq), -1)
        out = np.stack([np.interp(f, self.freq, c.real) for c in flat.T], axis=1)
        if np.iscomplexobj(flat):
            out = out + 1j * np.stack([np.interp(f, self.freq, c.imag) for c in flat.T], axis=1)
        step = self.freq[-1] - self.freq[-2] if len(self.freq) > 1 else 0.0
        out[f > self.freq[-1] + step] = 0.0
        return out.reshape(f.size, *np.shape(values)[1:])

    def channel(self, i: int, j: int | None = None) -> ModelError:
        """The SISO error of output i from input j (default i)."""
        i, j = int(i), int(i if j is None else j)
        ex = None if self.exact is None else (self.exact[0][i, j], self.exact[1][i, j])
        sub = self.delta[:, i : i + 1, j : j + 1]
        model = None if self.model is None else self.model[i, j]
        return ModelError(self.freq, sub, self.spread[:, i : i + 1, j : j + 1], ex, model)


def model_error(measured, G, *, loop_delay_samples: int = 0, k_std: float = 3.0) -> ModelError:
    """Delta = G_meas - G: what the design model G lacks against the measured plant.

    Parameters
    ----------
    measured : an FRF (:class:`workbench.io.formats.FrfData`, ZOH compensated as
        the spec has it: the hold is put back here) of the plant from its input
        to its outputs, or a discrete control.StateSpace of the true plant (a
        study: the error is then exact at every frequency).
    G : the discrete design plant u -> y (ZOH and loop delay in), as given to
        :func:`youla_maps`.
    loop_delay_samples : samples of loop delay that G holds and the FRF does
        not (an FRF measured from the plant input, after the real-time delay).
    k_std : the spread is k_std standard deviations of the FRF (its ``G_var``).

    The spread bounds what the measurement does not know; between the FRF's
    lines Delta is interpolated, so a lightly damped mode the lines do not
    resolve is not in it: measure densely where the plant has modes.
    """
    import control

    from workbench.core.lti import frf, zoh_frf

    if isinstance(measured, control.StateSpace):
        if not measured.dt or not np.isclose(measured.dt, G.dt, rtol=1e-9):
            raise InputError(f"measured: expected a discrete plant with dt = {G.dt:g} s, "
                             f"got {measured.dt}")  # fmt: skip
        if (measured.noutputs, measured.ninputs) != (G.noutputs, G.ninputs):
            raise InputError(f"measured: expected {G.noutputs} x {G.ninputs} (G's), got "
                             f"{measured.noutputs} x {measured.ninputs}")  # fmt: skip
        f = np.array([0.5 / G.dt])
        zero = np.zeros((1, G.noutputs, G.ninputs))
        return ModelError(f, zero.astype(complex), zero, (measured, G))
    freq = np.asarray(getattr(measured, "freq", None), float)
    Gm = np.asarray(getattr(measured, "G", None))
    if Gm.ndim != 3 or Gm.shape[1:] != (G.noutputs, G.ninputs) or freq.shape != Gm.shape[:1]:
        raise InputError(f"measured: expected an FRF of shape (n_f, {G.noutputs}, "
                         f"{G.ninputs}), got {Gm.shape}")  # fmt: skip
    fs = 1.0 / float(G.dt)
    if measured.fs is not None and not np.isclose(measured.fs, fs, rtol=1e-9):
        raise InputError(f"measured: expected an FRF taken at fs = {fs:g} Hz (G's), got "
                         f"{measured.fs:g}")  # fmt: skip
    keep = freq <= fs / 2
    freq, Gm = freq[keep], Gm[keep]
    if freq.size < 2:
        raise InputError(f"measured: expected >= 2 lines below Nyquist ({fs / 2:g} Hz)")
    hold = zoh_frf(freq, fs) * np.exp(-2j * np.pi * freq * int(loop_delay_samples) / fs)
    delta = Gm * hold[:, None, None] - frf(G, freq)
    var = getattr(measured, "G_var", None)
    spread = np.zeros(delta.shape)
    if var is not None:
        spread = float(k_std) * np.sqrt(np.asarray(var, float)[keep])
        spread = spread * np.abs(zoh_frf(freq, fs))[:, None, None]
    return ModelError(freq, delta, spread, model=G)


def interaction_bound(error: ModelError, gamma: float = 0.8):
    """t(f): a bound on every |T_ii| of a decentralized loop that keeps the MIMO loop stable.

    With E = (G - G_d) G_d^-1 the relative interaction of the measured plant
    (G_d its diagonal) and T_d the diagonal loops' complementary sensitivities,
    the MIMO loop is stable when every diagonal loop is and rho(E T_d) < 1 at
    every frequency (Grosdidier & Morari 1986; Skogestad & Postlethwaite 2005,
    sec. 10.6); rho(E T_d) <= rho(|E|) max_i |T_ii|, so |T_ii| <= gamma / rho(|E|)
    with gamma < 1 is enough. Returns the callable ``t_bound`` of
    :func:`max_bandwidth` (inf where the plant has no interaction).
    """
    if not 0 < gamma < 1:
        raise InputError(f"gamma: expected 0 < gamma < 1, got {gamma}")

    def t(f):
        Gm = error.measured_at(f)
        d = np.einsum("fii->fi", Gm)
        E = (Gm - d[:, :, None] * np.eye(d.shape[1])) / d[:, None, :]
        rho = np.max(np.abs(np.linalg.eigvals(np.abs(E))), axis=1)
        return np.where(rho > 0, gamma / np.where(rho > 0, rho, 1.0), np.inf)

    return t


@dataclass(frozen=True)
class YoulaMaps:
    """The affine closed-loop maps of one loop on a frequency grid.

    Attributes
    ----------
    f : (n_f,) Hz;  fs : Hz
    phi : (n_f, n_b) complex, the basis responses (column 0 the constant term)
    S0 : (n_f, n_y, n_y);  H : (n_f, n_y, n_u) = S0 G;  Si0 : (n_f, n_u, n_u)
    KS0 : (n_f, n_u, n_y), K0 S0 (the controller's output per output disturbance)
    GzSi0 : (n_f, n_z, n_u) or None, the performance map with K0
    delta, spread : the model error (n_f, n_y, n_u) and its spread per input
        (n_f, n_u) on the grid (:class:`ModelError`), or None
    n_basis, pole : the Laguerre basis of Q (n_b = n_basis + 1)
    G, K0 : the discrete plant (control.StateSpace) and the initial controller
    """

    f: np.ndarray
    fs: float
    phi: np.ndarray
    S0: np.ndarray
    H: np.ndarray
    Si0: np.ndarray
    KS0: np.ndarray
    GzSi0: np.ndarray | None
    n_basis: int
    pole: float
    G: object = field(repr=False)
    K0: StateSpaceController = field(repr=False)
    Gz: object = field(default=None, repr=False)
    diagonal: bool = False
    error: ModelError | None = field(default=None, repr=False)
    delta: np.ndarray | None = field(default=None, repr=False)
    spread: np.ndarray | None = field(default=None, repr=False)

    @property
    def shape_q(self) -> tuple[int, int, int]:
        """(n_b, n_u, n_y): Theta's shape."""
        return self.phi.shape[1], self.H.shape[2], self.H.shape[1]

    @property
    def free(self) -> np.ndarray:
        """(n_b, n_u, n_y) bool: the entries of Theta that are parameters."""
        n_b, nu, ny = self.shape_q
        mask = np.eye(nu, ny, dtype=bool) if self.diagonal else np.ones((nu, ny), bool)
        return np.broadcast_to(mask, (n_b, nu, ny))

    @property
    def theta_size(self) -> int:
        """Number of real parameters of Q."""
        return int(self.free.sum())

    def theta_full(self, theta: np.ndarray) -> np.ndarray:
        """Theta (n_b, n_u, n_y) from the parameter vector (zeros off the structure)."""
        th = np.zeros(self.shape_q)
        th[self.free] = np.asarray(theta, float)
        return th

    def q_frf(self, theta: np.ndarray) -> np.ndarray:
        """Q on the grid, (n_f, n_u, n_y)."""
        return np.einsum("fk,kab->fab", self.phi, self.theta_full(theta))

    def sensitivity(self, theta: np.ndarray) -> np.ndarray:
        """S = S0 - H Q S0 on the grid, (n_f, n_y, n_y)."""
        return self.S0 - self.H @ self.q_frf(theta) @ self.S0

    def z_response(self, theta: np.ndarray) -> np.ndarray:
        """T_dz = Gz Si0 - Gz Si0 Q H on the grid, (n_f, n_z, n_u)."""
        if self.GzSi0 is None:
            raise InputError("z_response: expected maps built with Gz, got none")
        return self.GzSi0 - self.GzSi0 @ self.q_frf(theta) @ self.H

    def _coef(self, L: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(n_f, P, R, n_theta): coefficients of L Q R in theta; L (n_f, P, n_u), R (n_f, n_y, R).

        Only the free entries (a, b) of Theta are formed (a diagonal Q on a 6 x 6
        loop would otherwise cost 36x the memory).
        """
        a, b = np.nonzero(self.free[0])
        C = np.einsum("fk,fpj,fjr->fprkj", self.phi, L[:, :, a], R[:, b, :])
        return C.reshape(*C.shape[:3], -1)  # theta's order: basis function, then (a, b)

    def sensitivity_affine(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(c0 (n_f,), C (n_f, n_theta)) with S_ii = c0 + C theta."""
        C = self._coef(self.H[:, i : i + 1], self.S0[:, :, i : i + 1])
        return self.S0[:, i, i], -C[:, 0, 0]

    def sensitivity_row_affine(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(c0 (n_f, n_y), C (n_f, n_y, n_theta)) with S[i, :] = c0 + C theta."""
        return self.S0[:, i, :], -self._coef(self.H[:, i : i + 1], self.S0)[:, 0]

    def ks_affine(self) -> tuple[np.ndarray, np.ndarray]:
        """(c0 (n_f, n_u n_y), C (n_f, n_u n_y, n_theta)): K S = K0 S0 + Si0 Q S0, flattened."""
        n_f = len(self.f)
        C = self._coef(self.Si0, self.S0)
        return self.KS0.reshape(n_f, -1), C.reshape(n_f, -1, C.shape[-1])

    def error_affine(self) -> tuple[np.ndarray, np.ndarray]:
        """(c0 (n_f, n_y n_y), C (n_f, n_y n_y, n_theta)): M = Delta K S, flattened.

        The loop on the measured plant G + Delta has S_true = S (I + M)^-1.
        """
        if self.delta is None:
            raise InputError("error_affine: expected maps built with a model error, got none")
        n_f = len(self.f)
        C = self._coef(self.delta @ self.Si0, self.S0)
        return (self.delta @ self.KS0).reshape(n_f, -1), C.reshape(n_f, -1, C.shape[-1])

    def measured_coupling(self, theta: np.ndarray) -> np.ndarray:
        """M = Delta K S on the grid, (n_f, n_y, n_y) (maps built with a model error)."""
        if self.delta is None:
            raise InputError("measured_coupling: expected maps built with a model error, got none")
        return self.delta @ (self.KS0 + self.Si0 @ self.q_frf(theta) @ self.S0)

    def true_sensitivity(self, theta: np.ndarray) -> np.ndarray:
        """S (I + Delta K S)^-1 on the grid: the loop on the measured plant, (n_f, n_y, n_y)."""
        S = self.sensitivity(theta)
        if self.delta is None:
            return S
        return S @ np.linalg.inv(np.eye(S.shape[1]) + self.measured_coupling(theta))

    def z_affine(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(c0 (n_f, n_u), C (n_f, n_u, n_theta)) with T_dz[j, :] = c0 + C theta."""
        G = self.GzSi0[:, j, :]
        return G, -self._coef(self.GzSi0[:, j : j + 1], self.H)[:, 0]


@dataclass(frozen=True)
class YoulaDesign:
    """A solved design: the controller, Q's coefficients and the figure on the grid.

    ``value`` is the optimized figure (the bandwidth, Hz, of :func:`max_bandwidth`;
    the peak of :func:`min_band_peak`; gamma of :func:`min_mixed_sensitivity`);
    ``solves`` the number of convex programs, ``seconds`` their wall time.
    ``rms`` (:func:`min_band_peak` with ``rms_factor``): (the design's, K0's) broadband
    rms of z under the disturbance force on the final grid (:func:`z_rms`), z's units
    per unit force std (white) or absolute (``rms_psd``). ``scan_rms`` (with ``scan``):
    (the design's, K0's) rms of z's scan error on the grid (:func:`scan_error_affine`), m.
    """

    controller: StateSpaceController
    theta: np.ndarray
    value: float
    maps: YoulaMaps = field(repr=False)
    solves: int = 1
    seconds: float = 0.0
    status: str = "optimal"
    rms: tuple[float, float] | None = None
    scan_rms: tuple[float, float] | None = None


def _as_controller(K0) -> StateSpaceController:
    """K0 as a StateSpaceController (a Controller, a design holding one, a discrete StateSpace)."""
    import control

    from workbench.loop import _controller_ss

    if isinstance(K0, StateSpaceController):
        return K0
    ctrl = getattr(K0, "controller", K0)
    if not (hasattr(ctrl, "step") or isinstance(ctrl, control.StateSpace)):
        raise InputError(f"K0: expected a discrete controller, got {type(K0).__name__}")
    ss = _controller_ss(ctrl)
    return StateSpaceController(
        ss.A, ss.B, ss.C, ss.D, 1.0 / float(ss.dt),
        tuple(getattr(ctrl, "input_names", ()) or ()),
        tuple(getattr(ctrl, "output_names", ()) or ()),
        int(getattr(ctrl, "delay_samples", 0) or 0),
    )  # fmt: skip


def youla_maps(
    G,
    K0,
    f,
    *,
    Gz=None,
    n_basis: int = 40,
    pole: float = 0.0,
    diagonal: bool = False,
    error: ModelError | None = None,
) -> YoulaMaps:
    """The affine maps of the loop (G, K0) on the grid ``f`` (Hz).

    Parameters
    ----------
    G : discrete control.StateSpace u (n_u) -> y (n_y), with the ZOH and the loop
        delay (e.g. :func:`workbench.loop.discrete_plant`); dt = 1/fs.
    K0 : a stabilizing discrete controller e (n_y) -> u (n_u) at the same dt.
    f : (n_f,) Hz, 0 < f <= fs/2.
    Gz : discrete control.StateSpace u -> z (performance outputs), same dt, or None.
    n_basis, pole : Q's Laguerre basis.
    diagonal : Q diagonal (n_u = n_y): one parameter set per loop; K is still
        MIMO (H couples the loops) and every map keeps the couplings.
    error : the model's error against the measured plant (:func:`model_error`),
        n_y x n_u like G; the programs then hold their bounds on the measured loop.
    """
    from workbench.core.lti import frf
    from workbench.sim import closed_loop_matrices

    Kc = _as_controller(K0)
    Ks = Kc.statespace()
    if not G.dt or not np.isclose(G.dt, Ks.dt, rtol=1e-9):
        raise InputError(f"G: expected a discrete plant with dt = {Ks.dt:g} s (K0's), got {G.dt}")
    if Ks.ninputs != G.noutputs or Ks.noutputs != G.ninputs:
        raise InputError(
            f"K0: expected {G.noutputs} inputs and {G.ninputs} outputs (the plant's), "
            f"got {Ks.ninputs} and {Ks.noutputs}"
        )
    fs = 1.0 / float(G.dt)
    f = np.asarray(f, float)
    if f.ndim != 1 or f.size < 2 or f.min() <= 0 or f.max() > fs / 2 * (1 + 1e-12):
        raise InputError(f"f: expected a 1-D grid in (0, fs/2 = {fs / 2:g}] Hz, got {f.shape}")
    Acl = closed_loop_matrices((G.A, G.B, G.C, G.D), (Ks.A, Ks.B, Ks.C, Ks.D))[0]
    if Acl.size and np.max(np.abs(np.linalg.eigvals(Acl))) >= 1.0:
        raise InputError("K0: expected a controller that stabilizes G, got an unstable loop")
    Gf, Kf = frf(G, f), frf(Ks, f)
    ny, nu = Gf.shape[1], Gf.shape[2]
    if diagonal and nu != ny:
        raise InputError(f"diagonal: expected a square plant, got {ny} outputs and {nu} inputs")
    S0 = np.linalg.inv(np.eye(ny) + Gf @ Kf)
    Si0 = np.linalg.inv(np.eye(nu) + Kf @ Gf)
    GzSi0 = None
    if Gz is not None:
        if not np.isclose(Gz.dt, G.dt, rtol=1e-9) or Gz.ninputs != nu:
            raise InputError(f"Gz: expected {nu} inputs at dt = {G.dt:g}, got {Gz.ninputs}")
        GzSi0 = frf(Gz, f) @ Si0
    delta = spread = None
    if error is not None:
        delta, spread = error.at(f)
        if delta.shape[1:] != (ny, nu):
            raise InputError(f"error: expected a {ny} x {nu} model error, got {delta.shape[1:]}")
    return YoulaMaps(
        f=f, fs=fs, phi=_basis_frf(n_basis, pole, f, fs), S0=S0, H=S0 @ Gf, Si0=Si0,
        KS0=Kf @ S0, GzSi0=GzSi0, n_basis=int(n_basis), pole=float(pole), G=G, K0=Kc, Gz=Gz,
        diagonal=bool(diagonal), error=error, delta=delta, spread=spread,
    )  # fmt: skip


def youla_controller(maps: YoulaMaps, theta: np.ndarray) -> StateSpaceController:
    """K = K0 + Q (I - H Q)^-1 as a StateSpaceController (K0's names and delay).

    Order n(K0) + n(H) + n_y n_basis with H = S0 G realized as
    ``control.feedback(G, K0)``; H is strictly proper (G is, behind a ZOH), so the
    inner loop has no algebraic loop.
    """
    import control

    ny = maps.shape_q[2]
    Th = maps.theta_full(theta)
    A, B, M = laguerre_basis(maps.n_basis, maps.pole)
    Aq = np.kron(np.eye(ny), A)
    Bq = np.kron(np.eye(ny), B[:, None])
    # q = Theta_0 e + sum_j sum_k Theta_k[:, j] s_{j,k},  s_j = M x_j
    Cq = np.hstack([Th[1:, :, j].T @ M for j in range(ny)])
    dt = float(maps.G.dt)
    Q = control.ss(Aq, Bq, Cq, Th[0], dt)
    K0 = maps.K0.statespace()
    H = control.feedback(maps.G, K0)  # G (I + K0 G)^-1 = S0 G
    K = control.parallel(K0, control.feedback(Q, H, sign=1))
    return StateSpaceController(
        K.A, K.B, K.C, K.D, maps.fs, maps.K0.input_names, maps.K0.output_names,
        maps.K0.delay_samples,
    )  # fmt: skip


# ------------------------------------------------------------------ the programs
def _soc_abs(c0, C, theta):
    """Rows [Re; Im] of c0 + C theta (complex affine) for cvxpy's SOC, shape (2, n)."""
    import cvxpy as cp

    re = np.real(C) @ theta + np.real(c0)
    im = np.imag(C) @ theta + np.imag(c0)
    return cp.vstack([re, im])


def _solve(problem) -> str:
    """Solve with Clarabel (the supernodal faer factorization: the programs' rows are dense
    in Q's parameters, 0.27 s an iteration on the beam against 0.4 s with qdldl), its
    default qdldl if faer is refused, SCS last."""
    import cvxpy as cp

    for opts in ({"direct_solve_method": "faer", "max_threads": 1}, {}):
        try:
            problem.solve(solver="CLARABEL", **opts)
            return str(problem.status)
        except (cp.SolverError, ValueError, TypeError, AttributeError):  # faer refused
            continue
    problem.solve(solver="SCS", eps=1e-7, max_iters=20000)
    return str(problem.status)


def _worst_lines(maps: YoulaMaps, theta, loops, ms_max: float, dense: int) -> np.ndarray:
    """Frequencies (Hz) between the grid's lines where |S_ii| exceeds ms_max (local peaks).

    On the measured loop when the maps hold a model error (and where its
    ||Delta K S|| reaches 1). The programs hold |S_ii| <= ms_max on the grid
    only; a lightly damped feature of Q or of the plant can peak between two
    lines. The check runs on ``dense`` times the grid's lines (log-spaced over
    its span, plus midpoints).
    """
    f = maps.f
    fd = np.geomspace(f[0], f[-1], dense * len(f))
    fd = np.setdiff1d(np.union1d(fd, np.sqrt(f[1:] * f[:-1])), f)
    dense = _regrid(maps, fd, with_z=False)
    S = np.abs(np.diagonal(dense.true_sensitivity(theta), axis1=1, axis2=2))[:, loops]
    a = np.max(S, axis=1) / ms_max
    if dense.delta is not None:  # the small-gain figure ||Delta K S|| must stay below 1
        a = np.maximum(a, np.linalg.norm(dense.measured_coupling(theta), axis=(1, 2)))
    peak = (a > 1) & (a >= np.r_[0, a[:-1]]) & (a >= np.r_[a[1:], 0])
    return fd[peak]


def _regrid(maps: YoulaMaps, f: np.ndarray, *, with_z: bool = True) -> YoulaMaps:
    """The same loop and basis on the lines ``f`` (Hz); without Gz when only S is needed."""
    return youla_maps(maps.G, maps.K0, f, Gz=maps.Gz if with_z else None,
                      n_basis=maps.n_basis, pole=maps.pole, diagonal=maps.diagonal,
                      error=maps.error)  # fmt: skip


def _loops(maps: YoulaMaps, loops) -> list[int]:
    ny = maps.S0.shape[1]
    loops = list(range(ny)) if loops is None else [int(i) for i in loops]
    if not loops or any(not 0 <= i < ny for i in loops):
        raise InputError(f"loops: expected indices in 0..{ny - 1}, got {loops}")
    return loops


def max_bandwidth(
    maps: YoulaMaps,
    *,
    ms_max: float = 2.0,
    loops=None,
    target: int | None = None,
    level: float = 1 / np.sqrt(2),
    slope: float = 0.0,
    ratios=None,
    fb_range: tuple[float, float] | None = None,
    t_bound=None,
    rel_tol: float = 0.01,
    refine: int = 4,
) -> YoulaDesign:
    """Largest fb of the template |S_tt(f)| <= level (f/fb)^slope, f <= fb, at |S_ii| <= ms_max.

    ``slope = 0`` (the default, level 1/sqrt 2) is the -3 dB sensitivity
    bandwidth; ``slope = 2, level = 1`` the disturbance-rejection template of a
    double-integrator loop with crossover ~fb (|S| ~ (f/fc)^2 below it), the
    convex stand-in for the crossover, which is not convex in Q.
    Bisection on fb (a quasi-convex figure): feasible when some Q meets the
    template on loop ``target`` and |S_ii(f)| <= ms_max everywhere on the grid
    (every loop of ``loops``, default all). Every loop of ``loops`` gets the
    template when ``target`` is None, loop ``i`` at ``fb * ratios[i]`` when
    ``ratios`` (one per loop of ``loops``, <= 1) is given. Returns the design at
    the largest feasible fb (``value``, Hz, to ``rel_tol``, searched in
    ``fb_range``, default the grid's span). ``t_bound = (f_from_hz, t_max)``
    adds |T_ii(f)| = |1 - S_ii(f)| <= t_max for f >= f_from_hz on every loop: a
    robustness bound where the model is not trusted (aliased modes above
    Nyquist); a callable ``t_bound(f) -> (n_f,)`` bounds |T_ii| line by line
    (inf: none), e.g. :func:`interaction_bound`. The grid is refined
    (``refine`` rounds) where the design's |S_ii| peaks above ms_max between
    its lines.
    """
    loops = _loops(maps, loops)
    targets = loops if target is None else [int(target)]
    r = np.ones(len(loops)) if ratios is None else np.asarray(ratios, float)
    if r.shape != (len(loops),) or not np.all((r > 0) & (r <= 1)):
        raise InputError(f"ratios: expected {len(loops)} values in (0, 1], got {ratios}")
    span = (maps.f[0], maps.f[-1]) if fb_range is None else tuple(float(x) for x in fb_range)
    return _refined(
        lambda m: _max_bandwidth(m, ms_max, loops, targets, level, slope, rel_tol, r, span,
                                 t_bound),
        maps, loops, ms_max, refine,
    )  # fmt: skip


def _refined(solve, maps: YoulaMaps, loops, ms_max: float, rounds: int) -> YoulaDesign:
    """solve(maps) -> (theta, value, solves, status), re-solved on a grid with the
    lines where the last design peaks above ms_max, until none or ``rounds``."""
    t0, solves = time.perf_counter(), 0
    for k in range(int(rounds) + 1):
        theta, value, n, status, *rest = solve(maps)
        solves += n
        if k == int(rounds):
            break  # the design's grid is the one it was solved on (its figures are that grid's)
        extra = _worst_lines(maps, theta, loops, ms_max, dense=8)
        if not extra.size:
            break
        maps = _regrid(maps, np.union1d(maps.f, extra))
    return YoulaDesign(youla_controller(maps, theta), theta, float(value), maps, solves,
                       time.perf_counter() - t0, status,
                       *rest)  # fmt: skip


def _column_scale(blocks) -> np.ndarray:
    """Per-parameter scale: the largest |coefficient| of each column over the blocks.

    Q's coefficients span many decades (a rigid-body loop at 5 kHz needs
    Theta ~ 1e6 where the basis meets small S0 H); the programs solve for
    theta * scale, whose columns are O(1), or the interior-point iterations stall.
    """
    m = np.zeros(blocks[0].shape[-1])
    for C in blocks:
        m = np.maximum(m, np.max(np.abs(C.reshape(-1, C.shape[-1])), axis=0))
    return np.where(m > 0, m, 1.0)


#: lines where K0's ||Delta K0 S0|| + its spread term is below this keep the nominal rows:
#: the model error moves |S| there by that fraction (x the design's gain over K0's), and
#: the dense check on the measured loop (:func:`_worst_lines`) covers the rest
_ERROR_NEGLIGIBLE = 1e-3


class _MeasuredLoop:
    """The robust rows of the programs: on the measured plant G + Delta, per loop i and line,

        ||S[i, :]|| / b_i + r <= s,   ||(I - S + M)[i, :]|| / t + r <= s  (where T is bounded),
        r = ||M||_F + sum_a spread_a ||(K S)[a, :]||,   M = Delta K S

    The measured loop has S_true = S (I + M)^-1 and T_true = (T + M)(I + M)^-1, so
    for ||M|| < 1 (the measured loop is then stable: the small-gain argument on
    G + tau Delta, 0 <= tau <= 1) |S_true[i, i]| <= ||S[i, :]|| / (1 - ||M||) and
    |T_true[i, i]| <= ||(T + M)[i, :]|| / (1 - ||M||): s <= 1 keeps both within
    their bounds; the spread covers the measurement's own error in Delta. Held
    on the lines where the error is not negligible (:func:`_robust_lines`).
    """

    def __init__(self, maps: YoulaMaps, loops, on: np.ndarray):
        self.maps, self.on = maps, on
        ny = maps.S0.shape[1]
        self.rows = [maps.sensitivity_row_affine(i) for i in loops]
        self.err = maps.error_affine()
        e0, E = self.err
        # (T + M)[i, :] = e_i - S[i, :] + M[i, :]
        self.trows = [
            (np.eye(ny)[i] - r0 + e0[:, i * ny : (i + 1) * ny], -R + E[:, i * ny : (i + 1) * ny])
            for i, (r0, R) in zip(loops, self.rows)
        ]
        self.ks = None
        if np.any(maps.spread > 0):  # K S rows per input a: (n_f, n_u, n_y[, n_theta])
            k0, K = maps.ks_affine()
            nu, ny = maps.KS0.shape[1:]
            self.ks = k0.reshape(-1, nu, ny), K.reshape(-1, nu, ny, K.shape[-1])

    def coupling(self, theta, idx) -> np.ndarray:
        """(len(idx),) r = ||M||_F + sum_a spread_a ||(K S)[a, :]|| at ``theta`` on lines idx."""
        r = np.linalg.norm(self.err[0][idx] + self.err[1][idx] @ theta, axis=1)
        if self.ks is not None:
            k0, K = self.ks
            ks = np.linalg.norm(k0[idx] + K[idx] @ theta, axis=2)  # (n, n_u)
            r = r + np.sum(self.maps.spread[idx] * ks, axis=1)
        return r

    def coupling_rows(self, theta, scale, idx) -> tuple:
        """(r, cones): a cvxpy expression r >= :meth:`coupling` on lines idx and its cones."""
        import cvxpy as cp

        v = cp.Variable(idx.size)
        cons = [_row_norm_soc(self.err[0][idx], self.err[1][idx] / scale, theta, v)]
        r = v
        if self.ks is not None:
            k0, K = self.ks
            for a in range(k0.shape[1]):
                e = self.maps.spread[idx, a]
                if not np.any(e > 0):
                    continue
                w = cp.Variable(idx.size)
                cons.append(
                    _row_norm_soc(
                        e[:, None] * k0[idx, a], e[:, None, None] * K[idx, a] / scale, theta, w
                    )
                )
                r = r + w
        return r, cons

    def figure(self, theta, bounds, t) -> np.ndarray:
        """(n_f,) the largest left-hand side over the loops (0 off ``self.on``)."""
        idx = np.flatnonzero(self.on)
        r = self.coupling(theta, idx)
        out = np.zeros(len(self.on))
        for (r0, R), (t0, Tr), b in zip(self.rows, self.trows, bounds):
            u = np.linalg.norm(r0[idx] + R[idx] @ theta, axis=1) / b[idx]
            w = np.linalg.norm(t0[idx] + Tr[idx] @ theta, axis=1) / t[idx]
            out[idx] = np.maximum(out[idx], np.maximum(u, w) + r)
        return out

    def constraints(self, theta, s, bounds, t, scale, lines) -> list:
        """The rows on ``lines`` (indices into the grid) that are in ``self.on``."""
        import cvxpy as cp

        idx = lines[self.on[lines]]
        if not idx.size:
            return []
        r, cons = self.coupling_rows(theta, scale, idx)
        tl = idx[np.isfinite(t[idx])]
        for (r0, R), (t0, Tr), b in zip(self.rows, self.trows, bounds):
            u = cp.Variable(idx.size)
            bi = b[idx]
            cons += [_row_norm_soc(r0[idx] / bi[:, None], R[idx] / (bi[:, None, None] * scale),
                                   theta, u), u + r <= s]  # fmt: skip
            if tl.size:
                ut = cp.Variable(tl.size)
                ti = t[tl]
                rt = r if tl.size == idx.size else r[np.isin(idx, tl)]
                cons += [_row_norm_soc(t0[tl] / ti[:, None], Tr[tl] / (ti[:, None, None] * scale),
                                       theta, ut), ut + rt <= s]  # fmt: skip
        return cons


def _robust_lines(maps: YoulaMaps) -> np.ndarray:
    """(n_f,) bool: the lines where the model error is not negligible."""
    r = np.linalg.norm(maps.delta @ maps.KS0, axis=(1, 2))
    r = r + np.sum(maps.spread * np.linalg.norm(maps.KS0, axis=2), axis=1)
    return r >= _ERROR_NEGLIGIBLE


def _grow(active: np.ndarray, g: np.ndarray, s_value: float, most: int = 24) -> bool:
    """Add to ``active`` (bool, in place) the worst lines where g > s (local peaks first)."""
    bad = (g > s_value * (1 + 1e-6) + 1e-9) & ~active
    if not bad.any():
        return False
    peak = bad & (g >= np.r_[0, g[:-1]]) & (g >= np.r_[g[1:], 0])
    cand = np.flatnonzero(peak if peak.any() else bad)
    active[cand[np.argsort(g[cand])[-most:]]] = True
    return True


def _t_lines(t_bound, f: np.ndarray) -> np.ndarray:
    """(n_f,) the bound on |T_ii| per line (inf where none) from ``t_bound``."""
    if t_bound is None:
        return np.full(len(f), np.inf)
    if callable(t_bound):
        t = np.asarray(t_bound(f), float)
        if t.shape != f.shape or np.any(t <= 0):
            raise InputError(f"t_bound: expected positive bounds of shape {f.shape}, got {t.shape}")
        return t
    f_from, t_max = (float(x) for x in t_bound)
    return np.where(f >= f_from, t_max, np.inf)


def _max_bandwidth(maps, ms_max, loops, targets, level, slope, rel_tol, ratios, span, t_bound):
    """Bisection on fb; each step solves min s: |S_tt| <= template s, |S_ii| <= ms_max s.

    The scaled form is always feasible (Q = 0 gives a finite s), so the solver
    returns an optimum rather than having to certify infeasibility near the
    boundary, which interior-point codes do poorly; fb is feasible iff s <= 1.
    Each row is divided by its bound (the template falls to (f/fb)^2 ~ 1e-5).
    With a model error (maps built with ``error``) the bounds hold on the
    measured loop (:class:`_MeasuredLoop`).

    The rows are dense in Q's parameters and most lines do not bind at the
    optimum, so they are generated: each program holds them on an active set
    of lines (every 6th to start, kept across the bisection), the solution is
    checked on every line, and the worst violated lines join the set until none
    is; the relaxation's optimum is then the full program's.
    """
    import cvxpy as cp

    f = maps.f
    aff = [maps.sensitivity_affine(i) for i in loops]
    scale = _column_scale([C for _, C in aff])
    measured = None
    if maps.delta is not None and (on := _robust_lines(maps)).any():
        measured = _MeasuredLoop(maps, loops, on)
    t = _t_lines(t_bound, f)
    bounded = np.isfinite(t)
    active = np.zeros(len(f), bool)
    active[::6] = True
    active[-1] = True
    programs = 0

    def figure(th, bounds) -> np.ndarray:
        g = np.zeros(len(f))
        for (c0, C), b in zip(aff, bounds):
            S = c0 + C @ th
            g = np.maximum(g, np.abs(S) / b)
            g[bounded] = np.maximum(g[bounded], np.abs(1 - S[bounded]) / t[bounded])
        if measured is not None:
            g = np.maximum(g, measured.figure(th, bounds, t))
        return g

    def scaled(fb):
        nonlocal programs
        bounds = []
        for i, ratio in zip(loops, ratios):
            b = np.full(len(f), float(ms_max))
            if i in targets:
                fbi = fb * ratio
                low = f <= fbi
                b[low] = np.minimum(level * (f[low] / fbi) ** slope, ms_max)
            bounds.append(b)
        while True:  # each round adds lines, so this ends (at worst with every line)
            lines = np.flatnonzero(active)
            tl = lines[bounded[lines]]
            th_s, s = cp.Variable(maps.theta_size), cp.Variable()
            cons = []
            for (c0, C), b in zip(aff, bounds):
                x = _soc_abs(c0[lines] / b[lines], C[lines] / (b[lines, None] * scale), th_s)
                cons.append(cp.SOC(s * np.ones(lines.size), x, axis=0))
                if tl.size:  # T_ii = 1 - S_ii <= t
                    x = _soc_abs((1 - c0[tl]) / t[tl], -C[tl] / (t[tl, None] * scale), th_s)
                    cons.append(cp.SOC(s * np.ones(tl.size), x, axis=0))
            if measured is not None:
                cons += measured.constraints(th_s, s, bounds, t, scale, lines)
            _solve(cp.Problem(cp.Minimize(s), cons))
            programs += 1
            if s.value is None:
                return np.inf, None
            th = np.array(th_s.value) / scale
            g = figure(th, bounds)
            if not _grow(active, g, float(s.value)):
                return float(np.max(g)), th

    (lo, hi), best = span, None
    value, theta = scaled(lo)  # the low end must hold, or nothing does
    if value <= 1.0 + 1e-7:
        best = theta
    else:
        hi = lo
    while hi / lo > 1 + rel_tol:
        mid = np.sqrt(lo * hi)
        value, theta = scaled(mid)
        if value <= 1.0 + 1e-7:
            lo, best = mid, theta
        else:
            hi = mid
    if best is None:
        where = " on the measured loop" if measured is not None else ""
        raise InputError(
            f"max_bandwidth: no Q meets |S| <= {ms_max}{where} with a bandwidth of "
            f"{span[0]:g} Hz on this grid"
        )
    return best, float(lo), programs, "optimal"


def min_band_peak(
    maps: YoulaMaps,
    band_hz: tuple[float, float],
    *,
    ms_max: float = 2.0,
    loops=None,
    z: int = 0,
    elsewhere: float | None = None,
    rms_factor: float | None = None,
    rms_psd=None,
    scan=None,
    scan_factor: float = 1.0,
    z_error=None,
    refine: int = 4,
) -> YoulaDesign:
    """Smallest max over ``band_hz`` of ||T_dz[z, :](f)||_2 at |S_ii| <= ms_max on every loop.

    The norm is over the plant inputs (the response of z to a unit force at each
    actuator); ``value`` is that peak in the units of Gz / G's inputs, on the
    grid's lines in the band. The gain in the band must not be bought with
    amplification elsewhere (the waterbed moved onto z); two guards:

    ``rms_factor`` = rho >= 1: the broadband rms of z under the disturbance force
    (independent, equal forces at every actuator) at most rho times K0's,

        sqrt(sum_k w_k ||T_dz[z, :](f_k)||^2) <= rho * (the same with K0),

    ONE second-order cone over every line of the grid (T_dz is affine in Q, the sum
    a convex quadratic), w_k = the line's cell width (Hz) x the force's one-sided
    PSD (``rms_psd(f) -> (n_f,)``, N^2/Hz; default white with unit variance per
    sample, 2 / fs), :func:`z_rms`. With the white default and Gz on G's states the
    realized design's exact rms on the model (a discrete Lyapunov equation,
    :func:`z_rms_exact`) is checked and the cone tightened until it holds (at most
    4 times): the grid's quadrature misses what peaks between its lines. ``design.rms``
    reports the grid figures.

    ``scan`` = (r (N,), ff (N, n_u)): a scan's reference (m, the same at every measured
    output and at z: a rigid translation) and feedforward force (N) records at fs; the rms
    of z's tracking error in that scan on the model at most ``scan_factor`` (>= 1) x K0's,
    a second cone of the same kind (:func:`scan_error_affine`): the band design's Q acts on
    the reference path too (on the beam, without it, 4.4x pid-notch's scan error at z).

    ``elsewhere`` = e >= 1 (per line, kept; the cone supersedes it: it bounds the
    figure that is reported, and on the beam the per-line rows did not converge in 20
    min, in a run whose band sat on a 2.6 Hz suspension mode): outside the band
    ||T_dz(f)|| <= e ||T_dz(f) with K0|| on every line. Both may be given.
    The grid is refined as in :func:`max_bandwidth`.

    Maps built with a model error (``youla_maps(..., error=...)``): the |S_ii|
    bounds hold on the MEASURED loop (:class:`_MeasuredDiagonal`: stable, |S_ii| <=
    ms_max on G + Delta), the rows generated over the lines as in
    :func:`max_bandwidth`.

    ``z_error`` (a relative bound eps >= 0, a number or a callable ``eps(f) ->
    (n_f,)``, e.g. :func:`relative_error`) makes the figure robust to the
    model's error at z, which no sensor sees in operation: with Gz_true = Gz +
    dGz, ||dGz[z, :]|| <= eps ||Gz[z, :]||, the band rows become

        ||T_dz[z, :]|| + eps ||Gz[z, :]|| ||Si||_F <= t,    Si = (I + K G)^-1 = Si0 - Si0 Q H,

    an upper bound of ||Gz_true Si[z, :]||: a Q that cancels the force at z
    through the model (T_dz ~ 0 with Si large) pays for it, loop gain in the
    band (Si small) does not. ``value`` is then that robust peak.
    """
    if maps.GzSi0 is None:
        raise InputError("min_band_peak: expected maps built with Gz, got none")
    loops = _loops(maps, loops)
    lo, hi = (float(b) for b in band_hz)
    n_band = int(((maps.f >= lo) & (maps.f <= hi)).sum())
    if n_band < 2:
        raise InputError(f"band_hz: expected >= 2 grid lines in {band_hz}, got {n_band}")
    if elsewhere is not None and not elsewhere >= 1.0:
        raise InputError(f"elsewhere: expected a factor >= 1 (K0 itself meets 1), got {elsewhere}")
    if rms_factor is not None and not (np.isfinite(rms_factor) and rms_factor >= 1.0):
        raise InputError(
            f"rms_factor: expected a finite factor >= 1 (K0 itself meets 1), got {rms_factor}"
        )
    if rms_psd is not None and not callable(rms_psd):
        raise InputError(f"rms_psd: expected a callable psd(f) -> (n_f,), got {rms_psd!r}")
    if not (np.isfinite(scan_factor) and scan_factor >= 1.0):
        raise InputError(
            f"scan_factor: expected a finite factor >= 1 (K0 itself meets 1), got {scan_factor}"
        )
    sc = None
    if scan is not None:
        r, ff = (np.asarray(x, float) for x in scan)
        nu = maps.H.shape[2]
        if r.ndim != 1 or r.size < 2 or ff.shape != (r.size, nu):
            raise InputError(f"scan: expected (r (N,), ff (N, {nu})), got {r.shape} and {ff.shape}")
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(ff))):
            raise InputError("scan: expected finite records, got non-finite values")
        sc = (r, ff, float(scan_factor))
    if z_error is not None and not callable(z_error):
        if not (np.isfinite(z_error) and z_error >= 0):
            raise InputError(
                f"z_error: expected a relative bound >= 0 or a callable, got {z_error}"
            )
    rms = None if rms_factor is None else (float(rms_factor), rms_psd)
    warm: dict = {}  # carried across the refinement's grids: lines, design, tightened cone
    return _refined(lambda m: _min_band_peak(m, lo, hi, ms_max, loops, z, elsewhere, z_error,
                                             rms, warm, sc),
                    maps, loops, ms_max, refine)  # fmt: skip


def rms_weights(f, fs: float, psd=None) -> np.ndarray:
    """(n_f,) w_k with sum_k w_k ||T(f_k)||^2 ~ the variance of T's output under the force.

    w_k = the width (Hz) of line k's cell (midpoints between lines; the first cell from
    0, the last to fs/2) x the force's one-sided PSD at f_k (``psd(f) -> (n_f,)``,
    N^2/Hz; default a discrete white force of unit variance per sample, 2 / fs: then
    sqrt(sum) is the rms per unit force std). ``f`` (n_f,) increasing, Hz.
    """
    f = np.asarray(f, float)
    edges = np.concatenate([[0.0], 0.5 * (f[1:] + f[:-1]), [max(fs / 2, f[-1])]])
    p = np.full(f.size, 2.0 / fs) if psd is None else np.asarray(psd(f), float)
    if p.shape != f.shape or not np.all(np.isfinite(p) & (p >= 0)):
        raise InputError(f"rms_psd: expected finite values >= 0 of shape {f.shape}, got {p.shape}")
    return np.diff(edges) * p


def z_rms(maps: YoulaMaps, theta, z: int = 0, psd=None) -> float:
    """sqrt(sum_k w_k ||T_dz[z, :](f_k)||^2) on the maps' grid (:func:`rms_weights`): the
    broadband rms of z under independent forces of PSD ``psd`` at every plant input."""
    T = maps.z_response(np.asarray(theta, float))[:, z, :]
    w = rms_weights(maps.f, maps.fs, psd)
    return float(np.sqrt(np.sum(w * np.sum(np.abs(T) ** 2, axis=1))))


def z_rms_exact(G, Gz, controller, z: int = 0) -> float:
    """The rms of z = Gz (u + d) (row ``z``) under a discrete white force d of unit variance
    per sample at every input of G, the loop u = -K y closed by ``controller``: the H2 norm
    of Gz (I + K G)^-1 from the discrete Lyapunov equation (no grid).

    G, Gz discrete control.StateSpace on the SAME states (equal A, B: rows of one plant, as
    :func:`workbench.cli.inferential_stages.design_youla_band` builds them); separate
    copies would carry the rigid-body poles at z = 1 as modes the loop cannot reach.
    """
    import scipy.linalg

    from workbench.sim import closed_loop_matrices

    if not _shared_states(G, Gz):
        raise InputError("Gz: expected the states of G (equal A and B), got another realization")
    K = _as_controller(controller).statespace()
    A, B, U, W = closed_loop_matrices((G.A, G.B, G.C, G.D), (K.A, K.B, K.C, K.D))
    ny, nu = G.noutputs, G.ninputs
    Cz, Dz = np.asarray(Gz.C, float)[z : z + 1], np.asarray(Gz.D, float)[z : z + 1]
    Ux, Uw = U[:nu], W[:nu]  # u = Ux x + Uw [r; d; v]
    C = np.hstack([Cz, np.zeros((1, A.shape[0] - Cz.shape[1]))]) + Dz @ Ux
    D = Dz @ Uw[:, ny : ny + nu]
    B = B[:, ny : ny + nu]
    if A.size and np.max(np.abs(np.linalg.eigvals(A))) >= 1.0:
        raise InputError("z_rms_exact: expected a stable loop, got an unstable one")
    P = (
        scipy.linalg.solve_discrete_lyapunov(A, B @ B.T, method="bilinear")
        if A.size
        else np.zeros((0, 0))
    )
    return float(np.sqrt(np.trace(C @ P @ C.T + D @ D.T)))


def _shared_states(G, Gz) -> bool:
    """Whether Gz is output rows of G's state space (equal A, B)."""
    return (
        Gz is not None
        and np.shape(Gz.A) == np.shape(G.A)
        and np.shape(Gz.B) == np.shape(G.B)
        and np.array_equal(np.asarray(Gz.A), np.asarray(G.A))
        and np.array_equal(np.asarray(Gz.B), np.asarray(G.B))
    )


def relative_error(error: ModelError, G):
    """eps(f) = (||Delta(f)||_F + ||spread(f)||) / ||G(f)||_F: the model's relative error on the
    measured loop, as a callable for ``min_band_peak(z_error=...)``.

    The stand-in for the error at an unmeasured point z: the same model predicts
    z and the measured outputs, so z is taken as known as well, relatively, as
    the measured loop is (Delta and its spread from :func:`model_error`; G the
    discrete design plant). An assumption, not a measurement: a model that is
    right at the sensors and wrong at z (a node of a mode at a sensor) escapes it.
    """
    from workbench.core.lti import frf

    def eps(f):
        f = np.asarray(f, float)
        d, sp = error.at(f)
        g = np.linalg.norm(frf(G, f), axis=(1, 2))
        return (np.linalg.norm(d, axis=(1, 2)) + np.linalg.norm(sp, axis=1)) / np.where(
            g > 0, g, np.inf
        )

    return eps


def _row_norm_soc(c0, C, theta, rhs):
    """SOC ||c0[l] + C[l] theta||_2 <= rhs[l] per line l; c0 (n, n_u), C (n, n_u, n_theta)."""
    import cvxpy as cp

    n, nu = c0.shape
    re = np.real(C).reshape(n * nu, -1) @ theta + np.real(c0).ravel()
    im = np.imag(C).reshape(n * nu, -1) @ theta + np.imag(c0).ravel()
    X = cp.vstack([cp.reshape(re, (n, nu), order="C").T, cp.reshape(im, (n, nu), order="C").T])
    return cp.SOC(rhs, X, axis=0)


#: re-centerings of the measured-loop rows' inner bound after the first design
_RECENTER_ROUNDS = 2

#: the largest ||Delta K S|| (+ spread) the band-peak design allows on the measured loop: the
#: small-gain margin (stable for < 1) and the factor 1 / (1 - mu) = 2 of the bound on |S_true|
_COUPLING_MAX = 0.5


class _MeasuredDiagonal:
    """Robust |S_ii| rows of :func:`min_band_peak` on the measured plant G + Delta, per loop
    i and line:

        |S_ii| + kappa (alpha a^2 + m^2 / alpha) / 2 <= b,   m <= mu,   kappa = 1 / (1 - mu),
        a >= ||S[i, :]||,   m >= ||M||_F + sum_a spread_a ||(K S)[a, :]||,   M = Delta K S.

    S_true = S (I + M)^-1 = S - S M (I + M)^-1, so for ||M|| <= m <= mu < 1 (stable:
    small gain, as :class:`_MeasuredLoop`) |S_true[i, i]| <= |S_ii| + a m / (1 - m) <=
    |S_ii| + kappa a m, and a m <= (alpha a^2 + m^2 / alpha) / 2 for any alpha > 0: a
    convex inner bound, tight where alpha = m / a (:meth:`recenter` puts it at a design).
    Where S's off-diagonal terms are large and M small (the beam's suspension modes:
    ||S0[i, :]|| 5.1 with |S0_ii| <= 1) this holds far more than ||S[i, :]|| / b + ||M||
    <= 1 of :class:`_MeasuredLoop`, which no Q meets there at b = 2.
    """

    def __init__(self, maps: YoulaMaps, loops, on: np.ndarray, mu: float = _COUPLING_MAX):
        self.base = _MeasuredLoop(maps, loops, on)
        self.diag = [maps.sensitivity_affine(i) for i in loops]
        self.on, self.mu, self.kappa = on, float(mu), 1.0 / (1.0 - float(mu))
        self.alpha = np.ones((len(loops), len(on)))
        self.recenter(np.zeros(maps.theta_size))

    def _norms(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(a (n_loops, n_f), m (n_f,)) at ``theta``, zero off ``self.on``."""
        b = self.base
        idx = np.flatnonzero(self.on)
        m = np.zeros(len(self.on))
        m[idx] = b.coupling(theta, idx)
        a = np.zeros((len(self.diag), len(self.on)))
        for j, (r0, R) in enumerate(b.rows):
            a[j, idx] = np.linalg.norm(r0[idx] + R[idx] @ theta, axis=1)
        return a, m

    def recenter(self, theta) -> None:
        """alpha = m / a at ``theta``: the inner bound touches the exact one there."""
        a, m = self._norms(theta)
        self.alpha = np.clip(np.where(a > 0, m / np.where(a > 0, a, 1.0), 1.0), 1e-6, 1e6)

    def extend(self, theta) -> bool:
        """Hold the rows also where the design at ``theta`` (not K0) makes the model error
        matter (:data:`_ERROR_NEGLIGIBLE`), centered there; whether lines joined.

        The lines were chosen on K0's ||Delta K0 S0||; a design whose gain differs from
        K0's by orders (the beam's band design: 6e-4 -> 1e-2 at 8-60 Hz) moves the measured
        |S| there while its nominal rows still hold (2.19 on the true beam at 16.8 Hz), and
        the refinement's extra lines, nominal too, would not stop it.
        """
        off = np.flatnonzero(~self.on)
        if not off.size:
            return False
        new = off[self.base.coupling(theta, off) >= _ERROR_NEGLIGIBLE]
        if not new.size:
            return False
        self.on[new] = True  # the same array as self.base.on
        a, m = self._norms(theta)
        self.alpha[:, new] = np.clip(m[new] / np.where(a[:, new] > 0, a[:, new], 1.0), 1e-6, 1e6)
        return True

    def figure(self, theta, ms_max: float) -> np.ndarray:
        """(n_f,) the largest ratio of a row to its bound (<= 1 holds), 0 off ``self.on``."""
        a, m = self._norms(theta)
        g = m / self.mu
        for j, (c0, C) in enumerate(self.diag):
            am = 0.5 * self.kappa * (self.alpha[j] * a[j] ** 2 + m**2 / self.alpha[j])
            g = np.maximum(g, (np.abs(c0 + C @ theta) + am) / ms_max)
        return np.where(self.on, g, 0.0)

    def constraints(self, theta, ms_max: float, scale, lines) -> list:
        """The rows on ``lines`` (indices into the grid) that are in ``self.on``."""
        import cvxpy as cp

        b = self.base
        idx = lines[self.on[lines]]
        if not idx.size:
            return []
        r, cons = b.coupling_rows(theta, scale, idx)
        cons.append(r <= self.mu)
        for j, ((c0, C), (r0, R)) in enumerate(zip(self.diag, b.rows)):
            a = cp.Variable(idx.size)
            cons.append(_row_norm_soc(r0[idx], R[idx] / scale, theta, a))
            x = _soc_abs(c0[idx], C[idx] / scale, theta)
            d = cp.Variable(idx.size)
            cons.append(cp.SOC(d, x, axis=0))
            al = self.alpha[j, idx]
            am = cp.multiply(al, cp.square(a)) + cp.multiply(1 / al, cp.square(r))
            cons.append(d + 0.5 * self.kappa * am <= ms_max)
        return cons


def _input_sensitivity_affine(maps: YoulaMaps) -> tuple[np.ndarray, np.ndarray]:
    """(c0 (n_f, n_u n_u), C (n_f, n_u n_u, n_theta)): Si = Si0 - Si0 Q H, flattened."""
    n_f = len(maps.f)
    C = maps._coef(maps.Si0, maps.H)
    return maps.Si0.reshape(n_f, -1), -C.reshape(n_f, -1, C.shape[-1])


def _z_error_lines(z_error, maps: YoulaMaps, z: int, sel: np.ndarray) -> np.ndarray | None:
    """(n_band,) eps ||Gz[z, :]|| on the band's lines, or None without ``z_error``."""
    if z_error is None:
        return None
    from workbench.core.lti import frf

    f = maps.f[sel]
    eps = np.asarray(z_error(f) if callable(z_error) else np.full(f.size, z_error), float)
    if eps.shape != f.shape or not np.all(np.isfinite(eps) & (eps >= 0)):
        raise InputError(f"z_error: expected finite bounds >= 0 of shape {f.shape}, got {eps}")
    return eps * np.linalg.norm(frf(maps.Gz, f)[:, z, :], axis=1)


def scan_error_affine(maps: YoulaMaps, r, ff, z: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(e0 (n_f, 1), E (n_f, 1, n_theta)): z's error in a scan, e_z = r - z, on the grid,
    as the DTFT e_z(f) = e0 + E theta.

    The loop tracks r (N,) (m) at every measured output, with the feedforward force
    ff (N, n_u) at the plant input: z = Gz Si (K 1 r + ff) = Gz (K S) 1 r + Gz Si ff,
    K S = K0 S0 + Si0 Q S0 and Gz Si = Gz Si0 - Gz Si0 Q H, both affine in Q. The records
    are held at their last values after the end (the scan's final position and holding
    force: the error then settles instead of seeing a step back to 0), so
    R(f) = sum_n (r_n - r_end) e^{-j w n} + r_end / (1 - e^{-j w}), the same for ff; the
    loop's integral action cancels the pole at DC. sum_k w_k |e_z(f_k)|^2 (the white
    weights of :func:`rms_weights`) is then the error's energy sum_n e_n^2 (per sample),
    the settling after the record included.
    """
    from workbench.core.lti import frf

    r, ff = np.asarray(r, float), np.asarray(ff, float)
    f = maps.f
    wz = np.exp(-2j * np.pi * f / maps.fs)

    def dtft(x):  # (n_f, ...) in blocks of lines: N can be 1e5 samples
        n = np.arange(x.shape[0])
        out = []
        for i in range(0, f.size, 64):
            out.append(np.exp(-2j * np.pi * np.outer(f[i : i + 64], n) / maps.fs) @ x)
        return np.concatenate(out)

    R = dtft(r - r[-1]) + r[-1] / (1 - wz)
    FF = dtft(ff - ff[-1]) + ff[-1][None, :] / (1 - wz)[:, None]
    one = np.ones(maps.S0.shape[1])
    Gzf = frf(maps.Gz, f)[:, z, :]
    L = maps.GzSi0[:, z : z + 1]
    zr0 = np.einsum("fu,fuy,y->f", Gzf, maps.KS0, one)  # Gz K0 S0 1
    C1 = maps._coef(L, (maps.S0 @ one)[:, :, None])[:, 0, 0]  # Gz Si0 Q S0 1
    zf0 = np.einsum("fu,fu->f", maps.GzSi0[:, z], FF)  # Gz Si0 ff
    C2 = maps._coef(L, maps.H @ FF[:, :, None])[:, 0, 0]  # Gz Si0 Q H ff
    e0 = R - R * zr0 - zf0
    E = -R[:, None] * C1 + C2
    return e0[:, None], E[:, None, :]


def _rms_cone(maps: YoulaMaps, c0, C, psd, what: str = "rms_factor"):
    """(R (m, n_theta), r (m,), ref): ||R theta + r|| = z_rms(theta) / z_rms(K0) for the
    scaled parameters (C already divided by the column scale), m <= n_theta + 1.

    The stacked affine map [Re; Im] of sqrt(w_k) T_dz[z, :](f_k) has 2 n_f n_u rows
    (2400 on the beam); its QR keeps the same norm in n_theta + 1 rows (the last the
    part of K0's response no theta reaches), one small cone whatever the grid.
    """
    w = np.sqrt(rms_weights(maps.f, maps.fs, psd))
    A = w[:, None, None] * C
    b = w[:, None] * c0
    A = np.concatenate([np.real(A).reshape(-1, A.shape[-1]), np.imag(A).reshape(-1, A.shape[-1])])
    b = np.concatenate([np.real(b).ravel(), np.imag(b).ravel()])
    ref = float(np.linalg.norm(b))
    if ref == 0:
        raise InputError(f"{what}: expected K0 with a nonzero response at z, got zero")
    Qm, R = np.linalg.qr(A / ref)
    qb = Qm.T @ (b / ref)
    rest = np.linalg.norm(b / ref - Qm @ qb)
    return np.vstack([R, np.zeros((1, R.shape[1]))]), np.r_[qb, rest], ref


#: when the realized design's exact rms (:func:`z_rms_exact`) exceeds rho x K0's, the cone
#: is tightened by the excess and this margin (the next design lands below rho, not at it),
#: at most ``_RMS_TIGHTEN`` times
_RMS_MARGIN, _RMS_TIGHTEN = 1e-4, 4


def _min_band_peak(
    maps, lo, hi, ms_max, loops, z, elsewhere, z_error, rms=None, warm=None, scan=None
):
    """One design: the band rows on every band line, the |S_ii| (and, on the measured loop,
    :class:`_MeasuredDiagonal`) rows generated over the other lines as in :func:`_max_bandwidth`;
    the relaxation's optimum is the full program's once no line violates. ``rms`` = (rho,
    psd) adds the rms cone (:func:`_rms_cone`) on every line. ``warm`` (a dict, updated)
    carries the last grid's active lines, design and tightened cone to the next grid of
    the refinement: each program costs 5-20 s on the beam, a cold start a dozen of them."""
    import cvxpy as cp

    f = maps.f
    sel = (f >= lo) & (f <= hi)
    c0, C = maps.z_affine(z)
    aff = [maps.sensitivity_affine(i) for i in loops]
    cscale = _column_scale([Ci for _, Ci in aff] + [C])
    C = C / cscale
    scale = float(np.max(np.abs(c0[sel]))) or 1.0  # solver numerics: O(1) figures
    w = _z_error_lines(z_error, maps, z, sel)
    si = None if w is None else _input_sensitivity_affine(maps)
    measured = None
    if maps.delta is not None and (on := _robust_lines(maps)).any():
        measured = _MeasuredDiagonal(maps, loops, on)
    out = ~sel
    rhs_else = np.linalg.norm(c0[out], axis=1)  # K0's ||T_dz||, each row scaled to 1
    rhs_else = np.where(rhs_else > 0, rhs_else, 1.0)

    def figure(th) -> np.ndarray:
        """(n_f,) the largest constraint ratio per line (<= 1 holds)."""
        g = np.zeros(len(f))
        for c0i, Ci in aff:
            g = np.maximum(g, np.abs(c0i + Ci @ th) / ms_max)
        if measured is not None:
            g = np.maximum(g, measured.figure(th, ms_max))
        if elsewhere is not None:
            tz = np.linalg.norm(c0[out] + C[out] @ (th * cscale), axis=1)
            g[out] = np.maximum(g[out], tz / (rhs_else * elsewhere))
        g[sel] = 0.0  # the band's lines are always in the program
        return g

    cone = rho = None
    if rms is not None:
        rho, psd = rms
        cone = _rms_cone(maps, c0, C, psd)
        exact0 = None  # the exact check: white force and Gz on G's states only
        if psd is None and _shared_states(maps.G, maps.Gz):
            exact0 = z_rms_exact(maps.G, maps.Gz, maps.K0, z)
    scone = None
    if scan is not None:  # the scan's error at z: a second cone, on the grid's figure
        e0, E = scan_error_affine(maps, scan[0], scan[1], z)
        scone = _rms_cone(maps, e0, E / cscale, None, what="scan")
    warm = {} if warm is None else warm
    rho_eff, tightened = warm.get("rho_eff", rho), 0
    active = sel.copy()
    active[::6] = True
    active[-1] = True
    if "f_active" in warm:  # the refined grid holds the last grid's lines exactly
        active |= np.isin(f, warm["f_active"])
    if measured is not None and "theta" in warm:
        measured.extend(warm["theta"])
        measured.recenter(warm["theta"])
    programs, rounds, last = 0, 0, None
    while True:  # each round adds lines, recenters or tightens (bounded), so this ends
        lines = np.flatnonzero(active)
        theta, t = cp.Variable(maps.theta_size), cp.Variable()
        cons = [cp.SOC(np.full(lines.size, float(ms_max)),
                       _soc_abs(c0i[lines], Ci[lines] / cscale, theta), axis=0)
                for c0i, Ci in aff]  # fmt: skip
        nb = int(sel.sum())
        if w is None:
            cons.append(_row_norm_soc(c0[sel] / scale, C[sel] / scale, theta, cp.hstack([t] * nb)))
        else:
            v = cp.Variable(nb)
            s0, S = si
            cons += [_row_norm_soc(c0[sel] / scale, C[sel] / scale, theta, v),
                     _row_norm_soc(s0[sel] * (w / scale)[:, None],
                                   S[sel] * (w / scale)[:, None, None] / cscale, theta,
                                   t - v)]  # fmt: skip
        if measured is not None:
            cons += measured.constraints(theta, ms_max, cscale, lines)
        if elsewhere is not None:
            lo_ = np.flatnonzero(out[lines])
            o = lines[lo_]
            r = np.linalg.norm(c0[o], axis=1)
            r = np.where(r > 0, r, 1.0)
            cons.append(_row_norm_soc(c0[o] / r[:, None], C[o] / r[:, None, None], theta,
                                      np.full(o.size, float(elsewhere))))  # fmt: skip
        if cone is not None:
            cons.append(cp.SOC(cp.Constant(float(rho_eff)), cone[0] @ theta + cone[1]))
        if scone is not None:
            cons.append(cp.SOC(cp.Constant(scan[2]), scone[0] @ theta + scone[1]))
        st = _solve(cp.Problem(cp.Minimize(t), cons))
        programs += 1
        if theta.value is None:
            where = " on the measured loop" if measured is not None else ""
            raise InputError(
                f"min_band_peak: the program is {st} (no Q meets |S| <= {ms_max}{where})"
            )
        th = np.array(theta.value) / cscale
        if measured is not None:
            measured.extend(th)
        if _grow(active, figure(th), 1.0, most=96):
            continue
        if not (
            measured is None
            or rounds == _RECENTER_ROUNDS
            or (last is not None and float(t.value) > last * (1 - 1e-3))
        ):
            # the inner bound touches the exact one at th: the next program holds th (its t
            # cannot rise) and can move further along the exact constraint
            measured.recenter(th)
            rounds, last = rounds + 1, float(t.value)
            continue
        if cone is not None and exact0 is not None and tightened < _RMS_TIGHTEN:
            # the grid's quadrature against the exact figure of the realized loop: a peak
            # of the design between two lines is missed by the sum, not by the Lyapunov form
            ratio = z_rms_exact(maps.G, maps.Gz, youla_controller(maps, th), z) / exact0
            if ratio > rho:
                rho_eff, tightened = rho_eff * rho * (1 - _RMS_MARGIN) / ratio, tightened + 1
                continue
        break
    peak = np.linalg.norm(maps.z_response(th)[sel][:, z, :], axis=1)
    if w is not None:
        s0, S = si
        peak = peak + w * np.linalg.norm(s0[sel] + S[sel] @ th, axis=1)
    warm.update(f_active=f[active], theta=th, rho_eff=rho_eff)
    figures = None
    if rms is not None:
        figures = (z_rms(maps, th, z, rms[1]), z_rms(maps, np.zeros_like(th), z, rms[1]))
    scan_figures = None
    if scan is not None:
        n = scan[0].size
        e = np.abs(e0[:, 0] + E[:, 0] @ th) ** 2
        wq = rms_weights(f, maps.fs)
        scan_figures = (float(np.sqrt(np.sum(wq * e) / n)),
                        float(np.sqrt(np.sum(wq * np.abs(e0[:, 0]) ** 2) / n)))  # fmt: skip
    return th, float(np.max(peak)), programs, st, figures, scan_figures


def min_mixed_sensitivity(maps: YoulaMaps, W1f: np.ndarray, W3f: np.ndarray) -> YoulaDesign:
    """min over Q of max_f sqrt(|W1 S|^2 + |W3 T|^2) for a SISO loop (T = 1 - S).

    The H-inf mixed-sensitivity problem restricted to the basis and the grid:
    ``value`` approaches the H-inf optimum gamma from above as the basis grows
    (the cross-check of :func:`controllers.hinf.hinf_riccati` in the tests).
    W1f, W3f : (n_f,) complex weight responses on ``maps.f``.
    """
    import cvxpy as cp

    if maps.S0.shape[1:] != (1, 1):
        raise InputError(f"min_mixed_sensitivity: expected a SISO loop, got {maps.S0.shape[1:]}")
    c0, C = maps.sensitivity_affine(0)
    theta = cp.Variable(C.shape[1])
    t = cp.Variable()
    w1, w3 = np.asarray(W1f)[:, None], np.asarray(W3f)[:, None]
    X = cp.vstack([
        _soc_abs(w1[:, 0] * c0, w1 * C, theta),
        _soc_abs(w3[:, 0] * (1 - c0), -w3 * C, theta),
    ])  # fmt: skip
    prob = cp.Problem(cp.Minimize(t), [cp.SOC(cp.hstack([t] * len(maps.f)), X, axis=0)])
    t0 = time.perf_counter()
    st = _solve(prob)
    if theta.value is None:
        raise InputError(f"min_mixed_sensitivity: the program is {st}")
    th = np.array(theta.value)
    return YoulaDesign(youla_controller(maps, th), th, float(t.value), maps, 1,
                       time.perf_counter() - t0, st)  # fmt: skip


# ------------------------------------------------------------------ per-DOF design
@dataclass(frozen=True)
class YoulaTuneReport:
    """Per DOF: the template bandwidth fb (Hz, the convex figure), the crossover and
    max |S| of the channel loop on the design model, and the programs' cost;
    ``orders``: each loop controller's order (decentralized designs)."""

    template_hz: tuple[float, ...]
    crossover_hz: tuple[float, ...]
    s_peak: tuple[float, ...]
    solves: int
    seconds: float
    n_basis: int
    pole: float
    orders: tuple[int, ...] = ()


@dataclass(frozen=True)
class YoulaTuneDesign:
    controller: StateSpaceController
    report: YoulaTuneReport


def _measured_peaks(error: ModelError, blocks, modal, fs: float) -> np.ndarray:
    """(n_y,) max |S_ii| of the decentralized loop ``blocks`` (SISO e_i -> u_i) on the
    measured plant: the design grids and 2000 log lines."""
    from workbench.core.lti import frf

    f = np.unique(np.concatenate([_design_grid(modal, i, fs) for i in range(len(blocks))]))
    f = np.union1d(f, np.geomspace(f[0], f[-1], 2000))
    Kf = np.zeros((f.size, len(blocks), len(blocks)), complex)
    for i, b in enumerate(blocks):  # block by block: one resolvent of the whole K costs n^3
        Kf[:, i, i] = frf(b, f)[:, 0, 0]
    Gm = error.measured_at(f)
    S = np.linalg.inv(np.eye(Gm.shape[1]) + Gm @ Kf)
    return np.max(np.abs(np.einsum("fii->fi", S)), axis=0)


def closed_loop_error(error: ModelError, i: int, blocks, f) -> ModelError:
    """Channel i's error against what it sees on the measured plant with the other loops closed.

    With the decentralized loops ``blocks`` (SISO e_j -> u_j, discrete; block i is not
    used) closed on the measured plant G, loop i sees
    g_i = G_ii - G_ir K_r (I + G_rr K_r)^-1 G_ri (r: the other loops). Its error
    against the model's channel, g_i - G_model,ii, holds the interaction that
    :func:`interaction_bound` only bounds: a loop designed on it (with the others
    fixed) is the MIMO loop, |S_ii| = |1 / (1 + k_i g_i)| exactly (sequential loop
    closing; Skogestad & Postlethwaite 2005, sec. 10.6.5). ``f`` (Hz): the lines
    the error is evaluated on (linear interpolation between them, as for an FRF).
    The spread is the first-order bound |[1, Y]| spread |[1, X]^T| of the measured
    plant's elements through Y = G_ir K_r (I + G_rr K_r)^-1 and
    X = K_r (I + G_rr K_r)^-1 G_ri.
    """
    from workbench.core.lti import frf

    f = np.asarray(f, float)
    Gm = error.measured_at(f)
    n = Gm.shape[1]
    r = [j for j in range(n) if j != i]
    Kr = np.zeros((f.size, n - 1, n - 1), complex)
    for a, j in enumerate(r):
        Kr[:, a, a] = frf(blocks[j], f)[:, 0, 0]
    inv = np.linalg.inv(np.eye(n - 1) + Gm[:, r][:, :, r] @ Kr)
    Y = Gm[:, [i]][:, :, r] @ Kr @ inv  # (n_f, 1, n-1)
    X = Kr @ inv @ Gm[:, r][:, :, [i]]  # (n_f, n-1, 1)
    g = Gm[:, i, i] - (Y @ Gm[:, r][:, :, [i]])[:, 0, 0]
    G_model = error.exact[1] if error.exact is not None else error.model
    G_ii = G_model[i, i]
    delta = (g - frf(G_ii, f)[:, 0, 0])[:, None, None]
    spread = np.zeros(delta.shape)
    if error.exact is None and np.any(error.spread):
        order = [i] + r
        sp = error.on_lines(error.spread, f)[:, order][:, :, order]
        left = np.concatenate([np.ones((f.size, 1)), np.abs(Y[:, 0, :])], axis=1)
        right = np.concatenate([np.ones((f.size, 1)), np.abs(X[:, :, 0])], axis=1)
        spread[:, 0, 0] = np.einsum("fa,fab,fb->f", left, sp, right)
    return ModelError(f, delta, spread, model=G_ii)


def reduce_loop(block, g: np.ndarray, f: np.ndarray, ms_max: float, *, orders=None):
    """The lowest-order balanced truncation of a SISO loop controller that keeps |S| <= ms_max.

    ``block``: discrete SISO controller (control.StateSpace) e -> u; ``g`` (n_f,)
    the plant it sees (measured, the other loops closed: :func:`closed_loop_error`)
    on the lines ``f`` (Hz). Square-root balanced truncation of the stable part
    (SLICOT AB09MD, discrete; poles on or outside the unit circle, such as an
    integrator, are kept exactly). A truncation K_r is accepted when the small-gain
    certificate holds on the lines: a = |(K_r - K) g S| < 1, S = 1 / (1 + K g) the
    full design's sensitivity; then the loop with K_r is stable (K_r - K is
    stable) and |S_r| = |S| / |1 + (K_r - K) g S| <= |S| / (1 - a) <= ms_max.
    ``orders``: the orders tried, lowest first (default 2, 4, ... up to the
    block's). Returns (controller, order); the block itself when none passes.
    """
    import control
    import slycot

    from workbench.core.lti import frf

    n = block.nstates
    k = frf(block, f)[:, 0, 0]
    S = 1.0 / (1.0 + k * g)
    for r in range(2, n, 2) if orders is None else orders:
        if r >= n:
            break
        nr, Ar, Br, Cr, _, _ = slycot.ab09md("D", "B", "N", n, 1, 1, block.A, block.B, block.C,
                                             alpha=1.0, nr=int(r))  # fmt: skip
        Kr = control.ss(Ar[:nr, :nr], Br[:nr], Cr[:, :nr], block.D, block.dt)
        a = np.abs((frf(Kr, f)[:, 0, 0] - k) * g * S)
        if np.max(a) < 1 and np.max(np.abs(S) / (1 - a)) <= ms_max:
            return Kr, int(nr)
    return block, int(n)


def unmeasured_bound(t_bound, G, K0, f_top: float):
    """``t_bound`` and, above the measured band (f > ``f_top`` Hz), |T| <= |T0| of K0's loop.

    Where the FRF has no line the model's error is unknown (:class:`ModelError` only
    holds its last value there): a design may then be no more exposed to an additive
    error than the baseline, |K S| = |T / G| <= |K0 S0|, i.e. |T| <= |T0| on the model
    (SISO ``G``, ``K0`` a StateSpaceController). A stand-in, not a certificate: K0 was
    stable on the machine, and the design keeps at most K0's gain to the unknown.
    """
    from workbench.core.lti import frf

    def t(f):
        f = np.asarray(f, float)
        out = np.array(_t_lines(t_bound, f), float)
        hi = f > f_top * (1 + 1e-9)
        if hi.any():
            L0 = frf(G, f[hi])[:, 0, 0] * frf(K0.statespace(), f[hi])[:, 0, 0]
            out[hi] = np.minimum(out[hi], np.maximum(np.abs(L0 / (1 + L0)), 1e-12))
        return out

    return t


def _design_grid(modal, i: int, fs: float) -> np.ndarray:
    """Log grid fs/5000..fs/2 plus 80 lines within +-15 % of every mode the channel shows."""
    f = [np.geomspace(fs / 5000, fs / 2, 600)]
    for md in modal.modes:
        if md.kind == "flexible" and abs(md.b[i] * md.c[i]) > 0 and md.freq_hz < fs / 2:
            f.append(np.linspace(0.85 * md.freq_hz, min(1.15 * md.freq_hz, fs / 2), 80))
    return np.unique(np.concatenate(f))


def tune_youla(
    model,
    *,
    ms_max: float = 2.0,
    loop_delay_samples: int = 0,
    fs: float | None = None,
    K0=None,
    structure: str | None = None,
    n_basis: int = 40,
    pole: float = 0.75,
    margin: float = 0.97,
    t_bound: tuple[float, float] | None = None,
    measured=None,
    k_std: float = 3.0,
    sequential_rounds: int = 2,
    reduce: bool = True,
    progress=None,
) -> YoulaTuneDesign:
    """Youla design per DOF for the widest crossover template at |S_ii| <= margin * ms_max.

    First every diagonal channel u_i -> y_i of the modal model
    (:func:`controllers.hinf.channel_plant`: its modes, its delay and the loop's)
    gets :func:`max_bandwidth` with the double-integrator template (slope 2,
    level 1) around its loop of :func:`controllers.pid_notch.tune_pid_notch`:
    the decoupled optimum fb_i of each DOF. Then

    * ``structure="decentralized"`` (default with ``measured``): those SISO
      designs, block-diagonal; with ``measured``, each |T_ii| is first bounded
      by :func:`interaction_bound` of the measured plant, which keeps the MIMO
      loop stable, and then (``sequential_rounds`` > 0) every loop is
      re-designed on what it sees of the measured plant with the others closed
      (:func:`closed_loop_error`, sequential loop closing), without that bound:
      the interaction is then in each loop's error, not bounded for the worst
      case; the loops whose |S_ii| on the measured plant still exceed ms_max
      are re-designed again, up to ``sequential_rounds`` passes; with
      ``reduce``, each loop's controller is then cut to the lowest order whose
      measured loop keeps the bound (:func:`reduce_loop`);
    * ``structure="coupled"`` (default without ``measured``): one program on the MIMO loop
      around ``K0`` (default the pid-notch design; e.g. a modal-sf design),
      a diagonal Q, every |S_ii| of the coupled loop bounded, the templates at
      alpha * fb_i with alpha bisected in [0.3, 1]: the loops' interaction
      through the plant's flexible modes is in the program, not left to a check.

    ``margin`` keeps the design below the bound on the model, for what the
    model lacks. The result's report has per DOF the template fb actually
    imposed, and the crossover and |S_ii| of the MIMO loop on the model.

    ``measured``: the plant as measured, an FRF (spec 1b, from the plant input
    u, so without the loop's ``loop_delay_samples``, which are put in here) or
    a discrete control.StateSpace of the true plant u_c -> y with every delay
    (a study). Every program then holds its bounds on the MEASURED loop
    (:func:`model_error`: the model's error against it, ``k_std`` standard
    deviations of the FRF as its spread): robust to what the model lacks and
    the measurement shows, such as the modes above Nyquist. Without it the
    design is only as good as the model: on the wafer stage the coupled design
    on the nominal model is stable with |S_ii| <= 1.91 on the true stage without
    its modes above Nyquist and UNSTABLE with them (z loop |S| 7.9).
    """
    import control

    from controllers.hinf import channel_plant
    from controllers.modal_sf import _as_modal
    from controllers.pid_notch import tune_pid_notch
    from workbench.core.lti import frf
    from workbench.core.model import as_model
    from workbench.loop import discrete_plant, screen_loops

    if structure is None:  # the coupled program on the measured loop is slow (minutes a step)
        structure = "coupled" if measured is None else "decentralized"
    if structure not in ("coupled", "decentralized"):
        raise InputError(f"structure: expected 'coupled' or 'decentralized', got {structure!r}")
    modal = _as_modal(model)
    plant = as_model(modal.to_lti())
    if plant.n_u != plant.n_y:
        raise InputError(f"model: expected a square model, got {plant.n_u} x {plant.n_y}")
    if fs is None:
        raise InputError("fs: expected the controller rate in Hz, got None")
    fs = float(fs)
    m = int(loop_delay_samples)
    pid, _ = tune_pid_notch(plant, fs, ms_max=ms_max, loop_delay_samples=m)
    G = discrete_plant(plant, fs, m)
    error = None
    if measured is not None:
        error = model_error(measured, G, k_std=k_std,
                            loop_delay_samples=0 if isinstance(measured, control.StateSpace)
                            else m)  # fmt: skip
    t_channel = t_bound
    if error is not None and t_bound is None and structure == "decentralized" and plant.n_u > 1:
        t_channel = interaction_bound(error)  # the MIMO loop's stability, from the measurement
    n_steps = len(pid.channels) + (structure == "coupled" and plant.n_u > 1)
    say = progress or (lambda _i, _n: None)
    solves, t0 = 0, time.perf_counter()
    n_loops = len(pid.channels)

    # an FRF that stops short of Nyquist says nothing of the plant above its last line
    # (where a stage's folded modes above Nyquist sit): there the loops are held to the
    # baseline's exposure (unmeasured_bound)
    f_top = None
    if error is not None and error.exact is None and error.freq[-1] < 0.99 * fs / 2:
        f_top = float(error.freq[-1])
        warnings.warn(f"measured: the FRF ends at {f_top:g} Hz, below Nyquist ({fs / 2:g} Hz); "
                      "above it the loops keep |T_ii| <= the baseline's", DataWarning,
                      stacklevel=2)  # fmt: skip

    def channel(i, err=None, t=t_channel):
        nonlocal solves
        if err is None and error is not None:
            err = error.channel(i)
        A, B, C, D = pid.channels[i].discrete_ss(fs)
        Gi, k0 = channel_plant(modal, i, fs, m), StateSpaceController(A, B, C, D, fs)
        if f_top is not None:
            t = unmeasured_bound(t, Gi, k0, f_top)
        d = max_bandwidth(
            youla_maps(Gi, k0, _design_grid(modal, i, fs), n_basis=n_basis, pole=pole, error=err),
            ms_max=margin * ms_max, slope=2.0, level=1.0, t_bound=t,
        )  # fmt: skip
        solves += d.solves
        return d.controller.statespace(), d.value

    # the measured loop's lines: every channel's design grid and a dense log grid
    f_all = np.unique(np.concatenate([_design_grid(modal, i, fs) for i in range(n_loops)]))
    f_meas = np.union1d(f_all, np.geomspace(f_all[0], f_all[-1], 4000))
    blocks, fb = [], []
    for i in range(len(pid.channels)):
        b, v = channel(i)
        blocks.append(b)
        fb.append(v)
        say(i + 1, n_steps)
    if t_channel is not None and error is not None and t_bound is None:
        # the interaction bound keeps the MIMO loop stable (and every subset of its loops,
        # so each loop can be opened) but it is conservative where the plant couples, and
        # the loops' |S_ii| on the measured plant are not the channels'. Sequential loop
        # closing: each loop re-designed on what it sees with the others closed, the
        # interaction in its error (exact for that loop, the others fixed), until every
        # |S_ii| on the measured plant holds ms_max
        todo = list(range(n_loops))
        for _ in range(sequential_rounds):
            for i in todo:
                blocks[i], fb[i] = channel(i, closed_loop_error(error, i, blocks, f_meas), None)
            peak = _measured_peaks(error, blocks, modal, fs)
            todo = [int(i) for i in np.flatnonzero(peak > ms_max)]
            if not todo:
                break
    if reduce and error is not None and structure == "decentralized":
        # each loop's controller cut to the lowest order the measured loop allows, in turn
        # (the others closed, already cut): a design's order is n(K0) + n(G_ii) + n(K0) + n_basis
        # (the certificate of each holds for the loops as they are when it is cut: the
        # final check on the measured plant keeps the full designs if a cut moved another)
        cut = list(blocks)
        for i in range(n_loops):
            ce = closed_loop_error(error, i, cut, f_meas)
            g = frf(ce.model, f_meas)[:, 0, 0] + ce.delta[:, 0, 0]
            cut[i], _ = reduce_loop(cut[i], g, f_meas, ms_max)
        if np.all(_measured_peaks(error, cut, modal, fs) <= ms_max):
            blocks = cut
    if structure == "decentralized" or plant.n_u == 1:
        K = control.append(*blocks)
        ctrl = StateSpaceController(K.A, K.B, K.C, K.D, fs, pid.input_names, pid.output_names, m)
    else:
        maps = youla_maps(G, pid if K0 is None else K0, f_all, n_basis=n_basis, pole=pole,
                          diagonal=True, error=error)  # fmt: skip
        top = max(fb)
        d = max_bandwidth(maps, ms_max=margin * ms_max, slope=2.0, level=1.0, t_bound=t_bound,
                          ratios=np.array(fb) / top, fb_range=(0.3 * top, top))  # fmt: skip
        solves += d.solves
        fb = [d.value * x / top for x in fb]
        ctrl = d.controller
        say(n_steps, n_steps)
    _, peak, cross = screen_loops(plant, ctrl)
    orders = tuple(int(b.nstates) for b in blocks) if structure == "decentralized" else ()
    rep = YoulaTuneReport(tuple(fb), tuple(float(x) for x in cross),
                          tuple(float(x) for x in peak), solves, time.perf_counter() - t0,
                          int(n_basis), float(pole), orders)  # fmt: skip
    return YoulaTuneDesign(ctrl, rep)

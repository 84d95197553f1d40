"""Modal analysis by similarity: a state-space model to the modal canonical form.

Data flow::

    control.StateSpace (discrete, from identify)  --d2c-->  continuous (A, B, C, D)
        --> rigid-body cluster (|s| < 2 pi f_rigid): invariant subspace, projected
            onto double integrators, one per DOF
        --> every other pole pair: a real 2x2 block [[0, 1], [-w^2, -2 z w]]
            with B rows [0; b_k] and C columns [c_k, 0]; real poles: 1x1 blocks
        --> ModalModel (frozen)  .to_statespace()  .table_text()  .to_json()

Per mode k the transfer function is ``c_k b_k^T / (s^2 + 2 z_k w_k s + w_k^2)``
(rigid: ``c_k b_k^T / s^2``; real pole ``p``: ``c_k b_k^T / (s - p)``).
The split of the scale between ``b_k`` and ``c_k`` is not identifiable from
input-output data; we take ``|b_k| = |c_k|`` (rigid modes per output DOF: see
:meth:`ModalModel.from_statespace`).

The one modal model of the workbench. ``from_statespace(..., exact=True)`` is
lossless (each mode keeps its exact numerator ``N1 s + N0``); the model also
holds the delay and the diagnosis's lags and coupling. Conversions:
``to_statespace`` / ``to_lti`` (with the delay) and ``from_statespace`` (a
``StateSpace`` or :class:`workbench.core.model.LTIModel`, continuous or discrete);
``plants.modal.ModalSet.to_modal`` (the plants' modes). The diagnosis works on
this type too: :meth:`ModalModel.with_rigid_merged` (the rigid modes as the one
``s^2`` term it fits), :meth:`Mode.moved` (a mode moved, a rigid body
suspended), :attr:`Mode.effect` (which effect added a mode), :meth:`core_frf`,
:meth:`channel_factor`, :meth:`simulate` (exact ZOH, :mod:`workbench.modal.simulate`).
Refinement packs and unpacks the parameters through :mod:`workbench.modal.params`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import scipy.linalg

from workbench.core.arrays import readonly
from workbench.core.errors import InputError
from workbench.core.lti import as_matrices

__all__ = [
    "Mode",
    "ModalModel",
    "apply_outer",
    "lag_factor",
    "split_rigid_gain",
    "wrap_outer",
    "plot_model_bode",
    "plot_mode_superposition",
]

Kind = Literal["rigid", "flexible", "real"]


@dataclass(frozen=True)
class Mode:
    """One mode of a :class:`ModalModel`.

    Attributes
    ----------
    kind : {"rigid", "flexible", "real"}
        Rigid body (double integrator), flexible (complex pole pair) or a real
        pole (first order: overdamped, or a lag).
    freq_hz : float
        Natural frequency ``w / 2 pi``, Hz (rigid: 0; real pole ``p``: ``|p| / 2 pi``).
    damping : float
        Damping ratio (rigid: 0; real pole: +1 stable, -1 unstable).
    b : (n_u,) array
        Modal input vector (modal force per input unit).
    c : (n_y,) array
        Modal output vector (output per unit modal displacement).
    residual : float
        Relative size of what the idealized form drops from the identified
        mode (velocity-proportional numerator, rank > 1 residue), at the
        mode's frequency; 0 for an exact modal system.
    N0, N1 : (n_y, n_u) arrays or None
        The mode's exact numerator ``N1 s + N0`` over its denominator, kept by
        ``ModalModel.from_statespace(..., exact=True)`` (and by the diagnosis's
        fitted terms); None: the ideal ``N0 = c b^T``, ``N1 = 0``. Rigid modes
        share the denominator ``s^2``: only their sum is defined, so the
        cluster's ``1/s`` coefficient (single integrators) sits on the first.
    effect : str
        The diagnosis effect that added this mode or made it (``"missing_mode"``,
        ``"suspension_stiffness"``: a rigid body on a spring); "" for a mode of
        the model as given (a ``"modal_mismatch"`` moves a mode and keeps it "").
    """

    kind: str
    freq_hz: float
    damping: float
    b: np.ndarray
    c: np.ndarray
    residual: float = 0.0
    N0: np.ndarray | None = None
    N1: np.ndarray | None = None
    effect: str = ""

    def __post_init__(self):
        if self.kind not in ("rigid", "flexible", "real"):
            raise InputError(
                f"mode kind: expected 'rigid', 'flexible' or 'real', got {self.kind!r}"
            )
        b = readonly(self.b, float)
        c = readonly(self.c, float)
        if b.ndim != 1 or c.ndim != 1:
            raise InputError(
                f"mode: expected b (n_u,) and c (n_y,), got shapes {b.shape}, {c.shape}"
            )
        if not (np.isfinite(self.freq_hz) and self.freq_hz >= 0 and np.isfinite(self.damping)):
            raise InputError(f"mode: expected a finite frequency >= 0 Hz, got {self.freq_hz}")
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        for key in ("N0", "N1"):
            v = getattr(self, key)
            if v is None:
                continue
            v = readonly(v, float)
            if v.shape != (c.size, b.size):
                raise InputError(
                    f"mode: expected {key} of shape ({c.size}, {b.size}) to match c and b, "
                    f"got {v.shape}"
                )
            object.__setattr__(self, key, v)
        if self.kind == "real" and self.N1 is not None and np.any(self.N1):
            raise InputError("mode: a real pole has no s-numerator: expected N1 = 0 or None")
        object.__setattr__(self, "freq_hz", float(self.freq_hz))
        object.__setattr__(self, "damping", float(self.damping))
        object.__setattr__(self, "residual", float(self.residual))

    @property
    def omega(self) -> float:
        """Natural frequency, rad/s."""
        return 2 * np.pi * self.freq_hz

    @property
    def n_states(self) -> int:
        return 1 if self.kind == "real" else 2

    @property
    def is_ideal(self) -> bool:
        """True when the numerator is ``c b^T`` (no exact N0, N1 kept)."""
        return self.N0 is None and self.N1 is None

    def moved(self, freq_hz: float, damping: float, *, effect: str | None = None) -> Mode:
        """This mode at another natural frequency (Hz) and damping ratio, numerator kept.

        A rigid mode becomes a flexible one: its numerator over
        ``s^2 + 2 z w s + w^2`` (a rigid body on a spring). ``effect``: see
        :attr:`effect` (None keeps this mode's).
        """
        if self.kind == "real":
            raise InputError("mode: a real pole has no (frequency, damping) pair to move")
        return replace(
            self,
            kind="flexible",
            freq_hz=freq_hz,
            damping=damping,
            effect=self.effect if effect is None else effect,
        )

    def numerator(self) -> tuple[np.ndarray, np.ndarray]:
        """(N0, N1), (n_y, n_u) each: the numerator ``N1 s + N0`` of this mode."""
        N0 = np.outer(self.c, self.b) if self.N0 is None else self.N0
        N1 = np.zeros((self.c.size, self.b.size)) if self.N1 is None else self.N1
        return N0, N1

    def denominator(self) -> np.ndarray:
        """``(a1, a0)`` of ``s^2 + a1 s + a0`` (rigid: (0, 0)), or ``(a0,)`` of ``s + a0``."""
        w, z = self.omega, self.damping
        if self.kind == "rigid":
            return np.zeros(2)
        if self.kind == "real":
            return np.array([-self.pole.real])
        return np.array([2 * z * w, w * w])

    @property
    def pole(self) -> complex:
        """The pole (upper half plane for a pair), rad/s."""
        w, z = self.omega, self.damping
        if self.kind == "rigid":
            return 0j
        if self.kind == "real":
            return complex(-z * w)
        return complex(-z * w, w * np.sqrt(max(0.0, 1 - z * z)))

    def den(self, s: np.ndarray) -> np.ndarray:
        """The denominator at complex frequencies ``s`` (n_f,): ``s^2``, ``s - p`` or
        ``s^2 + 2 z w s + w^2``."""
        s = np.asarray(s, complex)
        w, z = self.omega, self.damping
        if self.kind == "rigid":
            return s**2
        if self.kind == "real":
            return s - self.pole.real
        return s**2 + 2 * z * w * s + w**2

    def response(self, s: np.ndarray) -> np.ndarray:
        """This mode's contribution ``c b^T / den(s)``, (n_f, n_y, n_u) complex."""
        return self.numerator_times(s, 1.0 / self.den(s))  # one division per line

    def numerator_times(self, s: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """``(N0 + s N1) phi(s)``, (n_f, n_y, n_u) complex, for per-line factors ``phi`` (n_f,).

        :meth:`response` with ``phi = 1/den``; a derivative of the response with respect to
        the denominator's parameters with ``phi = -d den / den^2``. Computed as
        ``p N0 + q N1`` (``p = phi``, ``q = s phi``) in one real product (n_f, 4) @
        (4, 2 n_y n_u) whose columns are (Re, Im) interleaved: the complex array is written
        once (the broadcast form wrote three; the diagnosis calls this thousands of times).
        """
        return numerators_times((self,), s, np.asarray(phi, complex)[:, None])


@dataclass(frozen=True)
class ModalModel:
    """A continuous-time model in modal coordinates (seed 000, eq. 7).

    Attributes
    ----------
    modes : tuple of Mode
        Rigid modes first, then flexible modes by frequency, then real poles.
    D : (n_y, n_u) array
        Feedthrough.
    transform : (n, n) array or None
        Similarity back to the realization it came from: ``x_source = T x_modal``
        for the ``"companion"`` form of :meth:`to_statespace`. Exact for the
        state matrix of the flexible and real modes; for the rigid cluster the
        least-squares map of the observability matrices.
    rigid_poles : (n_rigid_states,) complex array
        The poles the rigid cluster had before projection (near 0), rad/s.
    input_names, output_names : tuple of str
    delay_s : float
        Input delay on every input, s (exact, ``exp(-s delay_s)``); the
        :class:`workbench.core.model.LTIModel` delay, carried through conversions.
    tau_in : (n_u,) array or None, tau_out : (n_y,) array or None
        Actuator and sensor first-order lag time constants ``1 / (1 + s tau)``,
        s (0 or None: no lag); the extended terms of the diagnosis.
    T_in : (n_u, n_u) array or None, T_out : (n_y, n_y) array or None
        Static coupling (crosstalk) at the inputs and outputs (None: identity).

    The whole response is ``T_out Hy(s) [D + sum_k modes] Hu(s) T_in exp(-s delay_s)``
    (residual compliance is part of ``D``, a suspension turns the rigid modes
    into low flexible ones); a model from :meth:`from_statespace` has no lags
    or coupling.
    """

    modes: tuple[Mode, ...]
    D: np.ndarray
    transform: np.ndarray | None = None
    rigid_poles: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    delay_s: float = 0.0
    tau_in: np.ndarray | None = None
    tau_out: np.ndarray | None = None
    T_in: np.ndarray | None = None
    T_out: np.ndarray | None = None

    def __post_init__(self):
        D = readonly(self.D, float)
        if D.ndim != 2:
            raise InputError(f"modal model: expected D of shape (n_y, n_u), got {D.shape}")
        modes = tuple(self.modes)
        for k, m in enumerate(modes):
            if not isinstance(m, Mode):
                raise InputError(f"modal model: mode {k}: expected a Mode, got {type(m).__name__}")
            if m.b.shape != (D.shape[1],) or m.c.shape != (D.shape[0],):
                raise InputError(
                    f"modal model: mode {k}: expected b ({D.shape[1]},) and c ({D.shape[0]},) "
                    f"to match D {D.shape}, got {m.b.shape} and {m.c.shape}"
                )
        object.__setattr__(self, "modes", modes)
        object.__setattr__(self, "D", D)
        if self.transform is not None:
            object.__setattr__(self, "transform", readonly(self.transform, float))
        object.__setattr__(self, "rigid_poles", readonly(self.rigid_poles, complex))
        if not (np.isfinite(self.delay_s) and self.delay_s >= 0):
            raise InputError(f"modal model: expected delay_s >= 0 s, got {self.delay_s}")
        object.__setattr__(self, "delay_s", float(self.delay_s))
        n_u, n_y = D.shape[1], D.shape[0]
        for key, shape in (
            ("tau_in", (n_u,)),
            ("tau_out", (n_y,)),
            ("T_in", (n_u, n_u)),
            ("T_out", (n_y, n_y)),
        ):
            v = getattr(self, key)
            if v is None:
                continue
            v = readonly(v, float)
            if v.shape != shape or not np.all(np.isfinite(v)):
                raise InputError(
                    f"modal model: expected finite {key} of shape {shape}, got {v.shape}"
                )
            if key.startswith("tau") and np.any(v < 0):
                raise InputError(f"modal model: expected {key} >= 0 s, got {v.tolist()}")
            object.__setattr__(self, key, v)
        object.__setattr__(
            self, "input_names", tuple(self.input_names) or tuple(f"u{i}" for i in range(n_u))
        )
        object.__setattr__(
            self, "output_names", tuple(self.output_names) or tuple(f"y{i}" for i in range(n_y))
        )

    # ------------------------------------------------------------ properties
    @property
    def n_u(self) -> int:
        return self.D.shape[1]

    @property
    def n_y(self) -> int:
        return self.D.shape[0]

    @property
    def n_states(self) -> int:
        return sum(_mode_blocks(m)[0].shape[0] for m in self.modes)

    @property
    def is_ideal(self) -> bool:
        """True when every mode's numerator is ``c_k b_k^T`` (see :attr:`Mode.N0`)."""
        return all(m.is_ideal for m in self.modes)

    @property
    def freq_hz(self) -> np.ndarray:
        """(n_modes,) natural frequencies, Hz."""
        return np.array([m.freq_hz for m in self.modes])

    @property
    def damping(self) -> np.ndarray:
        """(n_modes,) damping ratios."""
        return np.array([m.damping for m in self.modes])

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(m.kind for m in self.modes)

    def modes_of_kind(self, kind: str) -> tuple[Mode, ...]:
        return tuple(m for m in self.modes if m.kind == kind)

    def rigid_residue(self) -> tuple[np.ndarray, np.ndarray]:
        """(N0, N1), (n_y, n_u) each: the rigid modes' summed numerator over their shared s^2.

        Only the sum is defined by the response (``N0 = sum_k c_k b_k^T``, full
        rank with one rigid mode per DOF; ``N1`` the 1/s part of an exact
        decomposition); diagnosis and refinement take the rigid body as this one term.
        """
        N0 = np.zeros((self.n_y, self.n_u))
        N1 = np.zeros((self.n_y, self.n_u))
        for m in self.modes_of_kind("rigid"):
            n0, n1 = m.numerator()
            N0, N1 = N0 + n0, N1 + n1
        return N0, N1

    # -------------------------------------------------------------- to / from
    def to_statespace(self, *, form: Literal["companion", "scaled"] = "companion"):
        """The modal realization as a continuous ``control.StateSpace``.

        Parameters
        ----------
        form : {"companion", "scaled"}
            ``"companion"``: blocks ``[[0, 1], [-w^2, -2 z w]]``, states
            (modal displacement q, velocity dq/dt), B rows ``[0; b_k]``, C
            columns ``[c_k, 0]``. ``"scaled"``: blocks ``[[0, w], [-w, -2 z w]]``,
            states (w q, dq/dt), C columns ``[c_k / w, 0]``: the layout of the
            shared example files (``nominal_model.npz``), better balanced.
            Rigid blocks are ``[[0, 1], [0, 0]]`` in both; real poles ``[[p]]``.
            A mode with an exact numerator (:attr:`Mode.N0`) gets the minimal
            realization of its residue: ``rank`` blocks of the same form with
            two B rows (rigid: ``[[0, I], [0, 0]]`` blocks of the rank of
            ``[N0; N1]``). The delay is not part of a ``StateSpace``:
            :meth:`to_lti` keeps it.
        """
        import control

        if form not in ("companion", "scaled"):
            raise InputError(f"form: expected 'companion' or 'scaled', got {form!r}")
        blocks = [_mode_blocks(m, form) for m in self.modes]
        n = sum(a.shape[0] for a, _, _ in blocks)
        A = scipy.linalg.block_diag(*[a for a, _, _ in blocks]) if n else np.zeros((0, 0))
        B = np.vstack([b for _, b, _ in blocks]) if n else np.zeros((0, self.n_u))
        C = np.hstack([c for _, _, c in blocks]) if n else np.zeros((self.n_y, 0))
        A, B, C, D = wrap_outer(A, B, C, self.D, self.tau_in, self.tau_out, self.T_in, self.T_out)
        return control.ss(
            A, B, C, D, 0, inputs=list(self.input_names), outputs=list(self.output_names)
        )

    @property
    def has_outer(self) -> bool:
        """True when the model has lags or coupling (the diagnosis's extended terms)."""
        return bool(np.any(self.tau_in) or np.any(self.tau_out) or self.T_in is not None) or (
            self.T_out is not None
        )

    def core_frf(self, freq_hz, modes=None, *, with_d: bool = True) -> np.ndarray:
        """``D + sum_k`` of ``modes`` (default: all) at ``freq_hz`` (Hz): (n_f, n_y, n_u).

        Without lags, coupling or delay (see :meth:`frf`).
        """
        s = 2j * np.pi * np.atleast_1d(np.asarray(freq_hz, float))
        modes = self.modes if modes is None else tuple(modes)
        if modes:
            G = numerators_times(modes, s, 1.0 / np.stack([m.den(s) for m in modes], -1))
        else:
            G = np.zeros((s.size, self.n_y, self.n_u), complex)
        if with_d:
            G += self.D[None]
        return G

    def channel_factor(self, freq_hz) -> np.ndarray:
        """Per-channel outer factor ``Hy_i Hu_j exp(-s delay_s)``, (n_f, n_y, n_u); no coupling."""
        s = 2j * np.pi * np.atleast_1d(np.asarray(freq_hz, float))
        h = lag_factor(s, self.lags("out"))[:, :, None] * lag_factor(s, self.lags("in"))[:, None, :]
        return h * np.exp(-s * self.delay_s)[:, None, None]

    def lags(self, side: Literal["in", "out"]) -> np.ndarray:
        """Lag time constants of the inputs (n_u,) or outputs (n_y,), s; zeros where none."""
        tau = self.tau_in if side == "in" else self.tau_out
        n = self.n_u if side == "in" else self.n_y
        return np.zeros(n) if tau is None else np.asarray(tau)

    def with_rigid_merged(self) -> ModalModel:
        """The rigid modes as one rigid mode holding their summed numerator; the rest by frequency.

        The rigid modes share ``s^2``, so the response defines only their sum
        (:meth:`rigid_residue`, full rank with one rigid mode per DOF): the
        diagnosis fits and edits that one term (a suspension moves its
        denominator, :meth:`Mode.moved`). The merged mode keeps the exact
        numerator; its ``b``, ``c`` are the rank-one part of ``N0``. The other
        modes follow by frequency (flexible and real poles together, a stable
        sort), the order in which the diagnosis indexes them. Same FRF.
        """
        rigid = self.modes_of_kind("rigid")
        rest = sorted((m for m in self.modes if m.kind != "rigid"), key=lambda m: m.freq_hz)
        if not rigid:
            return replace(self, modes=tuple(rest))
        N0, N1 = self.rigid_residue()
        C, B = split_rigid_gain(N0, 1, "svd")
        merged = Mode("rigid", 0.0, 0.0, B[0], C[:, 0], N0=N0, N1=N1)
        return replace(self, modes=(merged, *rest), transform=None)

    def simulate(self, u, fs: float) -> np.ndarray:
        """Zero-order-hold response from rest to ``u`` (N, n_u) sampled at ``fs`` (Hz): (N, n_y).

        Exact for every part, the delay included (:mod:`workbench.modal.simulate`).
        """
        from workbench.modal.simulate import simulate

        return simulate(self, u, fs)

    def frf(self, freq_hz, *, with_delay: bool = True) -> np.ndarray:
        """Frequency response (n_f, n_y, n_u): modes plus D, through lags, coupling and delay."""
        f = np.atleast_1d(np.asarray(freq_hz, float))
        return self.outer(f, self.core_frf(f), with_delay=with_delay)

    def outer(self, freq_hz, G: np.ndarray, *, with_delay: bool = True) -> np.ndarray:
        """The lags, coupling and delay applied to a core response ``G`` (n_f, n_y, n_u)."""
        return apply_outer(
            freq_hz,
            G,
            tau_in=self.tau_in,
            tau_out=self.tau_out,
            T_in=self.T_in,
            T_out=self.T_out,
            delay_s=self.delay_s if with_delay else 0.0,
        )

    def to_lti(self, *, form: Literal["companion", "scaled"] = "companion"):
        """The modal realization with its delay, as an LTIModel (dt = 0)."""
        from workbench.core.model import LTIModel

        return LTIModel.from_statespace(self.to_statespace(form=form), delay_s=self.delay_s)

    @classmethod
    def from_statespace(
        cls,
        sys,
        *,
        rigid_threshold_hz: float = 5.0,
        rigid_basis: Literal["auto", "outputs", "svd"] = "auto",
        exact: bool = False,
    ) -> ModalModel:
        """Modal analysis by similarity of a continuous or discrete model.

        The one modal decomposition of the workbench: identification,
        refinement, minimality and (with ``exact=True``) diagnosis start here.

        Parameters
        ----------
        sys : control.StateSpace or workbench.core.model.LTIModel
            ``A`` (n, n), ``B`` (n, n_u), ``C`` (n_y, n), ``D`` (n_y, n_u);
            a discrete model is first converted with :func:`workbench.core.d2c.d2c`.
            An LTIModel's delay and names are kept.
        rigid_threshold_hz : float
            Poles with ``|s| < 2 pi rigid_threshold_hz`` form the rigid-body
            cluster, Hz. They come in pairs (one double integrator per DOF);
            identification returns them as small complex or real pairs, possibly
            slightly unstable.
        rigid_basis : {"auto", "outputs", "svd"}
            How the rigid-body static gain ``P = sum_k c_k b_k^T`` is split
            into modes: ``"outputs"``, one mode per output DOF (``c_k`` along
            output k; needs as many rigid modes as outputs); ``"svd"``,
            orthogonal ``c_k`` and ``b_k`` from the SVD of ``P``; ``"auto"``,
            outputs when possible.
        exact : bool
            False (default): the idealized modal form (rank-one ``c_k b_k^T``,
            no velocity numerator, the cluster below ``rigid_threshold_hz``
            projected onto double integrators). True: lossless, the FRF of
            the result equals the model's: the rigid cluster is the poles at
            zero only (``|s| < 1e-6 max(|s|_max, 1)`` rad/s, the threshold is
            not used), near-rigid poles stay flexible or real modes at their
            own frequency, each mode keeps its exact numerator
            (:attr:`Mode.N0`, :attr:`Mode.N1`), ``transform`` is None.
            Integrators of order above two or a defective (non-diagonalizable)
            flexible part are refused (InputError).

        Returns
        -------
        ModalModel

        Notes
        -----
        Rigid cluster: an ordered real Schur form puts the small poles first;
        a Sylvester equation decouples them from the rest (block
        diagonalization). Of the cluster's transfer function
        ``C1 (sI - A1)^-1 B1 = C1 B1 / s + C1 A1 B1 / s^2 + ...`` the double
        integrator keeps ``P = C1 A1 B1``; its residual is
        ``|C1 B1| w_r / |P|`` at ``w_r = 2 pi rigid_threshold_hz``.

        Flexible pair ``s, conj(s)`` with right/left eigenvectors ``v, w``: the
        residue ``R = (C v)(w^H B)`` gives ``M = 2 j Im(s) R = N0 - z w N1 +
        j Im(s) N1`` for the numerator ``N1 s + N0``. The modal form keeps the
        rank-one part of ``N0`` (SVD, ``|b| = |c|``) and drops ``N1`` (a
        velocity-proportional term that a force-to-position mode does not
        have); ``residual = |N0 - c b^T + j w N1| / |N0|``. The similarity
        ``T = [a v, conj(a v)] E^-1`` with ``E = [[1, 1], [s, conj(s)]]`` and
        ``a`` the least-squares scale with ``a C v ~ c`` maps the block to
        companion form exactly (W. Gawronski, Advanced Structural Dynamics
        and Active Control of Structures, Springer 2004, ch. 2).
        """
        from workbench.core.d2c import d2c

        A, B, C, D, dt = as_matrices(sys)
        if dt > 0:
            A, B, C, D, _ = as_matrices(d2c(sys))
        delay_s = float(getattr(sys, "delay_s", 0.0))
        in_names = tuple(getattr(sys, "input_names", None) or sys.input_labels)
        out_names = tuple(getattr(sys, "output_names", None) or sys.output_labels)
        if rigid_threshold_hz < 0 or not np.isfinite(rigid_threshold_hz):
            raise InputError(
                f"rigid_threshold_hz: expected a finite value >= 0 Hz, got {rigid_threshold_hz}"
            )
        if rigid_basis not in ("auto", "outputs", "svd"):
            raise InputError(
                f"rigid_basis: expected 'auto', 'outputs' or 'svd', got {rigid_basis!r}"
            )
        n = A.shape[0]
        w_r = 2 * np.pi * rigid_threshold_hz
        lam_all = np.linalg.eigvals(A) if n else np.zeros(0)
        if exact:
            # poles at zero only (the tolerance of a computed double pole at z = 1 after d2c)
            w_r = 1e-6 * max(float(np.max(np.abs(lam_all), initial=0.0)), 1.0)
        n_cluster = int(np.sum(np.abs(lam_all) < w_r))
        # order the real Schur form: the small poles first
        T_s, A_s = np.eye(n), A.copy()
        if n_cluster:
            A_s, T_s, sdim = scipy.linalg.schur(
                A, output="real", sort=lambda x, y: np.hypot(x, y) < w_r
            )
            n_cluster = sdim
        n_rigid = n_cluster // 2
        blocks_T = []  # (columns of the source realization, Mode)
        modes: list[Mode] = []
        # exact: the whole cluster (an odd one holds a single integrator)
        k1 = n_cluster if exact else 2 * n_rigid
        # decouple the leading k1 states (rigid pairs) from the rest
        X = np.zeros((k1, n - k1))
        if k1 and n - k1:
            X = scipy.linalg.solve_sylvester(A_s[:k1, :k1], -A_s[k1:, k1:], -A_s[:k1, k1:])
        S = np.eye(n)
        S[:k1, k1:] = X
        T_bd = T_s @ S  # x = T_bd xi, xi block-diagonal coordinates
        T_bd_inv = np.linalg.inv(S) @ T_s.T
        Ab = T_bd_inv @ A @ T_bd
        Bb = T_bd_inv @ B
        Cb = C @ T_bd
        rigid_poles = np.linalg.eigvals(Ab[:k1, :k1]) if k1 else np.zeros(0, complex)
        if k1:
            r_modes, T_r = _rigid_modes(
                Ab[:k1, :k1], Bb[:k1], Cb[:, :k1], w_r, rigid_basis, exact=exact
            )
            modes += r_modes
            blocks_T.append(T_bd[:, :k1] @ T_r)
        f_modes, T_f = _flexible_modes(Ab[k1:, k1:], Bb[k1:], Cb[:, k1:], exact=exact)
        modes += f_modes
        if n - k1:
            blocks_T.append(T_bd[:, k1:] @ T_f)
        T = np.hstack(blocks_T) if blocks_T else np.zeros((0, 0))
        return cls(
            modes=tuple(modes),
            D=D,
            transform=None if exact else T,
            rigid_poles=rigid_poles,
            input_names=in_names,
            output_names=out_names,
            delay_s=delay_s,
        )

    # ---------------------------------------------------------------- report
    def table(self) -> list[dict]:
        """One dict per mode: index, kind, freq_hz, damping, |b|, |c|, residual, b, c."""
        rows = []
        for k, m in enumerate(self.modes):
            rows.append(
                {
                    "mode": k + 1,
                    "kind": m.kind,
                    "freq_hz": m.freq_hz,
                    "damping": m.damping,
                    "b_norm": float(np.linalg.norm(m.b)),
                    "c_norm": float(np.linalg.norm(m.c)),
                    "residual": m.residual,
                    "b": [float(v) for v in m.b],
                    "c": [float(v) for v in m.c],
                }
            )
        return rows

    def table_text(self) -> str:
        """The mode table as text (seed 000, Table 1, with rigid modes and participations)."""
        lines = [
            " mode  kind        freq (Hz)    damping      |b_k|        |c_k|     residual",
        ]
        for row in self.table():
            lines.append(
                f"{row['mode']:5d}  {row['kind']:<9s} {row['freq_hz']:10.2f} "
                f"{row['damping']:10.4f} {row['b_norm']:12.4e} {row['c_norm']:12.4e} "
                f"{row['residual']:10.2e}"
            )
        n_r = len(self.modes_of_kind("rigid"))
        if self.rigid_poles.size:
            lines.append(
                f"rigid-body cluster: {n_r} double integrators from poles with |s| up to "
                f"{np.max(np.abs(self.rigid_poles)) / (2 * np.pi):.3g} Hz"
            )
        return "\n".join(lines)

    def to_json(self) -> str:
        """The mode table and D as JSON text."""
        return json.dumps(
            {
                "modes": self.table(),
                "D": self.D.tolist(),
                "input_names": list(self.input_names),
                "output_names": list(self.output_names),
            },
            indent=2,
        )


def numerators_times(modes, s: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``sum_k (N0_k + s N1_k) phi_k(s)``, (n_f, n_y, n_u) complex; ``phi`` (n_f, n_modes).

    ``p N0 + q N1`` (``p = phi``, ``q = s phi``) for every mode in one real product
    (n_f, 4 n_modes) @ (4 n_modes, 2 n_y n_u) whose columns are (Re, Im) interleaved:
    the complex result is written once (a sum of broadcast products wrote three arrays
    a mode; the diagnosis evaluates such sums thousands of times).
    """
    s = np.asarray(s, complex)
    nums = [m.numerator() for m in modes]
    shape = nums[0][0].shape
    k = nums[0][0].size
    B = np.zeros((len(modes), 4, k, 2))
    for i, (N0, N1) in enumerate(nums):
        B[i, 0, :, 0] = B[i, 1, :, 1] = N0.ravel()
        B[i, 2, :, 0] = B[i, 3, :, 1] = N1.ravel()
    q = s[:, None] * phi
    coef = np.stack([phi.real, phi.imag, q.real, q.imag], -1)  # (n_f, n_modes, 4)
    out = coef.reshape(s.size, -1) @ B.reshape(-1, 2 * k)
    return out.view(complex).reshape(s.size, *shape)


# ------------------------------------------------- lags, coupling, delay (outer)
def lag_factor(s: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``1 / (1 + s tau_j)``, (n_f, n_ch), at complex frequencies ``s`` (rad/s); tau (n_ch,), s."""
    return 1.0 / (1.0 + s[:, None] * tau[None, :])


def left_product(T: np.ndarray, G: np.ndarray) -> np.ndarray:
    """``T @ G[f]`` for every line f of ``G`` (n_f, n_y, n_u). A real ``T`` on a complex
    ``G`` is one real product on G's (re, im) view: the complex product casts ``T``, and
    einsum's generic loop was 7x slower still (6x6 on 2000 lines: 3.2 ms; the coupled
    model's predictions in a joint fit spent most of their time there)."""
    if np.isrealobj(T) and np.iscomplexobj(G):
        G = np.ascontiguousarray(G, dtype=complex)
        return (T @ G.view(float)).view(complex)
    return T @ G


def apply_outer(freq_hz, G, *, tau_in=None, tau_out=None, T_in=None, T_out=None, delay_s=0.0):
    """``T_out Hy G Hu T_in exp(-s delay_s)`` for a core response ``G`` (n_f, n_y, n_u).

    ``Hu = diag(1/(1 + s tau_in))``, ``Hy = diag(1/(1 + s tau_out))`` (tau in s, None or
    0: no lag); ``T_in``, ``T_out`` static coupling (None: identity); ``delay_s`` in s.
    """
    s = 2j * np.pi * np.asarray(freq_hz, float)
    if tau_out is not None and np.any(tau_out):
        G = G * lag_factor(s, tau_out)[:, :, None]
    if tau_in is not None and np.any(tau_in):
        G = G * lag_factor(s, tau_in)[:, None, :]
    if T_out is not None:
        G = left_product(np.asarray(T_out), G)
    if T_in is not None:
        G = G @ T_in
    if delay_s:
        G = G * np.exp(-s * delay_s)[:, None, None]
    return G


def _lag_abcd(tau: np.ndarray):
    """(A, B, C, D) of diag(1/(1 + s tau_i)) (tau_i = 0: a direct channel)."""
    n = tau.size
    lagged = np.flatnonzero(tau > 0)
    A = np.diag(-1.0 / tau[lagged])
    B = np.zeros((lagged.size, n))
    B[np.arange(lagged.size), lagged] = 1.0 / tau[lagged]
    C = np.zeros((n, lagged.size))
    C[lagged, np.arange(lagged.size)] = 1.0
    D = np.eye(n)
    D[lagged, lagged] = 0.0
    return A, B, C, D


def _series(first, second):
    """(A, B, C, D) of ``second`` driven by ``first``'s output; states (first's, second's)."""
    A1, B1, C1, D1 = first
    A2, B2, C2, D2 = second
    A = np.block([[A1, np.zeros((A1.shape[0], A2.shape[0]))], [B2 @ C1, A2]])
    return A, np.vstack([B1, B2 @ D1]), np.hstack([D2 @ C1, C2]), D2 @ D1


def wrap_outer(A, B, C, D, tau_in=None, tau_out=None, T_in=None, T_out=None):
    """(A, B, C, D) of ``T_out Hy (A, B, C, D) Hu T_in`` (see :func:`apply_outer`).

    States: actuator lags (lagged inputs only), the core, sensor lags.
    """
    if tau_in is not None and np.any(tau_in):
        A, B, C, D = _series(_lag_abcd(np.asarray(tau_in, float)), (A, B, C, D))
    if tau_out is not None and np.any(tau_out):
        A, B, C, D = _series((A, B, C, D), _lag_abcd(np.asarray(tau_out, float)))
    if T_in is not None:
        B, D = B @ T_in, D @ T_in
    if T_out is not None:
        C, D = T_out @ C, T_out @ D
    return A, B, C, D


def split_rigid_gain(
    P: np.ndarray, n_r: int, basis: Literal["auto", "outputs", "svd"] = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Rigid modes from their summed gain ``P = sum_k c_k b_k^T`` of ``1/s^2``.

    Parameters
    ----------
    P : (n_y, n_u) array
    n_r : int
        Number of rigid modes.
    basis : {"auto", "outputs", "svd"}
        ``"outputs"``: one mode per output DOF, ``c_k = d_k e_k``, ``d_k =
        sqrt(|P[k]|)`` (needs ``n_r = n_y``); ``"svd"``: orthogonal ``c_k``,
        ``b_k`` of equal norm from the SVD of ``P``, zero modes beyond its
        size; ``"auto"``: outputs when ``n_r = n_y`` and no row of ``P`` is
        below ``1e-9`` of the largest, else svd.

    Returns
    -------
    C : (n_y, n_r) array, columns ``c_k``; B : (n_r, n_u) array, rows ``b_k``.
    """
    n_y = P.shape[0]
    row_norm = np.linalg.norm(P, axis=1)
    if basis == "outputs" and n_r != n_y:
        raise InputError(
            f"rigid_basis 'outputs': expected as many rigid modes as outputs ({n_y}), "
            f"got {n_r}; use 'svd'"
        )
    use_outputs = basis == "outputs" or (
        basis == "auto" and n_r == n_y and np.all(row_norm > 1e-9 * max(row_norm.max(), 1e-300))
    )
    if use_outputs:
        d = np.sqrt(row_norm)
        return np.diag(d), P / np.where(d > 0, d, 1.0)[:, None]
    U, s, Vt = np.linalg.svd(P)
    k = min(n_r, s.size)
    C = U[:, :k] * np.sqrt(s[:k])
    B = np.sqrt(s[:k])[:, None] * Vt[:k]
    if k < n_r:  # fewer singular values than modes (n_y or n_u < n_r): zero modes
        B = np.vstack([B, np.zeros((n_r - k, B.shape[1]))])
        C = np.hstack([C, np.zeros((n_y, n_r - k))])
    return C, B


# ------------------------------------------------------------------ internals
def _rank_split(M: np.ndarray, scale: float | None = None, tol: float = 1e-12):
    """Full-rank factors ``M = L R`` (L (m, r), R (r, n)) by SVD; r counts s > tol scale.

    ``scale`` defaults to the largest singular value of ``M``.
    """
    U, sv, Vt = np.linalg.svd(M, full_matrices=False)
    ref = (sv[0] if sv.size else 0.0) if scale is None else scale
    r = int(np.sum(sv > tol * max(ref, 1e-300))) if sv.size else 0
    return U[:, :r] * sv[:r], Vt[:r]


def _mode_blocks(m: Mode, form: str = "companion"):
    """(A, B, C) of one mode: (k, k), (k, n_u), (n_y, k); see ModalModel.to_statespace."""
    n_u, n_y = m.b.size, m.c.size
    w, z = m.omega, m.damping
    if m.is_ideal:
        if m.kind == "real":
            return np.array([[m.pole.real]]), m.b[None, :], m.c[:, None]
        if m.kind == "rigid":
            A, c0 = np.array([[0.0, 1.0], [0.0, 0.0]]), m.c
        elif form == "companion":
            A, c0 = np.array([[0.0, 1.0], [-(w**2), -2 * z * w]]), m.c
        else:
            A, c0 = np.array([[0.0, w], [-w, -2 * z * w]]), m.c / w
        B = np.vstack([np.zeros(n_u), m.b])
        return A, B, np.column_stack([c0, np.zeros(n_y)])
    N0, N1 = m.numerator()
    if m.kind == "real":
        L, R = _rank_split(N0)
        return m.pole.real * np.eye(L.shape[1]), R, L
    if m.kind == "rigid":
        # (N1 s + N0) / s^2 = [N0 N1] [[I/s^2], [I/s]]: (position, velocity) states per rank
        # of [N0; N1]; or double chains for N0 and single integrators for N1 (fewer states
        # when N0 = 0, e.g. a lone integrator): the smaller of the two
        scale = max(np.linalg.norm(N0, 2), np.linalg.norm(N1, 2))
        L, R = _rank_split(np.vstack([N0, N1]), scale)
        L0, R0 = _rank_split(N0, scale)
        L1, R1 = _rank_split(N1, scale)
        r, r0, r1 = R.shape[0], R0.shape[0], R1.shape[0]
        if 2 * r0 + r1 < 2 * r:
            A = np.zeros((2 * r0 + r1, 2 * r0 + r1))
            A[:r0, r0 : 2 * r0] = np.eye(r0)
            B = np.vstack([np.zeros((r0, n_u)), R0, R1])
            return A, B, np.hstack([L0, np.zeros((n_y, r0)), L1])
        A = np.block([[np.zeros((r, r)), np.eye(r)], [np.zeros((r, 2 * r))]])
        return A, np.vstack([np.zeros((r, n_u)), R]), np.hstack([L[:n_y], L[n_y:]])
    # flexible: residue R = (N1 lam + N0) / (lam - conj lam) at the upper pole lam, each rank
    # component phi psi^T a real 2-state block in (Re z, Im z), then put into the companion
    # form by x_c = O x_r with O = [e1^T; e1^T A_r] (an observable pair for Im lam != 0)
    lam = m.pole
    if not lam.imag > 0:
        # overdamped (z >= 1, e.g. a stiff suspension fitted by the diagnosis): per rank of
        # [N0; N1] a block [[0, w], [-w, -2 z w]] on states (w q, dq/dt), C [L0 / w, L1]
        a1, a0 = m.denominator()
        L, R = _rank_split(np.vstack([N0, N1]))
        r, w = R.shape[0], np.sqrt(a0)
        s1 = w if form == "scaled" else 1.0
        I_r, Z = np.eye(r), np.zeros((r, r))
        A = np.block([[Z, s1 * I_r], [-a0 / s1 * I_r, -a1 * I_r]])
        return A, np.vstack([np.zeros((r, n_u)), R]), np.hstack([L[:n_y] / s1, L[n_y:]])
    Res = (N1 * lam + N0) / (2j * lam.imag)
    phi, psi = _rank_split(Res)
    As, Bs, Cs = [], [], []
    Ar = np.array([[lam.real, -lam.imag], [lam.imag, lam.real]])
    O = np.array([[1.0, 0.0], Ar[0]])
    Oi = np.linalg.inv(O)
    Ac = O @ Ar @ Oi
    S = np.diag([1.0, 1.0]) if form == "companion" else np.diag([w, 1.0])
    for k in range(phi.shape[1]):
        Br = np.vstack([psi[k].real, psi[k].imag])
        Cr = np.column_stack([2 * phi[:, k].real, -2 * phi[:, k].imag])
        As.append(S @ Ac @ np.linalg.inv(S))
        Bs.append(S @ O @ Br)
        Cs.append(Cr @ Oi @ np.linalg.inv(S))
    if not As:
        return np.zeros((0, 0)), np.zeros((0, n_u)), np.zeros((n_y, 0))
    return scipy.linalg.block_diag(*As), np.vstack(Bs), np.hstack(Cs)


def _rigid_modes(A1, B1, C1, w_r, basis, *, exact=False):
    """Double-integrator modes from the rigid cluster (A1, B1, C1); and the state map."""
    n_r = A1.shape[0] // 2
    n_y = C1.shape[0]
    P = C1 @ A1 @ B1  # the 1/s^2 coefficient
    N1 = C1 @ B1  # the 1/s coefficient, 0 for exact double integrators
    if exact:
        # C1 A1^2 B1 /s^3 and beyond must vanish: a modal model has no triple integrators
        R3 = C1 @ A1 @ A1 @ B1
        scale = max(np.max(np.abs(np.linalg.eigvals(A1))), 1.0)
        if np.linalg.norm(R3) > 1e-6 * max(np.linalg.norm(P), 1e-300) * scale and np.any(R3):
            raise InputError(
                "model: expected rigid-body modes (double integrators) at s = 0, got "
                "integrators of order above two: not a modal model"
            )
        n_r = max(n_r, 1)
        if basis == "auto" and n_r != n_y:
            basis = "svd"
    Cr, Br = split_rigid_gain(P, n_r, basis)
    resid = float(np.linalg.norm(N1) * w_r / max(np.linalg.norm(P), 1e-300))
    exact_num = [(None, None)] * n_r
    if exact:
        # the rigid modes share s^2: the part their c_k b_k^T miss (P beyond rank n_r,
        # rounding) and the cluster's 1/s coefficient go on the first, so that the sum is exact
        exact_num = [(np.outer(Cr[:, k], Br[k]), np.zeros_like(P)) for k in range(n_r)]
        exact_num[0] = (exact_num[0][0] + P - Cr @ Br, N1)
    modes = [
        Mode(
            kind="rigid",
            freq_hz=0.0,
            damping=0.0,
            b=Br[k],
            c=Cr[:, k],
            residual=resid,
            N0=exact_num[k][0],
            N1=exact_num[k][1],
        )
        for k in range(n_r)
    ]
    # state map x_cluster = T_r x_modal from the observability matrices (3 block rows)
    Am = np.zeros((2 * n_r, 2 * n_r))
    Cm = np.zeros((n_y, 2 * n_r))
    for k in range(n_r):
        Am[2 * k, 2 * k + 1] = 1.0
        Cm[:, 2 * k] = Cr[:, k]
    O_id = np.vstack([C1, C1 @ A1, C1 @ A1 @ A1])
    O_m = np.vstack([Cm, Cm @ Am, Cm @ Am @ Am])
    T_r = np.linalg.lstsq(O_id, O_m, rcond=None)[0]
    if exact:
        T_r = np.zeros((A1.shape[0], 0))  # no state map for the exact form
    return modes, T_r


def _flexible_modes(A2, B2, C2, *, exact=False):
    """Flexible (pair) and real-pole modes of a block without rigid poles; and the state map."""
    n = A2.shape[0]
    if n == 0:
        return [], np.zeros((0, 0))
    lam, V = np.linalg.eig(A2)
    if exact and not np.linalg.cond(V) < 1e10:
        raise InputError(
            "model: expected a diagonalizable realization apart from the rigid-body modes, "
            "got a defective (repeated, coupled) pole: not a modal model"
        )
    W = np.linalg.inv(V)  # rows: left eigenvectors, W V = I
    cols = []
    modes = []
    done = np.zeros(n, bool)
    order = np.argsort(np.abs(lam))
    for idx in order:
        if done[idx]:
            continue
        s = lam[idx]
        v, wl = V[:, idx], W[idx]
        phi, psi = C2 @ v, wl @ B2
        if abs(s.imag) <= 1e-9 * max(abs(s), 1e-300):  # real pole
            done[idx] = True
            v, phi, psi = v.real, phi.real, psi.real
            kappa = (
                np.sqrt(np.linalg.norm(psi) / max(np.linalg.norm(phi), 1e-300))
                if np.any(phi)
                else 1.0
            )
            c, b = phi * kappa, psi / kappa
            modes.append(
                Mode(
                    kind="real",
                    freq_hz=abs(s.real) / (2 * np.pi),
                    damping=1.0 if s.real < 0 else -1.0,
                    b=b,
                    c=c,
                )
            )
            cols.append(((0, abs(s.real)), (v * kappa)[:, None]))
            continue
        # the conjugate partner
        dist = np.abs(lam - np.conj(s))
        dist[done] = np.inf
        dist[idx] = np.inf
        partner = int(np.argmin(dist))
        done[idx] = done[partner] = True
        if s.imag < 0:
            s, v, phi, psi = np.conj(s), np.conj(v), np.conj(phi), np.conj(psi)
        wd = s.imag
        w0 = abs(s)
        zeta = -s.real / w0
        M = 2j * wd * np.outer(phi, psi)
        N1 = M.imag / wd
        N0 = M.real - s.real * N1
        U, sv, Vt = np.linalg.svd(N0)
        c = U[:, 0] * np.sqrt(sv[0])
        b = Vt[0] * np.sqrt(sv[0])
        j = int(np.argmax(np.abs(c)))
        if c[j] < 0:
            c, b = -c, -b
        resid = np.linalg.norm(N0 - np.outer(c, b) + 1j * w0 * N1) / max(np.linalg.norm(N0), 1e-300)
        modes.append(
            Mode(
                kind="flexible",
                freq_hz=w0 / (2 * np.pi),
                damping=zeta,
                b=b,
                c=c,
                residual=resid,
                N0=N0 if exact else None,
                N1=N1 if exact else None,
            )
        )
        a = np.vdot(phi, c) / max(np.vdot(phi, phi).real, 1e-300)
        E = np.array([[1.0, 1.0], [s, np.conj(s)]])
        Tk = np.column_stack([a * v, np.conj(a * v)]) @ np.linalg.inv(E)
        cols.append(((1, w0), Tk.real))
    # order: flexible by frequency, then real poles by |p|
    key = sorted(range(len(modes)), key=lambda i: (cols[i][0][0] == 0, cols[i][0][1]))
    modes = [modes[i] for i in key]
    T = np.hstack([cols[i][1] for i in key])
    return modes, T


# ---------------------------------------------------------------------- plots
def _freq_axis(model: ModalModel, freq_hz):
    if freq_hz is not None:
        return np.asarray(freq_hz, float)
    f = [m.freq_hz for m in model.modes if m.freq_hz > 0]
    hi = 3 * max(f) if f else 1e3
    return np.logspace(np.log10(hi / 1e4), np.log10(hi), 800)


def plot_model_bode(model: ModalModel, path, *, freq_hz=None, title: str = "") -> None:
    """Save the magnitude of every input-output pair of the modal model (PNG grid)."""
    from matplotlib.figure import Figure

    from workbench.core.atomic import atomic_path
    from workbench.plotting import frequency_grid, lean_axes

    f = _freq_axis(model, freq_hz)
    G = model.frf(f)
    fig = Figure(figsize=(2.2 * model.n_u + 1, 1.8 * model.n_y + 1))
    axes = frequency_grid(fig, model.n_y, model.n_u, f)
    for i in range(model.n_y):
        for j in range(model.n_u):
            ax = axes[i, j]
            ax.loglog(f, np.abs(G[:, i, j]), lw=0.8)
            ax.grid(True, alpha=0.2)
            lean_axes(ax)
            if i == 0:
                ax.set_title(model.input_names[j], fontsize=8)
            if j == 0:
                ax.set_ylabel(model.output_names[i], fontsize=8)
            ax.tick_params(labelsize=6)
    fig.suptitle(title or "Modal model: |G| per input-output pair")
    fig.supxlabel("frequency (Hz)")
    # fixed margins: tight_layout costs seconds on a 6 x 6 grid
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.07, top=0.93, hspace=0.35, wspace=0.35)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)


def plot_mode_superposition(
    model: ModalModel, path, *, output: int = 0, input: int = 0, freq_hz=None, title: str = ""
) -> None:
    """Save the Bode plot of one input-output pair as the superposition of its modes (PNG).

    Each mode's contribution ``c_k[output] b_k[input] / den_k(s)`` is drawn with
    the sum (seed 000, Figure 5: a DOF's response as the sum of one rigid and
    two flexible modes). Modes that contribute nothing to the pair are left out.
    """
    from matplotlib.figure import Figure

    from workbench.core.atomic import atomic_path

    if not (0 <= output < model.n_y and 0 <= input < model.n_u):
        raise InputError(
            f"output/input: expected 0 <= output < {model.n_y} and 0 <= input < {model.n_u}, "
            f"got {output}, {input}"
        )
    f = _freq_axis(model, freq_hz)
    s = 2j * np.pi * f
    total = model.frf(f, with_delay=False)[:, output, input]  # the sum of the modes drawn
    fig = Figure(figsize=(7, 5))
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    ref = np.max(np.abs(total))
    for k, m in enumerate(model.modes):
        g = m.response(s)[:, output, input]
        if np.max(np.abs(g)) < 1e-6 * ref:
            continue
        label = f"mode {k + 1}: {m.kind}" + (f" {m.freq_hz:.1f} Hz" if m.kind != "rigid" else "")
        ax_m.loglog(f, np.abs(g), lw=0.8, ls="--", label=label)
        ax_p.semilogx(f, np.degrees(np.angle(g)), lw=0.8, ls="--")
    ax_m.loglog(f, np.abs(total), "k", lw=1.4, label="sum")
    ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(total))), "k", lw=1.4)
    ax_m.set_ylabel("magnitude")
    ax_p.set_ylabel("phase (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    ax_m.legend(fontsize=7)
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.2)
    ax_m.set_title(
        title or f"{model.output_names[output]} / {model.input_names[input]}: mode superposition"
    )
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)

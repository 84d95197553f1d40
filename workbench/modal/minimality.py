"""Minimality of a modal model: Lemma 1 (controllability) and Lemma 2 (observability).

Data flow::

    ModalModel --> per mode: Lemma 1 margin on b_k, Lemma 2 margin on c_k
                   (groups of modes that share an eigenvalue: independence)
               --> cross-checks: PBH rank at every eigenvalue, Gramians of the
                   stable (flexible, real) part
               --> MinimalityReport (frozen) .text() .to_json()

Margins are relative: 1 is perfectly conditioned, 0 is lost. A mode fails
below ``tol``; it is *weak* (nearly uncontrollable / unobservable) below
``weak``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError
from workbench.modal.model import ModalModel

__all__ = ["ModeCheck", "Failure", "MinimalityReport", "check_minimality"]

_MEANING = {
    "controllability": "cannot be moved by the inputs: feedback cannot damp or place it",
    "observability": "does not show in the outputs: an observer cannot estimate it",
}


@dataclass(frozen=True)
class ModeCheck:
    """Margins of one mode (relative, in [0, 1]).

    Attributes
    ----------
    mode : int
        1-based mode number in the :class:`ModalModel`.
    kind : str
    freq_hz : float
    group : tuple of int
        Modes that share this mode's eigenvalue (itself included).
    ctrb_lemma, obsv_lemma : float
        Lemma 1 / 2: ``|b_k| / max_j |b_j|``, and for a mode in a group the
        smaller of that and the sine of the angle between ``b_k`` and the
        span of the group's other ``b``'s (0 for the modes of a dependence).
    ctrb_pbh, obsv_pbh : float
        PBH (eigenvector form): ``sigma_min(W^H B) / |B|_2`` with ``W`` an
        orthonormal basis of the left null space of ``s I - A`` at the mode's
        eigenvalue (resp. ``C`` and the right null space), scaled modal form.
    ctrb_gram, obsv_gram : float or None
        Smallest eigenvalue of the mode's 2x2 (1x1) diagonal block of the
        controllability (observability) Gramian of the stable part, over the
        largest such value; None for rigid modes (no finite Gramian) and for
        unstable real poles.
    """

    mode: int
    kind: str
    freq_hz: float
    group: tuple[int, ...]
    ctrb_lemma: float
    obsv_lemma: float
    ctrb_pbh: float
    obsv_pbh: float
    ctrb_gram: float | None
    obsv_gram: float | None


@dataclass(frozen=True)
class Failure:
    """A mode that fails (or nearly fails) a criterion."""

    mode: int
    kind: str
    freq_hz: float
    property: str  # "controllability" or "observability"
    criterion: str
    margin: float
    severity: str  # "fails" or "weak"
    meaning: str


@dataclass(frozen=True)
class MinimalityReport:
    """Outcome of :func:`check_minimality`."""

    checks: tuple[ModeCheck, ...]
    failures: tuple[Failure, ...]
    tol: float
    weak: float

    @property
    def controllable(self) -> bool:
        return not any(
            f.severity == "fails" and f.property == "controllability" for f in self.failures
        )

    @property
    def observable(self) -> bool:
        return not any(
            f.severity == "fails" and f.property == "observability" for f in self.failures
        )

    @property
    def minimal(self) -> bool:
        return self.controllable and self.observable

    def text(self) -> str:
        lines = [
            " mode  kind       freq (Hz)  ctrb L1   ctrb PBH  ctrb Gram   "
            "obsv L2   obsv PBH  obsv Gram",
        ]
        for c in self.checks:
            g1 = "     -   " if c.ctrb_gram is None else f"{c.ctrb_gram:9.2e}"
            g2 = "     -   " if c.obsv_gram is None else f"{c.obsv_gram:9.2e}"
            lines.append(
                f"{c.mode:5d}  {c.kind:<9s} {c.freq_hz:10.2f}  {c.ctrb_lemma:8.2e} "
                f"{c.ctrb_pbh:9.2e} {g1}  {c.obsv_lemma:8.2e} {c.obsv_pbh:9.2e} {g2}"
            )
        verdict = "minimal (controllable and observable)" if self.minimal else "NOT minimal"
        lines.append(f"verdict: {verdict}; fail below {self.tol:g}, weak below {self.weak:g}")
        for f in self.failures:
            lines.append(
                f"mode {f.mode} ({f.kind}, {f.freq_hz:.2f} Hz) {f.severity} {f.property}: "
                f"{f.criterion}, margin {f.margin:.2e}: {f.meaning}"
            )
        if any(c.kind == "rigid" for c in self.checks):
            lines.append(
                "rigid modes: no finite Gramian (poles at 0); judged by Lemma 1/2 and PBH only"
            )
        return "\n".join(lines)

    def to_json(self) -> str:
        return json.dumps(
            {
                "controllable": self.controllable,
                "observable": self.observable,
                "minimal": self.minimal,
                "tol": self.tol,
                "weak": self.weak,
                "modes": [c.__dict__ | {"group": list(c.group)} for c in self.checks],
                "failures": [f.__dict__ for f in self.failures],
            },
            indent=2,
        )


def check_minimality(
    model: ModalModel, *, tol: float = 1e-8, weak: float = 1e-3, same_pole_rtol: float = 1e-6
) -> MinimalityReport:
    """Check Lemma 1 and Lemma 2 mode by mode, cross-checked by PBH and Gramians.

    Parameters
    ----------
    model : ModalModel
    tol : float
        A relative margin below ``tol`` fails the criterion.
    weak : float
        A relative margin below ``weak`` is reported as nearly failing.
    same_pole_rtol : float
        Modes whose poles differ by less than ``same_pole_rtol |s|`` (or are
        both rigid) share an eigenvalue.

    Returns
    -------
    MinimalityReport

    Notes
    -----
    Lemma 1 (seed 000, sec. 4): the modal model is controllable iff every
    ``b_k`` is nonzero and the ``b_k`` of the modes sharing an eigenvalue are
    linearly independent (the rigid-body modes all sit at 0). Lemma 2 is the
    dual on ``c_k``. PBH (Hautus): ``rank [s I - A, B] = n`` at every
    eigenvalue ``s``. The Gramians solve ``A W + W A^T + B B^T = 0`` for the
    stable part; for a lightly damped mode the diagonal block is about
    ``|b_k|^2 / (4 z w^3)`` times a 2x2 identity in the scaled form (Gawronski
    2004, sec. 4.2), so a small block means a weakly controllable mode.
    """
    if not isinstance(model, ModalModel):
        raise InputError(f"model: expected a ModalModel, got {type(model).__name__}")
    if not model.is_ideal or model.has_outer:
        # the lemmas are about the modal form c_k b_k^T / den_k: exact numerators, lags and
        # coupling add states and directions they do not see
        raise InputError(
            "model: expected an ideal modal model (ModalModel.from_statespace without exact=, "
            "no lags or coupling), got one with exact numerators, lags or coupling"
        )
    modes = model.modes
    n_m = len(modes)
    groups = _groups(model, same_pole_rtol)
    ctrb_l = _lemma_margins([m.b for m in modes], groups)
    obsv_l = _lemma_margins([m.c for m in modes], groups)
    sys = model.to_statespace(form="scaled")
    A, B, C = (np.asarray(x, float) for x in (sys.A, sys.B, sys.C))
    starts = np.cumsum([0] + [m.n_states for m in modes])
    ctrb_p, obsv_p = [], []
    for m in modes:
        s = m.pole
        g = len(groups[len(ctrb_p)])
        ctrb_p.append(_pbh_margin(A, B, s, g))
        obsv_p.append(_pbh_margin(A.T, C.T, np.conj(s), g))
    ctrb_g, obsv_g = _gram_margins(model, A, B, C, starts)
    checks = tuple(
        ModeCheck(
            mode=k + 1,
            kind=modes[k].kind,
            freq_hz=modes[k].freq_hz,
            group=tuple(j + 1 for j in groups[k]),
            ctrb_lemma=ctrb_l[k],
            obsv_lemma=obsv_l[k],
            ctrb_pbh=ctrb_p[k],
            obsv_pbh=obsv_p[k],
            ctrb_gram=ctrb_g[k],
            obsv_gram=obsv_g[k],
        )
        for k in range(n_m)
    )
    failures = []
    for c in checks:
        m = modes[c.mode - 1]
        for prop, lemma_margin, vec, name in (
            ("controllability", c.ctrb_lemma, m.b, "b"),
            ("observability", c.obsv_lemma, m.c, "c"),
        ):
            if lemma_margin >= weak:
                continue
            lemma = "Lemma 1" if prop == "controllability" else "Lemma 2"
            alone = len(c.group) == 1 or np.linalg.norm(vec) < tol * _largest(modes, name)
            margins = ctrb_l if prop == "controllability" else obsv_l
            partners = [j for j in c.group if j != c.mode and margins[j - 1] < weak]
            criterion = (
                f"{lemma}: {name}_{c.mode} = 0"
                if alone
                else f"{lemma}: {name}_{c.mode} is linearly dependent on the {name}'s of modes "
                f"{partners} that share its eigenvalue"
            )
            severity = "fails" if lemma_margin < tol else "weak"
            failures.append(_failure(c, prop, criterion, lemma_margin, severity))
        # cross-check: the PBH rank test must agree with the lemma
        for prop, pbh in (("controllability", c.ctrb_pbh), ("observability", c.obsv_pbh)):
            group_margins = [
                (ctrb_l if prop == "controllability" else obsv_l)[j - 1] for j in c.group
            ]
            # PBH is a test per eigenvalue: a group's dependence shows at every member
            if pbh < tol and min(group_margins) >= weak:
                criterion = "PBH rank test (the lemma passes: not in modal form?)"
                failures.append(_failure(c, prop, criterion, pbh, "fails"))
    return MinimalityReport(checks=checks, failures=tuple(failures), tol=tol, weak=weak)


# ------------------------------------------------------------------ internals
def _failure(c: ModeCheck, prop: str, criterion: str, margin: float, severity: str) -> Failure:
    """A failure of mode check ``c`` for ``prop`` ("controllability" or "observability")."""
    return Failure(
        mode=c.mode,
        kind=c.kind,
        freq_hz=c.freq_hz,
        property=prop,
        criterion=criterion,
        margin=margin,
        severity=severity,
        meaning=_MEANING[prop],
    )


def _largest(modes, name: str) -> float:
    return max((np.linalg.norm(getattr(m, name)) for m in modes), default=1.0) or 1.0


def _groups(model: ModalModel, rtol: float) -> list[list[int]]:
    modes = model.modes
    out = []
    for m in modes:
        g = []
        for j, o in enumerate(modes):
            if m.kind == "rigid" and o.kind == "rigid":
                g.append(j)
            elif m.kind == o.kind and abs(m.pole - o.pole) <= rtol * max(abs(m.pole), 1e-300):
                g.append(j)
        out.append(g)
    return out


def _lemma_margins(vectors, groups) -> list[float]:
    """Per mode: min(|v_k| / max_j |v_j|, sin of the angle between v_k and its group's others).

    The second term is 0 exactly for the modes involved in a linear
    dependence within a group sharing an eigenvalue, and 1 for a vector
    orthogonal to the others, so the report names the dependent modes only.
    """
    big = max((np.linalg.norm(v) for v in vectors), default=0.0)
    out = []
    for k, g in enumerate(groups):
        vk = np.asarray(vectors[k], float)
        nk = np.linalg.norm(vk)
        if big == 0 or nk == 0:
            out.append(0.0)
            continue
        margin = nk / big
        others = [np.asarray(vectors[j], float) for j in g if j != k]
        if others:
            Q, R = np.linalg.qr(np.array(others).T)  # (n_ch, g-1)
            keep = np.abs(np.diag(R)) > 1e-12 * max(np.abs(np.diag(R)).max(), 1e-300)
            Q = Q[:, keep]
            rest = vk - Q @ (Q.T @ vk)
            margin = min(margin, np.linalg.norm(rest) / nk)
        out.append(float(margin))
    return out


def _pbh_margin(A: np.ndarray, B: np.ndarray, s: complex, g: int) -> float:
    """Hautus eigenvector form: sigma_min(W^H B) / |B| over the left null space W of s I - A.

    ``rank [s I - A, B] < n`` iff some left eigenvector ``w`` of ``s`` has
    ``w^H B = 0``; ``W`` (n, g) is an orthonormal basis of the left null space
    (the ``g`` smallest left singular vectors of ``s I - A``, ``g`` the number
    of modes sharing ``s``), so the margin does not depend on the scaling of A.
    """
    n = A.shape[0]
    nb = np.linalg.norm(B, 2)
    if nb == 0:
        return 0.0
    U, _, _ = np.linalg.svd(s * np.eye(n) - A)
    W = U[:, n - g :]
    sv = np.linalg.svd(W.conj().T @ B, compute_uv=False)
    return float(sv[-1] / nb) if sv.size and sv.size >= g else 0.0


def _gram_margins(model, A, B, C, starts):
    """Per-mode Gramian margins of the stable non-rigid part; None where undefined."""
    modes = model.modes
    idx = [k for k, m in enumerate(modes) if m.kind != "rigid" and m.pole.real < 0]
    ctrb = [None] * len(modes)
    obsv = [None] * len(modes)
    if not idx:
        return ctrb, obsv
    states = np.concatenate([np.arange(starts[k], starts[k + 1]) for k in idx])
    As = A[np.ix_(states, states)]
    Wc = scipy.linalg.solve_continuous_lyapunov(As, -B[states] @ B[states].T)
    Wo = scipy.linalg.solve_continuous_lyapunov(As.T, -C[:, states].T @ C[:, states])
    vals_c, vals_o = [], []
    pos = 0
    for k in idx:
        d = modes[k].n_states
        blk = slice(pos, pos + d)
        vals_c.append(max(0.0, float(np.min(np.linalg.eigvalsh(Wc[blk, blk])))))
        vals_o.append(max(0.0, float(np.min(np.linalg.eigvalsh(Wo[blk, blk])))))
        pos += d
    mc, mo = max(vals_c) or 1.0, max(vals_o) or 1.0
    for k, vc, vo in zip(idx, vals_c, vals_o):
        ctrb[k] = vc / mc
        obsv[k] = vo / mo
    return ctrb, obsv

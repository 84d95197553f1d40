"""The modal model as a parameter vector: pack a ModalModel into ``theta``, unpack ``theta``.

Refinement (:mod:`workbench.ident.refine`) and its Cramer-Rao bound fit and
differentiate the model through this one layout::

    ModalModel --pack(model, feedthrough=)--> (ParameterLayout, theta (n_par,))
    theta --layout.unpack(theta, template)--> ModalModel
    covariance (n_par, n_par) --layout.mode_std(cov)--> per-mode std of freq (Hz), damping

``theta`` holds, in order:

- the rigid body: one gain ``P = sum_k c_k b_k^T`` of ``1/s^2`` (``n_y n_u``
  entries, ``"rigid P"``) when there are at least ``min(n_u, n_y)`` rigid modes
  (their split into modes is not identifiable from the response), else
  ``c_k``, ``b_k`` per rigid mode;
- per flexible mode: ``freq_hz`` (Hz), ``damping``, ``c`` (n_y,), ``b`` (n_u,);
- per real mode: the pole (rad/s), ``c``, ``b``;
- ``D`` (``n_y n_u``, row-major) when ``feedthrough``.

The ideal modal form only (rank-one ``c b^T`` numerators, no lags or
coupling): a mode's exact numerator is not a parameter here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.modal.model import ModalModel, Mode, split_rigid_gain

__all__ = ["ParameterLayout", "pack"]

#: model order of the mode kinds (ModalModel: rigid, flexible, real)
_ORDER = {"rigid": 0, "flexible": 1, "real": 2}


@dataclass(frozen=True)
class ParameterLayout:
    """Where each mode's parameters sit in ``theta`` (see the module docstring).

    Attributes
    ----------
    kinds : tuple of str
        Per entry: ``"rigid_full"`` (the shared gain P), ``"rigid"``, ``"flexible"``, ``"real"``.
    slices : tuple of dict
        Per entry, the slices of ``theta``: ``"P"``; or ``"c"``, ``"b"`` and
        ``"f"``, ``"zeta"`` (flexible) or ``"s"`` (real).
    d_slice : slice or None
        The feedthrough ``D``, row-major.
    n_par, n_u, n_y, n_rigid : int
    names : tuple of str
        One name per entry of ``theta``.
    """

    kinds: tuple[str, ...]
    slices: tuple[dict, ...]
    d_slice: slice | None
    n_par: int
    n_u: int
    n_y: int
    n_rigid: int
    names: tuple[str, ...]

    def unpack(self, theta: np.ndarray, template: ModalModel) -> ModalModel:
        """The modal model at ``theta`` (n_par,), names (and D without feedthrough) of ``template``.

        Each mode's scale is split ``|b| = |c|``, largest entry of ``c`` positive
        (as :meth:`ModalModel.from_statespace`); the modes sorted rigid, flexible
        by frequency, real by ``|p|``; a shared gain P split by
        :func:`~workbench.modal.model.split_rigid_gain`.
        """
        n_y, n_u = self.n_y, self.n_u
        modes: list[Mode] = []
        for kind, sl in zip(self.kinds, self.slices):
            if kind == "rigid_full":
                C, B = split_rigid_gain(theta[sl["P"]].reshape(n_y, n_u), self.n_rigid)
                modes += [Mode("rigid", 0.0, 0.0, B[k], C[:, k]) for k in range(self.n_rigid)]
                continue
            c, b = theta[sl["c"]].copy(), theta[sl["b"]].copy()
            nc, nb = np.linalg.norm(c), np.linalg.norm(b)
            if nc > 0 and nb > 0:
                a = np.sqrt(nb / nc)
                c, b = c * a, b / a
                if c[np.argmax(np.abs(c))] < 0:
                    c, b = -c, -b
            if kind == "rigid":
                modes.append(Mode(kind="rigid", freq_hz=0.0, damping=0.0, b=b, c=c))
            elif kind == "flexible":
                f, zeta = theta[sl["f"]][0], theta[sl["zeta"]][0]
                modes.append(Mode(kind="flexible", freq_hz=abs(f), damping=zeta, b=b, c=c))
            else:
                s = theta[sl["s"]][0]
                modes.append(
                    Mode(
                        kind="real",
                        freq_hz=abs(s) / (2 * np.pi),
                        damping=1.0 if s < 0 else -1.0,
                        b=b,
                        c=c,
                    )
                )
        modes.sort(key=lambda m: (_ORDER[m.kind], m.freq_hz))
        D = theta[self.d_slice].reshape(n_y, n_u) if self.d_slice is not None else template.D
        return ModalModel(
            modes=tuple(modes),
            D=D,
            transform=None,
            rigid_poles=np.zeros(2 * self.n_rigid, complex),
            input_names=template.input_names,
            output_names=template.output_names,
        )

    def mode_std(self, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Standard deviations of frequency (Hz) and damping per mode, in layout order.

        ``cov`` (n_par, n_par) is the covariance of ``theta``; rigid modes get NaN,
        a real pole's damping 0 (it is fixed at +-1).
        """
        f_std, z_std = [], []
        for kind, sl in zip(self.kinds, self.slices):
            if kind == "rigid_full":
                f_std += [np.nan] * self.n_rigid
                z_std += [np.nan] * self.n_rigid
            elif kind == "rigid":
                f_std.append(np.nan)
                z_std.append(np.nan)
            elif kind == "flexible":
                i, j = sl["f"].start, sl["zeta"].start
                f_std.append(np.sqrt(max(cov[i, i], 0.0)))
                z_std.append(np.sqrt(max(cov[j, j], 0.0)))
            else:
                i = sl["s"].start
                f_std.append(np.sqrt(max(cov[i, i], 0.0)) / (2 * np.pi))
                z_std.append(0.0)
        return np.array(f_std), np.array(z_std)

    def mode_order(self, theta: np.ndarray) -> np.ndarray:
        """Permutation from layout order to the order of :meth:`unpack`'s modes."""
        keys = []
        for kind, sl in zip(self.kinds, self.slices):
            if kind == "rigid_full":
                keys += [(0, 0.0)] * self.n_rigid
            elif kind == "rigid":
                keys.append((0, 0.0))
            elif kind == "flexible":
                keys.append((1, abs(theta[sl["f"]][0])))
            else:
                keys.append((2, abs(theta[sl["s"]][0]) / (2 * np.pi)))
        return np.array(sorted(range(len(keys)), key=lambda i: keys[i]), int)


def pack(model: ModalModel, *, feedthrough: bool = False) -> tuple[ParameterLayout, np.ndarray]:
    """The layout of ``model``'s parameters and their values ``theta`` (n_par,).

    Parameters
    ----------
    model : ModalModel
        Ideal modal form (``c_k``, ``b_k`` per mode; an exact numerator is not packed).
    feedthrough : bool
        Make ``D`` a parameter.
    """
    n_u, n_y = model.n_u, model.n_y
    rigid = model.modes_of_kind("rigid")
    kinds, slices, theta, names = [], [], [], []
    k = 0

    def take(n, label):
        nonlocal k
        s = slice(k, k + n)
        k += n
        names.extend(f"{label}[{i}]" for i in range(n)) if n > 1 else names.append(label)
        return s

    full_rigid = len(rigid) >= min(n_u, n_y) and len(rigid) > 0
    if full_rigid:
        P = sum(np.outer(m.c, m.b) for m in rigid)
        kinds.append("rigid_full")
        slices.append({"P": take(n_y * n_u, "rigid P")})
        theta.append(P.ravel())
    j = 0
    for m in model.modes:
        j += 1
        if m.kind == "rigid":
            if full_rigid:
                continue
            kinds.append("rigid")
            slices.append({"c": take(n_y, f"mode {j} c"), "b": take(n_u, f"mode {j} b")})
            theta += [m.c, m.b]
        elif m.kind == "flexible":
            kinds.append("flexible")
            slices.append(
                {
                    "f": take(1, f"mode {j} freq_hz"),
                    "zeta": take(1, f"mode {j} damping"),
                    "c": take(n_y, f"mode {j} c"),
                    "b": take(n_u, f"mode {j} b"),
                }
            )
            theta += [[m.freq_hz], [m.damping], m.c, m.b]
        else:
            kinds.append("real")
            slices.append(
                {
                    "s": take(1, f"mode {j} pole"),
                    "c": take(n_y, f"mode {j} c"),
                    "b": take(n_u, f"mode {j} b"),
                }
            )
            theta += [[m.pole.real], m.c, m.b]
    d_slice = None
    if feedthrough:
        d_slice = take(n_y * n_u, "D")
        theta.append(model.D.ravel())
    layout = ParameterLayout(
        kinds=tuple(kinds),
        slices=tuple(slices),
        d_slice=d_slice,
        n_par=k,
        n_u=n_u,
        n_y=n_y,
        n_rigid=len(rigid),
        names=tuple(names),
    )
    return layout, np.concatenate([np.ravel(t) for t in theta]).astype(float)

"""The FE model file (spec section 4): K, M affine in the physical parameters alpha.

    K(alpha) = K0 + sum_i alpha_i K_i,   M(alpha) = M0 + sum_i alpha_i M_i

with a force input map ``B`` (n, n_u), a displacement output map ``C``
(n_y, n), channel names and modal damping. :func:`fe_from_arrays` checks a file
at the boundary (symmetry, shapes, names, a positive definite mass matrix at the
nominal alpha) and refuses a bad one with one line; :func:`fe_arrays` writes the
arrays back, every matrix exactly as given (only ``alpha`` and ``damping`` are
the tool's to change).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from workbench.core.arrays import readonly
from workbench.core.atomic import save_npz
from workbench.core.errors import InputError, describe

__all__ = ["FEModel", "fe_from_arrays", "read_fe", "fe_arrays", "save_fe"]

_KEYS = ("K0", "M0", "K_i", "M_i", "alpha", "parameter_names", "B", "C", "damping")
#: Relative asymmetry ``max|A - A^T| / max|A|`` above which a matrix is refused.
SYMMETRY_RTOL = 1e-10


@dataclass(frozen=True, eq=False)
class FEModel:
    """A parameterized FE model (spec 4), read-only arrays.

    Attributes
    ----------
    K0, M0 : (n, n) arrays
        Parameter-independent stiffness (N/m, or N m/rad for rotations) and mass (kg).
    K_i, M_i : (p, n, n) arrays
        Stiffness and mass per unit of each parameter.
    alpha : (p,) array
        Parameter values, SI units.
    parameter_names : tuple of p str
    B : (n, n_u) array
        Force input map, DOF forces = ``B u`` (u in N).
    C : (n_y, n) array
        Displacement output map, ``y = C q`` (m).
    damping : (n_m,) array
        Modal damping ratio of the first ``n_m`` modes (a scalar file value is
        stored as shape (1,) with ``damping_scalar`` True: it holds for every mode).
    input_names, output_names : tuple of str
    damping_scalar : bool
    """

    K0: np.ndarray
    M0: np.ndarray
    K_i: np.ndarray
    M_i: np.ndarray
    alpha: np.ndarray
    parameter_names: tuple[str, ...]
    B: np.ndarray
    C: np.ndarray
    damping: np.ndarray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    damping_scalar: bool = False

    @property
    def n_dof(self) -> int:
        return self.K0.shape[0]

    @property
    def n_par(self) -> int:
        return self.alpha.size

    def matrices(self, alpha=None) -> tuple[np.ndarray, np.ndarray]:
        """K(alpha), M(alpha), each (n, n); default the model's own alpha."""
        a = self.alpha if alpha is None else np.asarray(alpha, float)
        if a.shape != self.alpha.shape:
            raise InputError(f"alpha: expected shape {self.alpha.shape}, got {a.shape}")
        K = self.K0 + np.tensordot(a, self.K_i, axes=1)
        M = self.M0 + np.tensordot(a, self.M_i, axes=1)
        return K, M

    def mode_damping(self, n_modes: int) -> np.ndarray:
        """Damping ratio of the first ``n_modes`` modes (nan beyond the file's ``n_m``)."""
        if self.damping_scalar:
            return np.full(n_modes, float(self.damping[0]))
        out = np.full(n_modes, np.nan)
        k = min(n_modes, self.damping.size)
        out[:k] = self.damping[:k]
        return out

    def output_index(self, names, src: str = "data") -> np.ndarray:
        """Rows of ``C`` for output ``names``; a name the file lacks is refused."""
        return _index(names, self.output_names, src, "output")

    def input_index(self, names, src: str = "data") -> np.ndarray:
        """Columns of ``B`` for input ``names``; a name the file lacks is refused."""
        return _index(names, self.input_names, src, "input")


def _index(names, have: tuple[str, ...], src: str, what: str) -> np.ndarray:
    idx = []
    for n in names:
        if n not in have:
            raise InputError(
                f"{src}: {what} '{n}' is not in the FE model; expected one of {', '.join(have)}"
            )
        idx.append(have.index(n))
    return np.array(idx, int)


def _matrix(arrays, key: str, shape: tuple, src: str) -> np.ndarray:
    if key not in arrays:
        have = ", ".join(sorted(arrays)) or "none"
        raise InputError(f"{src}: missing key '{key}' (spec 4); keys present: {have}")
    a = np.asarray(arrays[key])
    if a.dtype.kind not in "fiu" or a.dtype == bool:
        raise InputError(f"{src}: key '{key}': expected a real array, got {describe(a)}")
    if a.shape != shape:
        want = "(" + ", ".join(str(s) for s in shape) + ")"
        raise InputError(f"{src}: key '{key}': expected shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{src}: key '{key}': expected finite values, got nan or inf")
    return a.astype(float)


def _symmetric(a: np.ndarray, src: str, key: str) -> None:
    scale = np.max(np.abs(a)) if a.size else 0.0
    if scale == 0:
        return
    asym = np.max(np.abs(a - np.swapaxes(a, -1, -2)))
    if asym > SYMMETRY_RTOL * scale:
        raise InputError(
            f"{src}: key '{key}': expected a symmetric matrix, got max|A - A^T| / max|A| = "
            f"{asym / scale:.3g}"
        )


def _names(arrays, key: str, n: int, src: str) -> tuple[str, ...]:
    if key not in arrays:
        raise InputError(f"{src}: missing key '{key}' ({n} names; spec 4 matches channels by name)")
    a = np.asarray(arrays[key])
    if a.ndim != 1 or a.dtype.kind not in "US" or a.size != n:
        raise InputError(f"{src}: key '{key}': expected {n} strings, got {describe(a)}")
    names = tuple(str(s) for s in a)
    if len(set(names)) != n or any(not s for s in names):
        raise InputError(f"{src}: key '{key}': expected {n} distinct non-empty names, got {names}")
    return names


def fe_from_arrays(arrays: dict, src: str = "FE model") -> FEModel:
    """Check spec-4 arrays and build an :class:`FEModel`; one-line InputError on bad input.

    Refused: a missing key, ``kind`` other than "fe", a shape mismatch, non-finite
    values, a non-symmetric K0/M0/K_i/M_i, missing or duplicate names, damping
    outside [0, 1), and M(alpha) not positive definite at the file's alpha.
    """
    kind = arrays.get("kind")
    if kind is None or np.asarray(kind).dtype.kind not in "US" or str(np.asarray(kind)) != "fe":
        got = "missing" if kind is None else describe(np.asarray(kind))
        raise InputError(f"{src}: key 'kind': expected 'fe' (spec 4), got {got}")
    if "K0" not in arrays:
        _matrix(arrays, "K0", (0, 0), src)
    n = np.asarray(arrays["K0"]).shape[0] if np.asarray(arrays["K0"]).ndim >= 1 else 0
    K0 = _matrix(arrays, "K0", (n, n), src)
    M0 = _matrix(arrays, "M0", (n, n), src)
    alpha = _matrix(arrays, "alpha", np.asarray(arrays.get("alpha", np.zeros(0))).shape, src)
    if alpha.ndim != 1 or alpha.size < 1:
        raise InputError(f"{src}: key 'alpha': expected shape (p,) with p >= 1, got {alpha.shape}")
    p = alpha.size
    K_i = _matrix(arrays, "K_i", (p, n, n), src)
    M_i = _matrix(arrays, "M_i", (p, n, n), src)
    for key, a in (("K0", K0), ("M0", M0), ("K_i", K_i), ("M_i", M_i)):
        _symmetric(a, src, key)
    B = np.asarray(arrays.get("B", np.zeros((0, 0))))
    n_u = B.shape[1] if B.ndim == 2 else 0
    B = _matrix(arrays, "B", (n, n_u), src)
    Cr = np.asarray(arrays.get("C", np.zeros((0, 0))))
    n_y = Cr.shape[0] if Cr.ndim == 2 else 0
    C = _matrix(arrays, "C", (n_y, n), src)
    if n_u < 1 or n_y < 1:
        raise InputError(f"{src}: keys 'B', 'C': expected at least one input and one output")
    pnames = _names(arrays, "parameter_names", p, src)
    in_names = _names(arrays, "input_names", n_u, src)
    out_names = _names(arrays, "output_names", n_y, src)
    d = np.asarray(arrays.get("damping", np.nan))
    if "damping" not in arrays:
        raise InputError(f"{src}: missing key 'damping' (modal damping ratio, float or (n_m,))")
    if d.dtype.kind not in "fiu" or d.ndim > 1 or d.size < 1:
        raise InputError(
            f"{src}: key 'damping': expected a float or (n_m,) floats, got {describe(d)}"
        )
    d = d.astype(float).reshape(-1)
    if not np.all(np.isfinite(d)) or np.any(d < 0) or np.any(d >= 1):
        raise InputError(
            f"{src}: key 'damping': expected ratios in [0, 1), got {d.min():g}..{d.max():g}"
        )
    model = FEModel(
        K0=readonly(K0),
        M0=readonly(M0),
        K_i=readonly(K_i),
        M_i=readonly(M_i),
        alpha=readonly(alpha),
        parameter_names=pnames,
        B=readonly(B),
        C=readonly(C),
        damping=readonly(d),
        input_names=in_names,
        output_names=out_names,
        damping_scalar=np.asarray(arrays["damping"]).ndim == 0,
    )
    _, M = model.matrices()
    try:
        scipy.linalg.cholesky(M, lower=True)
    except np.linalg.LinAlgError:
        w = scipy.linalg.eigvalsh(M)
        raise InputError(
            f"{src}: M(alpha) at the file's alpha: expected positive definite, got smallest "
            f"eigenvalue {w[0]:.3g} kg"
        ) from None
    return model


def read_fe(path: str | os.PathLike) -> FEModel:
    """Read and check a spec-4 FE model file."""
    from workbench.io.formats import read_npz

    return fe_from_arrays(read_npz(path), src=str(path))


def fe_arrays(
    model: FEModel,
    *,
    alpha=None,
    damping=None,
    original: dict | None = None,
) -> dict[str, np.ndarray]:
    """Spec-4 arrays of ``model`` with ``alpha`` and ``damping`` replaced.

    ``original`` (the arrays as read) makes every other key go back exactly as
    given (dtype and values; extra keys kept); otherwise the model's arrays.
    """
    if original is not None:
        out = {k: np.asarray(v) for k, v in original.items()}
    else:
        out = {
            "kind": np.array("fe"),
            "K0": model.K0,
            "M0": model.M0,
            "K_i": model.K_i,
            "M_i": model.M_i,
            "alpha": model.alpha,
            "parameter_names": np.array(model.parameter_names),
            "B": model.B,
            "C": model.C,
            "damping": model.damping[0] if model.damping_scalar else model.damping,
            "input_names": np.array(model.input_names),
            "output_names": np.array(model.output_names),
        }
    if alpha is not None:
        a = np.asarray(alpha, float)
        if a.shape != model.alpha.shape:
            raise InputError(f"alpha: expected shape {model.alpha.shape}, got {a.shape}")
        out["alpha"] = a
    if damping is not None:
        out["damping"] = np.asarray(damping, float)
    return out


def save_fe(path: str | os.PathLike, model: FEModel, **changes) -> None:
    """Write ``model`` as a spec-4 file, atomically (``changes`` as in :func:`fe_arrays`)."""
    arrays = fe_arrays(model, **changes)
    fe_from_arrays(arrays, src=str(path))  # never write a file we would refuse to read
    save_npz(path, **arrays)

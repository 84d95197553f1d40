"""The compiled closed loop: a linear controller on a plant that describes its own sampled step.

Data flow::

    plant.sampled_step() -> SampledStep (A, B0, B1, m, C, D, saturation, raw map, noise,
                                         quantization, decoupling: what plant.step does)
    controller.statespace() -> (A_c, B_c, C_c, D_c)
        |  sparse_realization: exact power-of-2 balancing, real Schur, block
        |  diagonalization (Bavely-Stewart) while the transformation stays well conditioned
        v
    workbench._kernels.closed_loop_kernel (numba, one pass over the N samples) -> u, y

The kernel draws the noise from the caller's generator, in the loop, exactly as
``plant.step`` draws it (``standard_normal(n_raw)`` per sample: NumPy's ziggurat on the
generator's own bit stream, the same numbers and the generator left in the same state),
so the compiled loop and ``plant.step`` / ``controller.step`` give the same u and y to
rounding (tested). The kernel's arguments of a plant and of a controller are memoized on
their matrices (a scan or a repeated run prepares them once). The plant's description is
the plant's own business (it may read its own settings); identification code never sees it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.linalg

from workbench.core.errors import InputError

__all__ = [
    "SampledStep",
    "SparseRealization",
    "sparse_realization",
    "banded",
    "run_compiled_loop",
]

#: Largest entry of a Sylvester solution accepted when splitting off a diagonal block: the
#: transformation's condition number (and the rounding difference to the original
#: coordinates) grows with it.
_MAX_COUPLING = 100.0


@dataclass(frozen=True)
class SampledStep:
    """What one ``plant.step`` does, as matrices and static nonlinearities.

    At sample k, with ``u_s[j] = clip(u[j], -saturation, saturation)``::

        raw  = raw_map (C x + D u_s[k-m]) + noise_std * w[k]   (w ~ N(0, 1), drawn when any std > 0)
        raw  = quantization * round(raw / quantization)       (when quantization > 0)
        y[k] = decouple raw
        x   <- A x + B0 u_s[k-m] + B1 u_s[k-m-1]

    Parameters
    ----------
    A : (n, n) array
        Discrete state matrix over one sample.
    B0, B1 : (n, n_u) arrays
        Inputs u[k-m] and u[k-m-1] (fractional delay), N -> state.
    m : int
        Whole samples of the input delay.
    C : (n_y, n) array, D : (n_y, n_u) array
        Noise-free outputs, m.
    saturation : (n_u,) array
        Symmetric saturation of each delayed input, N (inf = none).
    raw_map : (n_raw, n_y) array
        Outputs to raw sensors.
    decouple : (n_y, n_raw) array
        Raw sensors to measured outputs.
    noise_std : (n_raw,) array
        White noise on each raw sensor, m.
    quantization : float
        Raw sensor resolution, m (0 = none).
    """

    A: np.ndarray
    B0: np.ndarray
    B1: np.ndarray
    m: int
    C: np.ndarray
    D: np.ndarray
    saturation: np.ndarray
    raw_map: np.ndarray
    decouple: np.ndarray
    noise_std: np.ndarray
    quantization: float

    def __post_init__(self):
        arrays = {k: np.array(getattr(self, k), float) for k in _ARRAYS}
        n = arrays["A"].shape[0]
        n_u = arrays["B0"].shape[1]
        n_y = arrays["C"].shape[0]
        n_raw = arrays["raw_map"].shape[0]
        want = {
            "A": (n, n),
            "B0": (n, n_u),
            "B1": (n, n_u),
            "C": (n_y, n),
            "D": (n_y, n_u),
            "saturation": (n_u,),
            "raw_map": (n_raw, n_y),
            "decouple": (n_y, n_raw),
            "noise_std": (n_raw,),
        }
        for k, shape in want.items():
            if arrays[k].shape != shape:
                raise InputError(f"SampledStep.{k}: expected shape {shape}, got {arrays[k].shape}")
        if int(self.m) != self.m or self.m < 0:
            raise InputError(f"SampledStep.m: expected an integer >= 0, got {self.m!r}")
        if not self.quantization >= 0:
            raise InputError(
                f"SampledStep.quantization: expected >= 0 m, got {self.quantization!r}"
            )
        for k, a in arrays.items():
            a.setflags(write=False)
            object.__setattr__(self, k, a)
        object.__setattr__(self, "m", int(self.m))
        object.__setattr__(self, "quantization", float(self.quantization))


_ARRAYS = ("A", "B0", "B1", "C", "D", "saturation", "raw_map", "decouple", "noise_std")


@dataclass(frozen=True)
class SparseRealization:
    """x = S z: A_z = S^-1 A S block diagonal (or A itself when that is cheaper).

    Parameters
    ----------
    A, S : (n, n) arrays
        The realization's state matrix and the transformation (x = S z).
    blocks : tuple of int
        Sizes of the diagonal blocks (one block of size n: no split found).
    cond : float
        Condition number of the non-diagonal part of S (the exact power-of-2
        balancing excluded); rounding differences to the original coordinates
        grow with it.
    """

    A: np.ndarray
    S: np.ndarray
    blocks: tuple[int, ...]
    cond: float

    def to_z(self, B: np.ndarray) -> np.ndarray:
        """S^-1 B for an input matrix B (n, n_in)."""
        return np.linalg.solve(self.S, B)

    def from_z(self, C: np.ndarray) -> np.ndarray:
        """C S for an output matrix C (n_out, n)."""
        return C @ self.S


def _schur_blocks(T: np.ndarray) -> list[int]:
    """Start indices of the 1x1 / 2x2 diagonal blocks of a real Schur form, and n."""
    n = T.shape[0]
    b, i = [0], 0
    while i < n:
        i += 2 if i + 1 < n and T[i + 1, i] != 0 else 1
        b.append(i)
    return b


def banded(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A in the kernel's banded storage: its tridiagonal part and the rows with more.

    Parameters
    ----------
    A : (n, n) array

    Returns
    -------
    tri : (3, n) array
        A[i, i-1], A[i, i], A[i, i+1] (zero outside the matrix).
    rows : (r,) int64 array
        Rows with a nonzero outside the tridiagonal band.
    Er : (r, n) array
        Those rows of A with the band set to zero.
    """
    A = np.asarray(A, float)
    n = A.shape[0]
    tri = np.zeros((3, n))
    tri[1] = np.diagonal(A)
    tri[0, 1:] = np.diagonal(A, -1)
    tri[2, :-1] = np.diagonal(A, 1)
    i, j = np.indices((n, n))
    E = np.where(np.abs(i - j) <= 1, 0.0, A)
    rows = np.flatnonzero(np.any(E != 0, axis=1))
    return tri, rows.astype(np.int64), np.ascontiguousarray(E[rows])


def _identity(A: np.ndarray) -> SparseRealization:
    """A kept as it is (x = z)."""
    n = A.shape[0]
    return SparseRealization(A=np.array(A, float), S=np.eye(n), blocks=(n,), cond=1.0)


def _cost(A: np.ndarray) -> int:
    """Multiply-adds of one product A x in banded storage."""
    _, rows, _ = banded(A)
    return (3 + rows.size) * A.shape[0]


def sparse_realization(A: np.ndarray, *, max_coupling: float = _MAX_COUPLING) -> SparseRealization:
    """A cheap-to-step realization of A: block diagonal where it is well conditioned.

    Parameters
    ----------
    A : (n, n) array
        Discrete state matrix.
    max_coupling : float
        Largest entry of a decoupling Sylvester solution (in balanced
        coordinates) accepted to split off a block.

    Returns
    -------
    SparseRealization
        A itself (S = I) when it already costs no more than the block form.

    Notes
    -----
    1. Balance: A_b = D^-1 A D with D a diagonal of powers of 2 (exact, no rounding).
    2. Real Schur form A_b = Z T Z^T (orthogonal).
    3. Going down the diagonal, the leading cluster T11 is split from the rest
       by W = [[I, X], [0, I]], T11 X - X T22 = -T12, when max |X| <= max_coupling;
       otherwise the cluster grows by the next 1x1 / 2x2 block (close or
       defective eigenvalues, e.g. several integrators, stay in one block).
    Bavely & Stewart, An algorithm for computing reducing subspaces by block
    diagonalization, SIAM J. Numer. Anal. 16 (1979) 359-367.
    """
    A = np.asarray(A, float)
    n = A.shape[0]
    if n == 0:
        return SparseRealization(A=A.copy(), S=np.eye(0), blocks=(), cond=1.0)
    Ab, (Dv, _) = scipy.linalg.matrix_balance(A, permute=False, separate=True)
    T, Z = scipy.linalg.schur(Ab, output="real")
    (trsyl,) = scipy.linalg.get_lapack_funcs(("trsyl",), (T,))
    W = Z.copy()
    bounds = _schur_blocks(T)
    blocks, s, idx = [], 0, 1
    while s < n:
        e = bounds[idx]
        while e < n:
            # T11, T22 are quasi-triangular already: LAPACK's trsyl solves directly
            X, scale, info = trsyl(T[s:e, s:e], T[e:, e:], -T[s:e, e:], isgn=-1)
            X = X / scale if info >= 0 and scale > 0 else np.full_like(X, np.inf)
            if np.all(np.isfinite(X)) and np.max(np.abs(X)) <= max_coupling:
                T[s:e, e:] = 0.0  # decoupled: W^-1 T W has a zero block here
                W[:, e:] += W[:, s:e] @ X
                break
            idx += 1
            e = bounds[idx]
        blocks.append(e - s)
        s, idx = e, idx + 1
    cond = float(np.linalg.cond(W))
    if _cost(T) >= _cost(A):
        return _identity(A)
    S = Dv[:, None] * W  # x = D W z
    return SparseRealization(A=T, S=S, blocks=tuple(blocks), cond=cond)


@lru_cache(maxsize=16)
def _cached_realization(n: int, a_bytes: bytes) -> SparseRealization:
    """:func:`sparse_realization` memoized on the matrix's bytes: a scan or a repeated
    simulation reuses one controller (its realization costs about 1-2 ms for 34 states)."""
    A = np.frombuffer(a_bytes, dtype=float).reshape(n, n)
    sr = sparse_realization(A)
    for arr in (sr.A, sr.S):
        arr.setflags(write=False)
    return sr


def _key(*arrays: np.ndarray) -> tuple:
    """A hashable key of float arrays: their shapes and bytes."""
    return tuple((a.shape, np.ascontiguousarray(a, dtype=float).tobytes()) for a in arrays)


def _frozen(*arrays) -> tuple:
    out = []
    for a in arrays:
        a = np.ascontiguousarray(a)
        a.setflags(write=False)
        out.append(a)
    return tuple(out)


@lru_cache(maxsize=16)
def _plant_arrays(key: tuple) -> tuple:
    """The kernel's plant arguments (memoized on the matrices: a scan or a repeated run
    reuses them; banded storage and the realization test cost about 0.5 ms a call)."""
    A, B0, B1, C, D, raw_map = (np.frombuffer(b, dtype=float).reshape(s) for s, b in key)
    n = A.shape[0]
    plant = sparse_realization(A) if _cost(A) > 3 * n else _identity(A)
    Cr = plant.from_z(raw_map @ C)
    cols = np.flatnonzero(np.any(Cr != 0, axis=0))  # states no sensor reads: skipped
    return _frozen(
        *banded(plant.A),
        _t_or_empty(plant.to_z(B0), n),
        _t_or_empty(plant.to_z(B1), n),
        Cr[:, cols],
        cols.astype(np.int64),
        _t_or_empty(raw_map @ D, raw_map.shape[0]),
    )


@lru_cache(maxsize=16)
def _controller_arrays(key: tuple) -> tuple:
    """The kernel's controller arguments, memoized on the controller's matrices."""
    Ac, Bc, Cc, Dc = (np.frombuffer(b, dtype=float).reshape(s) for s, b in key)
    ctrl = _cached_realization(Ac.shape[0], Ac.tobytes())
    return _frozen(*banded(ctrl.A), ctrl.to_z(Bc).T, ctrl.from_z(Cc), _t_or_empty(Dc, Cc.shape[0]))


def _t_or_empty(M: np.ndarray, n_cols: int) -> np.ndarray:
    """M transposed, or (0, n_cols) when M is zero: no work in the kernel."""
    return np.ascontiguousarray(M.T) if np.any(M) else np.zeros((0, n_cols))


#: The generator handed to the kernel for a noise-free plant (nothing is drawn from it).
_NO_NOISE_RNG = np.random.default_rng(0)
_NO_NOISE_STD = _frozen(np.zeros(0))[0]  # read-only as SampledStep's arrays: one signature


def run_compiled_loop(
    step: SampledStep,
    controller_abcd,
    r: np.ndarray | None,
    d: np.ndarray,
    rng: np.random.Generator | None,
    delay_samples: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The closed loop of :func:`workbench.sim.closed_loop` in the compiled kernel.

    Parameters
    ----------
    step : SampledStep
        The plant's sampled step.
    controller_abcd : (A, B, C, D)
        Discrete controller e -> u_c.
    r : (N, n_y) array or None, d : (N, n_u) array
        Reference (None: zero) and input excitation.
    rng : numpy.random.Generator or None
        Source of the noise (None only for a noise-free plant): the kernel draws
        ``standard_normal(n_raw)`` per sample from it, as ``plant.step`` does
        (the same numbers, the generator left in the same state).
    delay_samples : int
        Loop delay, samples.

    Returns
    -------
    u : (N, n_u) array, y : (N, n_y) array
    """
    from workbench import _kernels  # numba: an ImportError here is a broken install

    Ac, Bc, Cc, Dc = (np.asarray(a, float) for a in controller_abcd)
    if delay_samples == 0 and np.any(Dc):
        raise InputError(
            "controller: stepping the loop needs delay_samples >= 1 or a controller without "
            "direct feedthrough (u[k] must not depend on y[k])"
        )
    N, n_u = d.shape
    n_y = step.C.shape[0]
    noisy = bool(np.any(step.noise_std > 0))
    if noisy and not isinstance(rng, np.random.Generator):
        raise InputError(f"rng: expected a numpy.random.Generator for the noise, got {rng!r}")
    plant = _plant_arrays(_key(step.A, step.B0, step.B1, step.C, step.D, step.raw_map))
    ctrl = _controller_arrays(_key(Ac, Bc, Cc, Dc))
    noise_std = step.noise_std if noisy else _NO_NOISE_STD
    r = np.zeros((N, 0)) if r is None else np.ascontiguousarray(r, dtype=float)
    u = np.empty((N, n_u))
    y = np.empty((N, n_y))
    args = (
        *plant, step.m, step.saturation, step.decouple,
        rng if noisy else _NO_NOISE_RNG, noise_std, step.quantization,
        *ctrl, int(delay_samples), r, np.ascontiguousarray(d, dtype=float), u, y,
    )  # fmt: skip
    if noisy:
        with rng.bit_generator.lock:  # as NumPy holds it while it draws
            _kernels.closed_loop_kernel(*args)
    else:
        _kernels.closed_loop_kernel(*args)
    return u, y

"""Subspace identification: structured Gram, exact recovery, closed-loop bias, memory."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from workbench.core.errors import InputError
from workbench.ident import (
    METHODS,
    format_singular_values,
    identify_subspace,
    plot_singular_values,
    suggest_order,
)
from workbench.ident.gram import hankel, hankel_gram
from workbench.io.formats import TimeData


# ------------------------------------------------------------------ helpers
def random_stable(rng: np.random.Generator, n: int, n_u: int, n_y: int, *, radius: float = 0.9):
    """A random discrete system, poles of modulus <= radius (similar to a real block form)."""
    A = np.zeros((n, n))
    k = 0
    while k < n:
        rho = radius * rng.uniform(0.5, 1.0)
        if k + 1 < n:
            th = rng.uniform(0.2, 2.8)
            A[k : k + 2, k : k + 2] = rho * np.array(
                [[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]]
            )
            k += 2
        else:
            A[k, k] = rho
            k += 1
    T = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    A = T @ A @ np.linalg.inv(T)
    return (
        A,
        rng.standard_normal((n, n_u)),
        rng.standard_normal((n_y, n)),
        rng.standard_normal((n_y, n_u)),
    )


def simulate(A, B, C, D, u, v=None, *, K=None, r=None):
    """Open loop (u given) or closed loop u[k] = r[k] - K y[k] (D must be 0 then)."""
    N = (u if u is not None else r).shape[0]
    x = np.zeros(A.shape[0])
    y = np.zeros((N, C.shape[0]))
    uu = np.zeros((N, B.shape[1])) if u is None else u
    v = np.zeros_like(y) if v is None else v
    for k in range(N):
        y[k] = C @ x + v[k]
        if K is not None:
            uu[k] = r[k] - K @ y[k]
        y[k] += D @ uu[k]
        x = A @ x + B @ uu[k]
    return uu, y


def frf_d(A, B, C, D, w):
    """Discrete FRF at normalized angular frequencies w (rad/sample), (n_f, n_y, n_u)."""
    n = A.shape[0]
    return np.array([C @ np.linalg.solve(np.exp(1j * x) * np.eye(n) - A, B) + D for x in w])


def mats(sys):
    return [np.asarray(m, float) for m in (sys.A, sys.B, sys.C, sys.D)]


def sorted_poles(A):
    p = np.linalg.eigvals(A)
    return p[np.lexsort((p.imag, p.real))]


# --------------------------------------------------------------------- Gram
@pytest.mark.parametrize(
    "N, k, chunk", [(60, 6, 7), (1000, 8, 64), (1000, 40, 4096), (83, 40, 5)], ids=str
)
def test_structured_gram_equals_explicit_gram(N, k, chunk):
    # oracle: H H^T of the explicitly built block-Hankel matrix
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((N, 2)), rng.standard_normal((N, 3))
    scales = [np.array([1.0, 2.0]), np.array([0.5, 1.0, 3.0])]
    G = hankel_gram([a, b], scales, n_blocks=k, n_samples=N, chunk=chunk)
    H = hankel([a, b], scales, n_blocks=k, n_samples=N)
    assert np.allclose(G, H @ H.T, rtol=0, atol=1e-13 * np.abs(G).max())


def _explicit_gram(blocks_of_signals, scales, k, N):
    """Independent oracle: the block-Hankel matrix built row by row, then H H^T."""
    z = np.hstack([s[:N] / c for s, c in zip(blocks_of_signals, scales)])
    j = N - k + 1
    H = np.vstack([z[a : a + j].T for a in range(k)])
    return H @ H.T


@pytest.mark.parametrize(
    "N, k, widths, chunk",
    [
        (40, 40, (1,), 1024),  # one channel, a single column (j = 1)
        (41, 4, (1,), 1024),  # one channel, N below one FFT segment
        (97, 8, (2, 1), 3),  # chunk smaller than a segment
        (5000, 40, (6, 6, 6), 1024),  # the benchmark's shape (18 channels), many chunks
        (5000, 40, (6, 6, 6), 10**6),  # the whole record in one chunk
        (1203, 6, (3, 2), 250),  # segment count not dividing the chunks
    ],
    ids=str,
)
def test_hankel_gram_equals_plain_numpy_gram(N, k, widths, chunk):
    # scaled, non-white channels (a filtered random walk) with a nonzero mean, so that
    # lagged products differ from zero-lag ones and edge terms matter
    rng = np.random.default_rng(N + k)
    sigs = [np.cumsum(rng.standard_normal((N, w)), axis=0) * 0.1 + 1.0 for w in widths]
    scales = [rng.uniform(0.5, 2.0, w) for w in widths]
    G = hankel_gram(sigs, scales, n_blocks=k, n_samples=N, chunk=chunk)
    G0 = _explicit_gram(sigs, scales, k, N)
    assert G.shape == G0.shape
    assert np.max(np.abs(G - G0)) <= 1e-13 * np.max(np.abs(G0))
    assert np.max(np.abs(G - G.T)) <= 1e-13 * np.max(np.abs(G0))  # symmetric to rounding


def test_lag_sums_equal_direct_sums():
    from workbench.ident.gram import lag_sums

    rng = np.random.default_rng(3)
    N, K = 777, 9
    a, b = rng.standard_normal((N, 2)), rng.standard_normal((N, 1))
    sc = [np.ones(2), np.array([3.0])]
    z = np.hstack([a, b / 3.0])
    F = lag_sums([a, b], sc, n_lags=K, n_samples=N, chunk=100)
    F0 = np.stack([z[: N - d].T @ z[d:] for d in range(K)])
    assert np.max(np.abs(F - F0)) <= 1e-13 * np.max(np.abs(F0))
    # fewer samples than lags: the sums over what there is (zero beyond)
    F = lag_sums([a[:5]], [np.ones(2)], n_lags=K, n_samples=5)
    assert np.allclose(F[5:], 0.0, atol=1e-15) and np.allclose(F[1], a[:4].T @ a[1:5])


# ------------------------------------------------------- exact, noise-free
@pytest.mark.parametrize("factorization", ["gram", "qr"])
@pytest.mark.parametrize("method", ["n4sid", "moesp"])
def test_open_loop_noise_free_is_exact(method, factorization):
    rng = np.random.default_rng(1)
    A, B, C, D = random_stable(rng, 6, 2, 2)
    u = rng.standard_normal((3000, 2))
    _, y = simulate(A, B, C, D, u)
    res = identify_subspace(
        TimeData(fs=1.0, u=u, y=y), method=method, block_rows=8, factorization=factorization
    )
    assert res.order == 6 and res.suggested_order == 6
    Ai, Bi, Ci, Di = mats(res.model)
    # machine precision: poles and FRF to 1e-9 relative (eps * conditioning)
    assert np.allclose(sorted_poles(Ai), sorted_poles(A), atol=1e-9)
    w = np.linspace(0.01, 3.1, 40)
    Gt, Gi = frf_d(A, B, C, D, w), frf_d(Ai, Bi, Ci, Di, w)
    assert np.max(np.abs(Gi - Gt)) < 1e-9 * np.max(np.abs(Gt))


@pytest.mark.parametrize("method", ["cl-n4sid", "cl-moesp", "cl-cva"])
def test_closed_loop_noise_free_is_exact(method):
    rng = np.random.default_rng(2)
    A, B, C, _ = random_stable(rng, 6, 2, 3, radius=0.8)
    D = np.zeros((3, 2))
    K = 0.05 * rng.standard_normal((2, 3))
    assert np.max(np.abs(np.linalg.eigvals(A - B @ K @ C))) < 1
    r = rng.standard_normal((3000, 2))
    u, y = simulate(A, B, C, D, None, K=K, r=r)
    with pytest.warns(UserWarning) if method == "cl-cva" else _nullcontext():
        res = identify_subspace(
            TimeData(fs=1.0, u=u, y=y, r=r, loop="closed"), method=method, block_rows=8
        )
    assert res.order == 6
    Ai, Bi, Ci, Di = mats(res.model)
    assert np.allclose(sorted_poles(Ai), sorted_poles(A), atol=1e-9)
    w = np.linspace(0.01, 3.1, 40)
    Gt, Gi = frf_d(A, B, C, D, w), frf_d(Ai, Bi, Ci, Di, w)
    assert np.max(np.abs(Gi - Gt)) < 1e-9 * np.max(np.abs(Gt))


class _nullcontext:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_known_input_delay_is_removed_from_the_data():
    # y[k] driven by u[k-2]: with input_delay=2 the order stays 4 and the model is exact
    rng = np.random.default_rng(3)
    A, B, C, D = random_stable(rng, 4, 2, 2)
    u = rng.standard_normal((2000, 2))
    u_late = np.vstack([np.zeros((2, 2)), u[:-2]])
    _, y = simulate(A, B, C, D, u_late)
    res = identify_subspace(
        TimeData(fs=100.0, u=u, y=y), method="moesp", block_rows=6, input_delay=2
    )
    assert res.order == 4 and res.delay_s == pytest.approx(0.02)
    assert np.allclose(sorted_poles(mats(res.model)[0]), sorted_poles(A), atol=1e-9)


# ----------------------------------------------------------- closed-loop bias
def test_open_loop_methods_are_biased_on_closed_loop_data_and_closed_loop_ones_are_not():
    """u[k] = r[k] - K y[k]: the noise reaches u, so open-loop N4SID/MOESP are biased.

    Oracle: the true FRF. Tolerances: the closed-loop estimate within 10 %
    (mean relative FRF error over the band, noise std 0.2 vs r std 0.3, 10^4
    samples); the open-loop estimates off by more than 5 times that.
    """
    rng = np.random.default_rng(4)
    A = np.zeros((4, 4))
    for k, z in enumerate([0.8 * np.exp(0.6j), 0.7 * np.exp(1.3j)]):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = [[z.real, z.imag], [-z.imag, z.real]]
    B = np.array([[1.0, 0.2], [0.0, 0.0], [0.1, 1.0], [0.0, 0.0]])
    C = np.array([[1.0, 0.5, 0.1, 0.0], [0.2, 0.0, 1.0, 0.3]])
    T = np.eye(4) + 0.3 * rng.standard_normal((4, 4))
    A, B, C, D = T @ A @ np.linalg.inv(T), T @ B, C @ np.linalg.inv(T), np.zeros((2, 2))
    K = 0.4 * np.eye(2)  # 80 % of the largest stabilizing gain of this plant
    assert np.max(np.abs(np.linalg.eigvals(A - B @ K @ C))) < 1
    N = 10_000
    r = 0.3 * rng.standard_normal((N, 2))
    v = 0.2 * rng.standard_normal((N, 2))
    u, y = simulate(A, B, C, D, None, v, K=K, r=r)
    data = TimeData(fs=1.0, u=u, y=y, r=r, loop="closed")
    w = np.linspace(0.01, 3.0, 60)
    Gt = frf_d(A, B, C, D, w)
    err = {}
    for method in METHODS:
        res = identify_subspace(data, method=method, order=4, block_rows=10)
        Gi = frf_d(*mats(res.model), w)
        err[method] = np.mean(
            np.linalg.norm(Gi - Gt, axis=(1, 2)) / np.linalg.norm(Gt, axis=(1, 2))
        )
    for m in ("cl-n4sid", "cl-moesp", "cl-cva"):
        assert err[m] < 0.10, err
    for m in ("n4sid", "moesp"):
        assert err[m] > 5 * max(err["cl-n4sid"], err["cl-moesp"], err["cl-cva"]), err


# ------------------------------------------------------------------- order
def test_suggest_order_prefers_the_last_clear_gap():
    s = np.array([100, 90, 80, 1.0, 0.9, 0.02, 0.019, 0.018, 0.017])  # gaps 80 and 45
    n, gap = suggest_order(s, max_order=8)
    assert n == 5 and gap == pytest.approx(0.9 / 0.02)
    text = format_singular_values(s, order=3, suggested=n, gap=gap)
    assert "suggested order 5" in text and "<- chosen" in text


def test_singular_value_plot_is_written(tmp_path):
    out = tmp_path / "sv.png"
    plot_singular_values(np.logspace(2, -3, 20), out, order=5, suggested=6)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -------------------------------------------------------------- bad input
def test_bad_input_is_refused_in_one_line():
    rng = np.random.default_rng(5)
    u, y = rng.standard_normal((500, 2)), rng.standard_normal((500, 2))
    open_data = TimeData(fs=1.0, u=u, y=y)
    with pytest.raises(InputError, match="expected closed-loop data with the excitation 'r'"):
        identify_subspace(open_data, method="cl-moesp")
    with pytest.raises(InputError, match="method: expected one of"):
        identify_subspace(open_data, method="pem")
    with pytest.raises(InputError, match="order: expected 1 <= order"):
        identify_subspace(open_data, method="moesp", block_rows=5, order=10)
    with pytest.raises(InputError, match="samples for 40 block rows"):
        identify_subspace(open_data, method="moesp", block_rows=40)
    with pytest.raises(InputError, match="identically zero"):
        identify_subspace(TimeData(fs=1.0, u=np.zeros((500, 2)), y=y), method="moesp", block_rows=5)


# ------------------------------------------------------------------ memory
def test_peak_memory_does_not_grow_with_the_record_length():
    """Peak allocation of an identification, 10^5 vs 10^6 samples: within 20 %.

    The data arrays are made before tracemalloc starts; what the method
    allocates is O(chunk * rows + rows^2), not O(N).
    """
    rng = np.random.default_rng(6)
    A, B, C, D = random_stable(rng, 2, 1, 1)
    peaks = []
    for N in (100_000, 1_000_000):
        u = rng.standard_normal((N, 1))
        # a first-order-filtered output, vectorized (scipy) so the test stays fast
        import scipy.signal

        y = scipy.signal.lfilter([0.0, 1.0], [1.0, -0.5], u[:, 0])[
            :, None
        ] + 0.01 * rng.standard_normal((N, 1))
        data = TimeData(fs=1.0, u=u, y=y)
        tracemalloc.start()
        identify_subspace(data, method="moesp", block_rows=5, order=1)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        del data, u, y
    assert peaks[1] < 1.2 * peaks[0] + 64_000, peaks
    assert peaks[1] < 8 * 1_000_000  # far below one copy of the 10^6-sample record (16 MB)


# ------------------------------------------------------- wafer stage (quick)
def test_wafer_stage_closed_loop_record_gives_the_modes():
    """One closed-loop wafer-stage record (10,000 samples, 5 kHz, nm noise, 1-sample delay).

    Named tolerances: the 913.8 / 1032 Hz modes within 0.5 Hz and damping
    within 10 % on a single record (the 20-realization study with the 0.1 Hz
    / 5 % targets is benchmarks/bench_subspace.py); 6 rigid-body modes.
    """
    from plants.wafer_stage import wafer_stage
    from workbench.experiments import wafer_stage_closed_loop_record
    from workbench.modal.model import ModalModel

    data = wafer_stage_closed_loop_record(wafer_stage(), rng=3)
    res = identify_subspace(data, method="cl-moesp", block_rows=20, input_delay=1)
    assert res.suggested_order == 16 and res.order == 16
    mm = ModalModel.from_statespace(res.model)
    assert mm.kinds == ("rigid",) * 6 + ("flexible",) * 2
    assert mm.freq_hz[6:] == pytest.approx([913.8, 1032.0], abs=0.5)
    assert mm.damping[6:] == pytest.approx([0.0091, 0.0095], rel=0.10)

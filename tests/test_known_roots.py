"""A mode behind lags: the ZOH coefficients from the filter's roots in closed form
(:func:`workbench.modal.simulate._channel_filters` knows them: the mode's and the lags'
-1/tau) are the coefficients from np.roots' eigenvalues, and the mode's output on a record
(:func:`~workbench.modal.simulate.mixed_inputs`, which passes them) is unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.modal import simulate as S


@pytest.mark.parametrize("n_lags", [1, 2])
@pytest.mark.parametrize("frac", [0.0, 0.37])
def test_coefficients_from_known_roots_are_np_roots(n_lags, frac):
    rng = np.random.default_rng(n_lags * 10 + int(frac * 100))
    fs = 4096.0
    dt = 1 / fs
    for _ in range(40):
        f = np.exp(rng.uniform(np.log(5.0), np.log(1500.0)))
        z = np.exp(rng.uniform(np.log(1e-4), np.log(0.9)))
        w = 2 * np.pi * f
        den = (2 * z * w, w * w)
        d = np.array([1.0, *den])
        taus = 1 / (2 * np.pi * rng.uniform(50, 3000, n_lags))
        for tau in taus:
            d = np.convolve(d, [tau, 1.0])
        roots = np.array(S._den_roots(den) + [complex(-1 / t) for t in taus], complex)
        for num0 in ([1.0], [1.0, 0.0]):
            (num,), dm = S._monic([num0], d)
            ref = S._zoh_coefficients.__wrapped__(num.tobytes(), dm.tobytes(), dt, frac * dt)
            out = S._zoh_coefficients.__wrapped__(
                num.tobytes(), dm.tobytes(), dt, frac * dt, roots.tobytes()
            )
            for x, y in zip(out, ref):
                assert np.allclose(x, y, rtol=1e-9, atol=1e-12 * np.max(np.abs(y)))


def test_known_roots_of_the_wrong_degree_are_not_used():
    """Roots that do not match the denominator's degree: np.roots, as without them."""
    d = np.convolve([1.0, 20.0, 1e4], [1e-3, 1.0])
    (num,), dm = S._monic([[1.0]], d)
    ref = S._pole_coefficients(num[1:], dm, 1e-3, 0.0)
    out = S._pole_coefficients(num[1:], dm, 1e-3, 0.0, np.array([-1.0 + 0j]))
    for x, y in zip(out, ref):
        assert np.array_equal(x, y)

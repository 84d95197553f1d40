"""Excitation designs (workbench.signals.excitation): lines, levels, orthogonality, seeds."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.core.errors import InputError
from workbench.signals.excitation import (
    as_rng,
    crest_factor,
    multisine,
    multisine_lines,
    step_signal,
    white_noise,
)

FS = 5000.0  # Hz, the wafer stage's sampling rate
PERIOD = 2000  # samples: 2.5 Hz lines, the period of the shared example record


@pytest.mark.parametrize("kind", ["full", "odd", "random_odd"])
def test_multisine_excites_exactly_its_lines_at_its_rms(kind):
    rms = np.array([6.0, 0.114])  # N, N m: the example record's Fx and Tx levels
    d = multisine(fs=FS, period=PERIOD, band_hz=(7.5, 1500), n_ch=2, rms=rms, kind=kind, rng=1)
    x = d.one_period()  # (R, n_exp, period, n_ch)
    assert x.shape == (1, 2, PERIOD, 2)
    X = np.fft.rfft(x, axis=2)
    excited = np.flatnonzero(np.abs(X[0, 0, :, 0]) > 1e-9 * np.abs(X).max())
    np.testing.assert_array_equal(excited, d.lines)
    np.testing.assert_allclose(np.sqrt(np.mean(x**2, axis=2)), np.broadcast_to(rms, (1, 2, 2)))
    np.testing.assert_allclose(X[:, :, d.lines], d.coef * PERIOD / 2, atol=1e-9)
    assert d.freq[0] >= 7.5 and d.freq[-1] <= 1500
    if kind != "full":
        assert np.all(d.lines % 2 == 1)


def test_random_odd_leaves_one_line_out_per_group():
    odd = multisine_lines(fs=FS, period=PERIOD, band_hz=(7.5, 1500), kind="odd", rng=0)
    ro = multisine_lines(fs=FS, period=PERIOD, band_hz=(7.5, 1500), kind="random_odd", rng=0)
    # 299 odd lines 3..599; groups of 4: 74 left out (the example record excites 225)
    assert odd.size == 299 and ro.size == 299 - 299 // 4 == 225
    groups = odd[: 4 * (odd.size // 4)].reshape(-1, 4)
    assert all(np.isin(g, ro).sum() == 3 for g in groups)


def test_orthogonal_design_is_perfectly_conditioned():
    for n_ch, n_exp in ((6, 6), (6, 8), (3, 4)):  # DFT pattern; Hadamard; Hadamard
        d = multisine(
            fs=FS,
            period=400,
            band_hz=(20, 1000),
            n_ch=n_ch,
            design="orthogonal",
            n_exp=n_exp,
            rng=2,
        )
        F = np.swapaxes(d.coef[0], 0, 1)  # (n_lines, n_exp, n_ch)
        FhF = np.swapaxes(F.conj(), 1, 2) @ F  # (n_lines, n_ch, n_ch): n_exp |c|^2 I
        diag = np.einsum("lii->li", FhF).real
        np.testing.assert_allclose(FhF, diag[:, :, None] * np.eye(n_ch), atol=1e-12)
        np.testing.assert_allclose(np.linalg.cond(FhF), 1.0, rtol=1e-9)


def test_seeded_and_reproducible():
    a = multisine(fs=FS, period=PERIOD, band_hz=(10, 100), n_ch=3, n_realizations=2, rng=5)
    b = multisine(
        fs=FS,
        period=PERIOD,
        band_hz=(10, 100),
        n_ch=3,
        n_realizations=2,
        rng=np.random.default_rng(5),
    )
    np.testing.assert_array_equal(a.coef, b.coef)
    assert a.coef.shape[:2] == (2, 3)
    assert not np.allclose(a.coef[0], a.coef[1])  # realizations differ
    with pytest.raises(InputError, match="rng"):
        as_rng(None)


def test_white_noise_and_step():
    x = white_noise(8192, 2, fs=FS, rms=[1.0, 2.0], band_hz=(10, 500), rng=3)
    np.testing.assert_allclose(x.std(axis=0), [1.0, 2.0])
    X = np.abs(np.fft.rfft(x, axis=0))
    f = np.fft.rfftfreq(8192, 1 / FS)
    assert X[(f > 520)].max() < 1e-9 * X.max()
    s = step_signal(100, amplitude=[1.0, 0.0, -2.0], n_ch=3, start_sample=10)
    assert s[:10].max() == 0 and np.all(s[10:] == [1.0, 0.0, -2.0])
    # a random-phase multisine's crest factor is near that of Gaussian noise (~3-4)
    d = multisine(fs=FS, period=PERIOD, band_hz=(7.5, 1500), n_ch=1, rng=4)
    assert 2.0 < crest_factor(d.one_period()[0, 0])[0] < 5.0


def test_bad_band_is_refused():
    with pytest.raises(InputError, match="band_hz"):
        multisine(fs=FS, period=PERIOD, band_hz=(100, 3000), n_ch=1, rng=0)
    with pytest.raises(InputError, match="no random_odd line"):
        multisine_lines(fs=FS, period=PERIOD, band_hz=(3.0, 3.5), kind="random_odd", rng=0)
    with pytest.raises(InputError, match="orthogonal"):
        multisine(
            fs=FS, period=PERIOD, band_hz=(10, 100), n_ch=3, design="orthogonal", n_exp=2, rng=0
        )

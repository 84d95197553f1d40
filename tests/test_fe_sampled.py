"""What a sampled experiment measures of an FE model, and images of modes above Nyquist."""

from __future__ import annotations

import control
import numpy as np
import pytest

from workbench.core.errors import InputError
from workbench.core.lti import zoh_frf
from workbench.fe import MeasuredModes, pair_aliases
from workbench.fe.predict import ModalTerms


def test_sampled_frf_equals_python_control_zoh_discretization():
    """ModalTerms.frf(fs=) = sum over modes of control.c2d(mode, 'zoh') at e^{jwT}, / ZOH;
    a rigid mode, modes far above Nyquist and a heavily damped one included."""
    rng = np.random.default_rng(0)
    fr = np.array([0.0, 3.0, 120.0, 900.0, 1500.0, 3000.0])
    z = np.array([0.0, 0.02, 0.005, 0.01, 0.02, 0.5])
    c, b = rng.standard_normal((6, 2)), rng.standard_normal((6, 3))
    D = 1e-6 * rng.standard_normal((2, 3))
    fs, f = 2048.0, np.linspace(1.0, 1020.0, 300)
    G = ModalTerms(fr, z, c, b, D).frf(f, fs=fs)
    ref = np.zeros_like(G)
    for k in range(fr.size):
        w = 2 * np.pi * fr[k]
        mode = control.ss([[0, 1], [-(w**2), -2 * z[k] * w]], [[0], [1]], [[1, 0]], [[0]])
        h = np.asarray(control.c2d(mode, 1 / fs, "zoh")(np.exp(2j * np.pi * f / fs))).ravel()
        ref += h[:, None, None] * np.outer(c[k], b[k])[None]
    ref = (ref + D) / zoh_frf(f, fs)[:, None, None]
    assert np.max(np.abs(G - ref)) / np.max(np.abs(ref)) < 1e-12
    # far below Nyquist the sampled and the continuous response agree
    G_c = ModalTerms(fr[1:4], z[1:4], c[1:4], b[1:4], D).frf(f[:5])
    G_s = ModalTerms(fr[1:4], z[1:4], c[1:4], b[1:4], D).frf(f[:5], fs=fs)
    # (0.2 %: the 900 Hz mode's image at 1148 Hz still reaches down there)
    assert np.max(np.abs(G_s - G_c) / np.abs(G_c)) < 1e-2
    with pytest.raises(InputError):
        ModalTerms(fr, z, c, b, D).frf(f, fs=-1.0)


def test_pair_aliases_finds_the_image_and_only_with_a_matching_shape():
    fs = 2048.0
    fe_f = np.array([100.0, 700.0, 1238.9, 1490.4])
    rng = np.random.default_rng(1)
    R = rng.standard_normal((4, 3, 2))
    # measured: the image of the 1238.9 Hz mode (at 809.1 Hz) with its shape, and a mode at
    # the image frequency of the 1490.4 Hz mode (557.6 Hz) with an unrelated shape
    meas = MeasuredModes(
        np.array([100.0, 809.2, 557.7]),
        np.array([0.01, 0.0267, 0.05]),
        np.stack([R[0], -2.0 * R[2], rng.standard_normal((3, 2))]),
        ("a", "b", "c"),
        ("u", "v"),
    )
    from workbench.fe import mac_matrix

    mac = mac_matrix(meas.residues, R)
    assert pair_aliases(meas, [1, 2], fe_f, mac, fs) == [(1, 2)]
    # no mode above Nyquist near an image: nothing paired
    assert pair_aliases(meas, [1, 2], fe_f[:2], mac[:, :2], fs) == []

"""workbench.testing: every assertion passes on a good loop and fails, naming why, on a bad one."""

from __future__ import annotations

import control
import numpy as np
import pytest

import plants
from controllers.protocol import StateSpaceController
from workbench.core.lti import frf
from workbench.experiments import default_controller
from workbench.io.formats import FrfData, save_controller
from workbench.scan import ScanLimits, scan
from workbench.testing import assert_bandwidth, assert_margins, assert_stable, assert_tracking

M = 2.0  # kg, the double integrator 1/(M s^2)
FS = 5000.0
FC = 100.0  # Hz, the lead's crossover
A_LEAD = 10.0  # pole/zero ratio: phase lead asin((a-1)/(a+1)) = 54.9 deg


def _plant():
    return control.ss(control.tf([1.0], [M, 0, 0]))


def _lead(fc: float = FC, gain: float = 1.0):
    """Lead with |L(j wc)| = 1 at fc for 1/(M s^2), Tustin (as in tests/test_loop.py)."""
    wc = 2 * np.pi * fc
    shape = control.tf([1 / (wc / np.sqrt(A_LEAD)), 1], [1 / (wc * np.sqrt(A_LEAD)), 1])
    k = gain * M * wc**2 / abs(shape(1j * wc))
    return control.ss(control.c2d(k * shape, 1 / FS, "tustin"))


# the closed form for the good loop: crossover FC, phase margin asin(9/11) = 54.9 deg less the
# ZOH's half sample (180 FC / FS = 3.6 deg): 51.3 deg
PM_GOOD = np.degrees(np.arcsin((A_LEAD - 1) / (A_LEAD + 1))) - 180 * FC / FS
# the same lead with its sign flipped: positive feedback on a double integrator, unstable
BAD_GAIN = -1.0


@pytest.fixture(scope="module")
def frf_data():
    f = np.logspace(np.log10(FS / 2e4), np.log10(FS / 2 * 0.999), 4000)
    return FrfData(freq=f, G=frf(_plant(), f))


@pytest.mark.parametrize("kind", ["model", "frf"])
def test_assert_stable(kind, frf_data):
    plant = _plant() if kind == "model" else frf_data
    assert_stable(plant, _lead())
    with pytest.raises(AssertionError, match="unstable"):
        assert_stable(plant, _lead(gain=BAD_GAIN))


def test_assert_margins_against_the_closed_form():
    assert_margins(_plant(), _lead(), phase_margin_deg=PM_GOOD - 0.5, s_peak_max=1.5)
    with pytest.raises(
        AssertionError, match=r"loop y\[0\]: phase margin 51\.\d+ deg < bound 60 deg"
    ):
        assert_margins(_plant(), _lead(), phase_margin_deg=60.0)
    with pytest.raises(AssertionError, match=r"loop y\[0\]: \|S\|inf 1\.\d+ .* > bound 1\.1"):
        assert_margins(_plant(), _lead(), s_peak_max=1.1)
    with pytest.raises(AssertionError, match=r"gain margin .* dB < bound 40 dB"):
        assert_margins(_plant(), _lead(), gain_margin_db=40.0)


def test_assert_bandwidth_against_the_closed_form(frf_data):
    for plant in (_plant(), frf_data):
        assert_bandwidth(plant, _lead(), crossover_hz=0.99 * FC)
        with pytest.raises(
            AssertionError, match=r"loop y\[?0\]?: crossover 100\.\d+ Hz < bound 120 Hz"
        ):
            assert_bandwidth(plant, _lead(), crossover_hz=120.0)
    with pytest.raises(AssertionError, match=r"-3 dB bandwidth .* Hz < bound 200 Hz"):
        assert_bandwidth(_plant(), _lead(), bandwidth_hz=200.0)


@pytest.fixture(scope="module")
def stage():
    """The true wafer stage with the experiments' decentralized PID at 100 Hz (fast to tune)."""
    plant = plants.wafer_stage()
    return plant, default_controller(plant, crossover_hz=100.0)


def test_assertions_on_a_true_plant_and_a_controller_file(stage, tmp_path):
    plant, K = stage
    path = tmp_path / "K.npz"
    save_controller(path, K)
    assert_stable(plant, K)
    assert_stable("wafer_stage", path)
    assert_bandwidth(plant, K, crossover_hz=80.0, dofs=["x", "y", "z"])
    with pytest.raises(AssertionError, match=r"loop z: crossover .* Hz < bound 500 Hz"):
        assert_bandwidth(plant, K, crossover_hz=500.0, dofs=["z"])


def test_assert_tracking(stage):
    plant, K = stage
    profile = scan(0.05, 0.002, ScanLimits(0.05, 5.0, 1000.0, 1e6), plant.fs, settle_s=0.01)
    # feedback only (no feedforward), 100 Hz crossover: the error in y is of order a / wc^2
    # (5 / (2 pi 100)^2 = 13 um during acceleration); bounds on the constant-velocity part
    assert_tracking(plant, K, profile, dof="y", ma_max=1e-4, window_s=0.002)
    with pytest.raises(AssertionError, match=r"tracking of the scan on y .* loop y: max \|MA\|"):
        assert_tracking(plant, K, profile, dof="y", ma_max=1e-12, window_s=0.002)
    with pytest.raises(AssertionError, match=r"loop x: max MSD .* > bound 1e-15"):
        assert_tracking(plant, K, profile, dof="y", msd_max=1e-15, dofs=["x"], window_s=0.002)


def test_bad_input_is_an_input_error(frf_data):
    from workbench.core.errors import InputError

    with pytest.raises(InputError, match="expected at least one bound"):
        assert_margins(_plant(), _lead())
    with pytest.raises(InputError, match="a measured FRF has no time response"):
        profile = scan(0.05, 0.002, ScanLimits(0.05, 5.0, 1000.0, 1e6), FS)
        assert_tracking(frf_data, _lead(), profile, dof=0, ma_max=1.0, window_s=0.001)
    with pytest.raises(InputError, match="plant: expected a plant name"):
        assert_stable("no_such_plant", _lead())
    K = StateSpaceController(A=np.zeros((0, 0)), B=np.zeros((0, 1)), C=np.zeros((1, 0)),
                             D=np.ones((1, 1)), fs=FS)  # fmt: skip
    with pytest.raises(InputError, match="dof: expected"):
        assert_tracking(_plant(), K, scan(0.05, 0.002, ScanLimits(0.05, 5, 1e3, 1e6), FS),
                        dof="q", ma_max=1.0, window_s=0.001)  # fmt: skip

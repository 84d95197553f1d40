"""workbench.core.model.LTIModel: one test per conversion, against closed forms.

Oracle: a mass-spring-damper, G(s) = 1 / (m s^2 + c s + k), natural frequency
sqrt(k/m) / 2 pi, damping c / (2 sqrt(k m)), static gain 1/k; a delay tau is
the factor exp(-j w tau).
"""

from __future__ import annotations

import control
import numpy as np
import pytest

from workbench.core import lti
from workbench.core.errors import InputError
from workbench.core.model import LTIModel, as_model, dc_gain, pade_order, pole_summary
from workbench.io import formats
from workbench.io.formats import FrfData

# a 2 kg mass on a 8e4 N/m spring, 20 N s/m damper: f_n = sqrt(4e4)/2 pi = 31.83 Hz,
# damping 20 / (2 sqrt(8e4 * 2)) = 0.025
M, K, C_DAMP = 2.0, 8.0e4, 20.0
TAU = 3.0e-4  # s, a computation-plus-amplifier delay of a few samples at 10 kHz


def msd(dt: float = 0.0, delay_s: float = 0.0) -> LTIModel:
    """Mass-spring-damper, input force (N), outputs position (m) and velocity (m/s)."""
    A = np.array([[0.0, 1.0], [-K / M, -C_DAMP / M]])
    B = np.array([[0.0], [1.0 / M]])
    C = np.eye(2)
    D = np.zeros((2, 1))
    sys = control.ss(A, B, C, D)
    if dt:
        sys = control.c2d(sys, dt, method="zoh")
    return LTIModel.from_statespace(
        sys,
        delay_s=delay_s,
        input_names=["force"],
        output_names=["pos", "vel"],
        state_names=["x", "v"],
    )


def msd_frf(freq_hz: np.ndarray) -> np.ndarray:
    """Closed form, shape (n_f, 2, 1): position 1/(m s^2 + c s + k), velocity s times it."""
    s = 2j * np.pi * freq_hz
    g = 1.0 / (M * s**2 + C_DAMP * s + K)
    return np.stack([g, s * g], axis=1)[:, :, None]


def one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


# ----------------------------------------------------------- StateSpace
@pytest.mark.parametrize("dt", [0.0, 1e-4], ids=["continuous", "discrete"])
def test_statespace_round_trip_keeps_matrices_names_and_dt(dt):
    m = msd(dt)
    sys = m.to_statespace()
    assert sys.dt == dt
    assert list(sys.input_labels) == ["force"]
    assert list(sys.output_labels) == ["pos", "vel"]
    assert list(sys.state_labels) == ["x", "v"]
    back = LTIModel.from_statespace(sys)
    for key in "ABCD":
        np.testing.assert_array_equal(getattr(back, key), getattr(m, key))
    assert (back.dt, back.delay_s) == (m.dt, 0.0)
    assert back.input_names == m.input_names and back.state_names == m.state_names


def test_arrays_are_read_only_copies():
    A = np.array([[-1.0]])
    m = LTIModel(A, [[1.0]], [[1.0]], [[0.0]])
    A[0, 0] = 5.0  # the caller's array changes, the model does not
    assert m.A[0, 0] == -1.0
    with pytest.raises(ValueError):
        m.A[0, 0] = 2.0
    assert m.input_names == ("u0",) and m.state_names == ("x0",)


# ----------------------------------------------------------------- file
@pytest.mark.parametrize(
    "dt,delay", [(0.0, TAU), (1e-4, 3e-4), (0.0, 0.0)], ids=["continuous", "discrete", "no-delay"]
)
def test_file_round_trip_is_exact_with_delay(tmp_path, dt, delay):
    m = msd(dt, delay)
    m.write(tmp_path / "m.npz")
    raw = np.load(tmp_path / "m.npz")
    assert ("delay_s" in raw) == (delay > 0)  # spec keys only when there is no delay
    back = LTIModel.read(tmp_path / "m.npz")
    for key in "ABCD":
        np.testing.assert_array_equal(getattr(back, key), getattr(m, key))
    assert back.dt == m.dt and back.delay_s == m.delay_s
    assert back.input_names == m.input_names and back.output_names == m.output_names
    # the rational part alone, for tools that take a StateSpace
    sys = formats.load_model(tmp_path / "m.npz")
    np.testing.assert_array_equal(sys.A, m.A)


def test_as_model_accepts_model_statespace_and_path(tmp_path):
    m = msd(0.0, TAU)
    m.write(tmp_path / "m.npz")
    assert as_model(m) is m
    from_path = as_model(tmp_path / "m.npz")
    assert from_path.delay_s == TAU
    from_sys = as_model(m.without_delay().to_statespace())
    assert from_sys.delay_s == 0.0 and from_sys.n_x == 2
    with pytest.raises(InputError) as exc:
        as_model(42)
    assert "expected an LTIModel, a python-control StateSpace or a model file path" in one_line(exc)


# ----------------------------------------------------------- frequency
@pytest.mark.parametrize("dt", [0.0, 1e-5], ids=["continuous", "discrete"])
def test_frf_with_delay_is_the_closed_form_times_exp(dt):
    f = np.geomspace(1.0, 2000.0, 60)
    G = msd(dt, TAU).frf(f)
    # lti.frf, given the model itself, applies the model's own delay too
    np.testing.assert_array_equal(lti.frf(msd(dt, TAU), f), G)
    exact = msd_frf(f) * np.exp(-2j * np.pi * f * TAU)[:, None, None]
    if dt:  # a ZOH-discretized model at 100 kHz: the hold's half-sample lag and sinc
        exact = exact * lti.zoh_frf(f, 1.0 / dt)[:, None, None]
        np.testing.assert_allclose(G, exact, rtol=2e-3, atol=0)
    else:
        np.testing.assert_allclose(G, exact, rtol=1e-10, atol=0)


def test_pade_states_on_request_match_the_delay_below_their_range():
    f_max = 1000.0  # Hz
    n = pade_order(TAU, f_max)  # the smallest order with < 1 deg phase error up to f_max
    m = msd(0.0, TAU)
    sys = m.to_statespace(pade_order=n)
    assert sys.nstates == 2 + n  # n Pade states on the one input
    f = np.linspace(f_max / 50, f_max, 200)
    ratio = lti.frf(sys, f) / m.frf(f)  # = Pade(jw) exp(+jw tau): unit gain, small phase
    np.testing.assert_allclose(np.abs(ratio), 1.0, atol=1e-9)
    assert np.degrees(np.abs(np.angle(ratio))).max() < 1.0
    # one order lower exceeds the limit somewhere: the chosen order is the smallest
    if n > 1:
        low = lti.frf(m.to_statespace(pade_order=n - 1), f) / m.frf(f)
        assert np.degrees(np.abs(np.angle(low))).max() >= 1.0


def test_discrete_delay_states_are_exact_shifts():
    m = msd(1e-4, 3e-4)  # 3 samples
    sys = m.to_statespace(pade_order=1)
    assert sys.nstates == 2 + 3
    f = np.linspace(10.0, 4900.0, 50)
    np.testing.assert_allclose(lti.frf(sys, f), m.frf(f), rtol=1e-9)


# -------------------------------------------------------------- summaries
@pytest.mark.parametrize("dt", [0.0, 1e-4], ids=["continuous", "discrete"])
def test_pole_summary_and_dc_gain_of_the_mass_spring(dt):
    p = msd(dt).pole_summary()
    (mode,) = p["flexible_modes"]
    assert mode["freq_hz"] == pytest.approx(np.sqrt(K / M) / (2 * np.pi), rel=1e-9)
    assert mode["damping"] == pytest.approx(C_DAMP / (2 * np.sqrt(K * M)), rel=1e-9)
    assert p["n_rigid_body_poles"] == 0 and p["n_unstable"] == 0
    np.testing.assert_allclose(msd(dt, TAU).dc_gain(), [[1 / K], [0.0]], atol=1e-15)
    # the module functions take a StateSpace as well
    assert pole_summary(msd(dt).to_statespace()) == p


def test_dc_gain_of_a_rigid_body_is_infinite():
    rigid = LTIModel([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]])
    assert rigid.pole_summary()["n_rigid_body_poles"] == 2
    assert dc_gain(rigid) is None


def test_d2c_keeps_the_delay_and_names():
    from workbench.core.d2c import d2c

    cont = d2c(msd(1e-4, 2e-4))
    assert isinstance(cont, LTIModel) and cont.dt == 0.0 and cont.delay_s == 2e-4
    np.testing.assert_allclose(cont.A, msd().A, rtol=1e-8, atol=1e-6)
    assert cont.output_names == ("pos", "vel")


# --------------------------------------------------------------- refusals
REFUSALS = [
    ("A-square", dict(A=np.zeros((2, 3))), "key 'A': expected a square matrix"),
    ("B-rows", dict(B=np.zeros((3, 1))), "key 'B': expected 2 rows"),
    ("D-shape", dict(D=np.zeros((1, 1))), "key 'D': expected shape (2, 1)"),
    ("A-nan", dict(A=np.full((2, 2), np.nan)), "key 'A': expected finite values"),
    ("A-complex", dict(A=np.eye(2) * 1j), "key 'A': expected real values"),
    ("dt-negative", dict(dt=-1e-3), "key 'dt': expected 0.0 (continuous) or a sample time"),
    ("delay-negative", dict(delay_s=-1e-4), "key 'delay_s': expected a finite delay >= 0 s"),
    ("delay-vector", dict(delay_s=[1e-4, 2e-4]), "key 'delay_s': expected a real scalar"),
    ("names", dict(output_names=("a",)), "key 'output_names': expected 2 names, got 1"),
]


@pytest.mark.parametrize("change,needle", [r[1:] for r in REFUSALS], ids=[r[0] for r in REFUSALS])
def test_bad_model_is_refused_in_one_line(change, needle):
    m = msd()
    fields = dict(A=m.A, B=m.B, C=m.C, D=m.D, dt=0.0, delay_s=0.0, output_names=())
    with pytest.raises(InputError) as exc:
        LTIModel(**{**fields, **change})
    line = one_line(exc)
    assert line.startswith("model: ") and needle in line


def test_delay_is_never_dropped_silently():
    with pytest.raises(InputError) as exc:
        msd(0.0, TAU).to_statespace()
    assert "give pade_order=N" in one_line(exc)
    with pytest.raises(InputError) as exc:
        msd(1e-4, 1.5e-4).to_statespace(pade_order=2)  # 1.5 samples
    assert "not a whole number of samples" in one_line(exc)
    with pytest.raises(InputError) as exc:
        msd(0.0, TAU).to_statespace(pade_order=0)
    assert "pade_order: expected an integer >= 1" in one_line(exc)


def test_bad_delay_key_in_a_file_is_refused(tmp_path):
    arrays = formats.model_arrays(msd())
    np.savez(tmp_path / "m.npz", **arrays, delay_s=np.array(-1e-3))
    with pytest.raises(InputError) as exc:
        formats.read_model(tmp_path / "m.npz")
    line = one_line(exc)
    assert str(tmp_path / "m.npz") in line and "key 'delay_s'" in line


# ----------------------------------------------------- the delay travels
def test_scenario_model_file_keeps_its_delay_through_compare(tmp_path):
    """[model] file = ... with delay_s, then [compare]: the delay is part of the model.

    Before, the stage read the file with load_model and the delay was lost: the
    comparison of the model with its own (delayed) response then showed an error
    of |1 - exp(-j w tau)|, about 0.5 at 260 Hz for tau = 0.3 ms.
    """
    from workbench.cli.loop_stages import stage_compare
    from workbench.cli.pipeline import RunState, stage_model
    from workbench.io.scenario import Scenario

    true = msd(0.0, TAU)
    true.write(tmp_path / "model.npz")
    f = np.linspace(5.0, 500.0, 100)
    data = FrfData(freq=f, G=true.frf(f), input_names=("force",), output_names=("pos", "vel"))
    scen = Scenario(name="t", seed=0, results=tmp_path / "out", path=tmp_path / "s.toml")
    st = RunState(scenario=scen, out=tmp_path / "out", rng=np.random.default_rng(0))
    st.out.mkdir()
    st.frf = data
    stage_model(st, {"file": "model.npz"})
    assert st.model.delay_s == TAU
    stage_compare(st, {"data": "frf"})
    assert st.summary["compare"]["error"] < 1e-10
    # the results folder's copy of the model keeps the delay too
    assert LTIModel.read(st.out / "model_nominal.npz").delay_s == TAU


def test_augment_keeps_the_models_delay(tmp_path):
    """augment of a delayed model: the delay is carried, exact, into the result."""
    from workbench.diagnosis.augment import augment

    true = msd(0.0, TAU)
    f = np.linspace(5.0, 500.0, 120)
    data = FrfData(freq=f, G=true.frf(f))
    res = augment(true, data, "time_delay")
    assert res.error_before < 1e-10  # the model's own delay was seen
    assert res.model.delay_s == pytest.approx(TAU, rel=1e-4)  # refitted on exact data
    assert res.delay_s == res.model.delay_s


# ------------------------------------------------------------ one d2c
def test_discrete_model_with_a_negative_real_pole_is_refused_by_diagnose():
    """A pole at z = -0.5 has no real logarithm; the diagnosis used to keep the real
    part of a complex logm silently. Now the one d2c refuses it in one line."""
    from workbench.diagnosis import diagnose
    from workbench.diagnosis.modal import decompose

    dt = 1e-3
    sys = control.ss([[-0.5, 0.0], [0.0, 0.9]], [[1.0], [1.0]], [[1.0, 1.0]], [[0.0]], dt)
    with pytest.raises(InputError) as exc:
        decompose(sys)
    assert "negative real axis" in one_line(exc)
    f = np.linspace(1.0, 400.0, 50)
    data = FrfData(freq=f, G=lti.frf(sys, f), fs=1 / dt)
    with pytest.raises(InputError) as exc:
        diagnose(sys, data, max_effects=1)
    line = one_line(exc)
    assert "negative real axis" in line and not line.startswith("model: model:")
